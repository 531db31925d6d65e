// Archived frame sequences (drivers/frame_sequence.hpp): index.csv and actuator.csv. The input
// is split at its first NUL byte: before it the index, after it the actuator file (none if
// there is no NUL).
#include <cstring>

#include "fuzz_input.hpp"
#include "lftrack/drivers/frame_sequence.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace lftrack;
  const auto dir = fuzz::scratch() / "sequence";
  std::filesystem::create_directories(dir);
  const void* nul = std::memchr(data, 0, size);
  const std::size_t index_bytes = nul != nullptr ? std::size_t(static_cast<const std::uint8_t*>(nul) - data) : size;
  std::ofstream(dir / "index.csv", std::ios::binary | std::ios::trunc)
      .write(reinterpret_cast<const char*>(data), std::streamsize(index_bytes));
  std::error_code ec;
  if (nul != nullptr)
    std::ofstream(dir / "actuator.csv", std::ios::binary | std::ios::trunc)
        .write(reinterpret_cast<const char*>(data + index_bytes + 1), std::streamsize(size - index_bytes - 1));
  else
    std::filesystem::remove(dir / "actuator.csv", ec);
  auto sequence = drivers::read_frame_sequence(dir);
  if (!sequence.ok()) fuzz::expect_reason(sequence.status());
  return 0;
}
