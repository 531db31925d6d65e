#pragma once
// The interval between two times in integer nanoseconds (any clock), as a double. Exact where
// the difference fits int64 (and exact in double up to 2^53 ns, 104 days); times further apart
// than int64 holds (a device's garbage timestamps) give the difference of the doubles instead
// of overflowing.

#include <cstdint>

namespace lftrack::loop {

inline double ns_between(std::int64_t from_ns, std::int64_t to_ns) {
  std::int64_t d = 0;
  return __builtin_sub_overflow(to_ns, from_ns, &d) ? double(to_ns) - double(from_ns) : double(d);
}

}  // namespace lftrack::loop
