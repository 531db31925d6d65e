#pragma once
// Counts heap allocations in the whole process, for the loop's allocations_per_cycle and the
// zero-allocation test. Linking the lftrack_allocation_counter library replaces the global
// operator new (every form) with one that counts (one relaxed atomic increment) and then calls
// malloc; operator delete calls free. Only executables link it (lftrack, the loop tests), never
// a library, so it cannot collide with another replacement.

#include <cstdint>

namespace lftrack::loop {

// Allocations since the process started, on every thread but those excluded below.
std::uint64_t process_allocation_count();

// For threads that watch the loop from outside the cycle and never delay it (the cycle hub, the
// monitor page's server, the OpenIGTLink server; watch/): their allocations are not the cycle's
// and are not counted, so "steady-state cycles allocate nothing" still measures the cycle's own
// threads (the loop, the registration's pool, the simulator) with a page open. Defined in
// lftrack::loop (allocation_scope.cpp), so a library may call it without the counter linked.
void exclude_this_thread_from_allocation_count();
bool this_thread_allocations_counted();

}  // namespace lftrack::loop
