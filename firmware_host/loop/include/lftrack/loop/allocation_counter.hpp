#pragma once
// Counts heap allocations in the whole process, for the loop's allocations_per_cycle and the
// zero-allocation test. Linking the lftrack_allocation_counter library replaces the global
// operator new (every form) with one that counts (one relaxed atomic increment) and then calls
// malloc; operator delete calls free. Only executables link it (lftrack, the loop tests), never
// a library, so it cannot collide with another replacement.

#include <cstdint>

namespace lftrack::host {

// Allocations since the process started.
std::uint64_t process_allocation_count();

}  // namespace lftrack::host
