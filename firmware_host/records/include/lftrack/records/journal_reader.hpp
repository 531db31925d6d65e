#pragma once
// The journal's reader (the format: lftrack/loop/journal.hpp and journal_format.hpp), offline:
// `journal export`, the tests, the chaos soak. A damaged frame (bad magic or size, CRC mismatch,
// cut short) loses only itself. The reader resynchronises on the next offset where a complete
// valid frame starts, reports each bad span (offset, length, what was wrong), and checks the
// cycle counter for gaps and repeats. A torn tail (a bad span at the end that a crash leaves) is
// reported but is not damage.

#include <array>
#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include "lftrack/loop/journal.hpp"
#include "lftrack/tracking/status.hpp"

namespace lftrack::records {

// Bytes between frames that are not a valid frame, from `offset` (bytes from the start of the
// file) for `bytes`.
struct JournalBadSpan {
  std::uint64_t offset = 0;
  std::uint64_t bytes = 0;
  std::string problem;  // what the frame at `offset` had wrong, e.g. "checksum mismatch"
  bool zeros = false;   // every byte of the span is zero (as a power loss leaves)
};

// Cycles missing between two records that follow each other in the file: `next_cycle` came
// where `after_cycle + 1 + skipped_periods` (of the record of `after_cycle`) was expected.
struct JournalCycleGap {
  std::uint64_t after_cycle = 0;
  std::uint64_t next_cycle = 0;
  std::uint64_t missing_cycles = 0;  // next_cycle - expected; at least the records missing
  std::uint32_t dropped_before = 0;  // the writer's count of queue drops, on the next record
  bool explained_by_drops = false;   // 1 <= dropped_before <= missing_cycles
  bool after_bad_span = false;       // a bad span lies between the two records
  std::size_t record_index = 0;      // of the next record in JournalContents::records
};

// A record whose cycle is not above every earlier record's: a duplicate (equal) or backwards.
struct JournalCycleRepeat {
  std::uint64_t cycle = 0;
  std::uint64_t highest_before = 0;  // the highest cycle of the records before it
  std::size_t record_index = 0;      // in JournalContents::records
};

// Limits on what one read takes, so that a stream without end (/dev/zero behind a valid header,
// a FIFO) stops in bounded time and memory. The defaults are far above any real journal (a
// treatment hour at 10 Hz is 36,000 records, 10 MB).
struct JournalReadLimits {
  std::size_t max_records = 4'000'000;       // about 1 GB in memory; 37 hours of cycles at 30 Hz
  std::uint64_t max_bad_bytes = 1ull << 30;  // 1 GiB in all not in any valid frame
};

struct JournalContents {
  std::uint32_t format_version = 0;
  std::array<std::uint8_t, 16> scene_fingerprint{};  // zeros: the writer recorded none
  std::vector<loop::JournalRecord> records;          // every valid frame, in file order (repeats included)
  std::vector<JournalBadSpan> bad_spans;  // in file order; a torn tail is the last one
  std::vector<JournalCycleGap> gaps;
  std::vector<JournalCycleRepeat> repeats;
  // The last bad span when it runs to the end of the file and is what a crash leaves: at most
  // one frame cut short by a kill, then nothing but zeros (blocks a power loss never wrote). Its
  // records were never durably written; it is not damage.
  std::size_t torn_tail_bytes = 0;
  std::string note;  // "ignored a torn tail: ..." when there is one
  // Why reading stopped before the end of the file (a limit reached, a read error); "" when it did not.
  std::string stopped;

  // True when records may have been lost or disordered beyond what a crash explains: a bad span
  // other than a torn tail, a gap the writer's drop counts do not explain, a repeated cycle, or
  // a read that stopped early.
  bool damaged() const;
};

// Reads every valid record, streaming the file (any size; a FIFO or a device too) through a
// 1 MiB window. Fails only when the file cannot be opened or read, is not a journal (header), is
// of another version than 1 or 2, or has a record size that does not match its version. Damage
// inside is reported in the result, never an error: the good records before and after it are all
// returned. Stops, with `stopped` saying so, before the record past `limits.max_records` or once
// more than `limits.max_bad_bytes` were not records.
// Memory: the records (264 bytes each) and the problems found. For a regular file the records'
// room is reserved from its size; on a stream of unknown length it grows by doubling, so briefly
// up to twice that (about 2 GB at the default record limit).
Result<JournalContents> read_journal(const std::filesystem::path& file, const JournalReadLimits& limits = {});

}  // namespace lftrack::records
