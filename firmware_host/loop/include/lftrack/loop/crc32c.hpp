#pragma once
// CRC-32C (Castagnoli, reflected polynomial 0x82F63B78), as used by iSCSI, ext4 and SCTP.
// Written here because Debian 12 packages no C/C++ CRC-32C library; the SSE4.2 crc32
// instruction is used where the CPU has it (checked at run time), a table otherwise. Both are
// tested against the standard check value crc32c("123456789") = 0xE3069283.

#include <cstddef>
#include <cstdint>

namespace lftrack::loop {

// CRC of `size` bytes continuing from `crc` (0 to start).
std::uint32_t crc32c(const void* data, std::size_t size, std::uint32_t crc = 0);
// The portable table implementation (the tests compare the two).
std::uint32_t crc32c_portable(const void* data, std::size_t size, std::uint32_t crc = 0);

}  // namespace lftrack::loop
