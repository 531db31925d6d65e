// Cycle journals (loop/journal.hpp read_journal): framing, CRC-32C, torn tails, record fields.
#include "fuzz_input.hpp"
#include "lftrack/loop/journal.hpp"
#include "lftrack/records/journal_reader.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace lftrack;
  records::JournalReadLimits limits;
  limits.max_records = 100000;
  auto journal = records::read_journal(fuzz::write_input("run.lfj", data, size), limits);
  if (!journal.ok()) fuzz::expect_reason(journal.status());
  return 0;
}
