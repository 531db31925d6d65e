#include "lftrack/tracking/checksum.hpp"

#include <zlib.h>

#include <algorithm>

namespace lftrack::tracking {

std::uint32_t crc32_of(const void* data, std::size_t bytes, std::uint32_t crc) {
  uLong value = crc;
  const auto* at = static_cast<const Bytef*>(data);
  while (bytes > 0) {
    const auto chunk = static_cast<uInt>(std::min<std::size_t>(bytes, 1u << 30));
    value = crc32(value, at, chunk);
    at += chunk;
    bytes -= chunk;
  }
  return static_cast<std::uint32_t>(value);
}

}  // namespace lftrack::tracking
