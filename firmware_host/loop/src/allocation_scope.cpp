// Which threads' allocations the process's allocation counter counts (allocation_counter.hpp).
// A thread-local flag with constant initialisation: reading it in operator new never allocates.

#include "lftrack/loop/allocation_counter.hpp"

namespace lftrack::loop {
namespace {
thread_local bool t_excluded = false;
}  // namespace

void exclude_this_thread_from_allocation_count() { t_excluded = true; }
bool this_thread_allocations_counted() { return !t_excluded; }

}  // namespace lftrack::loop
