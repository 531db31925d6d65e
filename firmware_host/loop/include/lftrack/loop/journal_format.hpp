#pragma once
// The journal's file format (journal.hpp), shared by its writer and its reader: a 32-byte header
// (magic, version), then one frame per record: magic, size, the record, CRC32C.

#include <cstddef>
#include <cstdint>

#include "lftrack/loop/journal.hpp"

namespace lftrack::loop::journal_format {

constexpr char kFileMagic[8] = {'L', 'F', 'T', 'J', 'R', 'N', 'L', '1'};
// 2: hold id and operator commands (8 bytes more); 3: the cycle's refusals by reason (32 more);
// 4: the true target residual per axis and the command's acknowledgement time (56 more); 5: the
// latency chain's links (40 more); 6: imaging on demand, the surrogate and the correlation model
// (184 more).
constexpr std::uint32_t kFormatVersion = 6;
constexpr std::uint32_t kFrameMagic = 0x4A52464C;  // "LFRJ"
constexpr std::size_t kHeaderBytes = 32;
constexpr std::size_t kFrameBytes = 8 + sizeof(JournalRecord) + 4;

struct Frame {
  std::uint32_t magic = kFrameMagic;
  std::uint32_t size = sizeof(JournalRecord);
  JournalRecord record;
  std::uint32_t crc = 0;
};

}  // namespace lftrack::loop::journal_format
