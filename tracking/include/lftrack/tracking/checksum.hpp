#pragma once
// CRC-32 (zlib's: ISO-HDLC, the polynomial of gzip and PNG) of any number of bytes, for the
// checksums files carry (light fields, the phantom cache) and the hashes that name what a file
// was built from. zlib takes 32-bit lengths; this feeds it in chunks.

#include <cstddef>
#include <cstdint>

namespace lftrack::tracking {

// The CRC-32 of `bytes` bytes at `data`, continuing from `crc` (0 to start).
std::uint32_t crc32_of(const void* data, std::size_t bytes, std::uint32_t crc = 0);

}  // namespace lftrack::tracking
