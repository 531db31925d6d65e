// The journal: round trip, checksums, torn tails, and kill -9 at random moments.

#include "lftrack/host/journal.hpp"

#include <gtest/gtest.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <chrono>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <random>
#include <thread>

#include "lftrack/host/crc32c.hpp"
#include "test_data.hpp"

namespace lftrack::host {
namespace {

JournalRecord record(std::uint64_t cycle) {
  JournalRecord r;
  r.cycle = cycle;
  r.cycle_start_ns = std::int64_t(cycle) * 100'000'000;
  r.pose_delta[0] = 0.001 * double(cycle);
  r.similarity[1] = 0.5;
  r.state = 2;
  return r;
}

TEST(Crc32c, StandardCheckValueAndBothImplementationsAgree) {
  const char* text = "123456789";
  EXPECT_EQ(crc32c(text, 9), 0xE3069283u);
  EXPECT_EQ(crc32c_portable(text, 9), 0xE3069283u);
  std::vector<unsigned char> data(1000);
  std::mt19937 rng(1);
  for (auto& b : data) b = static_cast<unsigned char>(rng());
  for (std::size_t n : {0u, 1u, 7u, 8u, 9u, 63u, 1000u})
    EXPECT_EQ(crc32c(data.data(), n), crc32c_portable(data.data(), n));
  EXPECT_EQ(crc32c(data.data() + 10, 90, crc32c(data.data(), 10)), crc32c(data.data(), 100)) << "continues";
}

TEST(Journal, RoundTripsEveryRecord) {
  test::TempDir dir;
  const auto file = dir.path() / "cycles.journal";
  {
    auto w = JournalWriter::open(file);
    ASSERT_TRUE(w.ok()) << w.status().message();
    for (std::uint64_t i = 0; i < 1000; ++i) ASSERT_TRUE((*w)->append(record(i)));
    ASSERT_TRUE((*w)->close().ok());
    EXPECT_EQ((*w)->written(), 1000u);
  }
  auto j = read_journal(file);
  ASSERT_TRUE(j.ok()) << j.status().message();
  ASSERT_EQ(j->records.size(), 1000u);
  EXPECT_EQ(j->torn_tail_bytes, 0u);
  for (std::uint64_t i = 0; i < 1000; ++i) {
    EXPECT_EQ(j->records[i].cycle, i);
    EXPECT_EQ(j->records[i].pose_delta[0], 0.001 * double(i));
  }
}

// A disk that fills up: write(2) takes bytes until a budget is spent (the last write partly),
// then fails with ENOSPC, as a real file system does.
std::atomic<long long> g_disk_bytes_left{0};
ssize_t filling_disk_write(int fd, const void* data, std::size_t bytes) {
  const long long left = g_disk_bytes_left.load();
  if (left <= 0) {
    errno = ENOSPC;
    return -1;
  }
  const std::size_t n = std::min<std::size_t>(bytes, static_cast<std::size_t>(left));
  g_disk_bytes_left -= static_cast<long long>(n);
  return ::write(fd, data, n);
}

TEST(Journal, ADiskThatFillsUpKeepsEveryRecordWrittenBeforeAndSaysSo) {
  test::TempDir dir;
  const auto file = dir.path() / "cycles.journal";
  constexpr std::size_t kFrame = 8 + sizeof(JournalRecord) + 4;
  g_disk_bytes_left = 32 + 100 * kFrame + kFrame / 2;  // header, 100 records and half of one
  JournalOptions options;
  options.write_call = &filling_disk_write;
  auto w = JournalWriter::open(file, options);
  ASSERT_TRUE(w.ok()) << w.status().message();
  for (std::uint64_t i = 0; i < 100; ++i) ASSERT_TRUE((*w)->append(record(i)));
  const auto until = std::chrono::steady_clock::now() + std::chrono::seconds(5);
  while ((*w)->written() < 100 && std::chrono::steady_clock::now() < until)
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
  EXPECT_FALSE((*w)->failed());
  for (std::uint64_t i = 100; i < 300; ++i) ASSERT_TRUE((*w)->append(record(i)));
  while (!(*w)->failed() && std::chrono::steady_clock::now() < until)
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
  EXPECT_TRUE((*w)->failed()) << "the cycle can see it at once";
  const Status closed = (*w)->close();
  ASSERT_FALSE(closed.ok());
  EXPECT_NE(closed.message().find("100 records before it are intact"), std::string::npos) << closed.message();
  EXPECT_EQ((*w)->lost(), 200u);
  auto j = read_journal(file);
  ASSERT_TRUE(j.ok()) << j.status().message();
  EXPECT_EQ(j->torn_tail_bytes, 0u) << "the half-written record was cut off";
  ASSERT_EQ(j->records.size(), 100u);
  for (std::uint64_t i = 0; i < 100; ++i) EXPECT_EQ(j->records[i].cycle, i);
}

TEST(Journal, TornTailIsIgnoredAndDamageInsideIsAnError) {
  test::TempDir dir;
  const auto file = dir.path() / "cycles.journal";
  {
    auto w = JournalWriter::open(file);
    for (std::uint64_t i = 0; i < 10; ++i) (*w)->append(record(i));
  }
  const auto size = std::filesystem::file_size(file);
  std::filesystem::resize_file(file, size - 17);  // the last record cut short
  auto torn = read_journal(file);
  ASSERT_TRUE(torn.ok());
  EXPECT_EQ(torn->records.size(), 9u);
  EXPECT_GT(torn->torn_tail_bytes, 0u);
  EXPECT_NE(torn->note.find("torn tail"), std::string::npos);
  // A flipped byte in the third record: not the tail, so the journal is damaged.
  {
    std::fstream f(file, std::ios::in | std::ios::out | std::ios::binary);
    f.seekp(32 + 2 * (8 + long(sizeof(JournalRecord)) + 4) + 20);
    f.put('\x5a');
  }
  auto damaged = read_journal(file);
  ASSERT_FALSE(damaged.ok());
  EXPECT_NE(damaged.status().message().find("checksum"), std::string::npos) << damaged.status().message();
}

TEST(Journal, RefusesWhatIsNotAJournalOfThisVersion) {
  test::TempDir dir;
  const auto file = dir.path() / "x.journal";
  std::ofstream(file) << "hello";
  EXPECT_FALSE(read_journal(file).ok());
  EXPECT_FALSE(read_journal(dir.path() / "missing.journal").ok());
  {
    auto w = JournalWriter::open(file);
    (*w)->append(record(1));
  }
  {
    std::fstream f(file, std::ios::in | std::ios::out | std::ios::binary);
    f.seekp(8);
    f.put('\x07');
  }
  auto j = read_journal(file);
  ASSERT_FALSE(j.ok());
  EXPECT_NE(j.status().message().find("version 7"), std::string::npos) << j.status().message();
  EXPECT_FALSE(JournalWriter::open(dir.path() / "no" / "such" / "folder" / "j").ok());
}

TEST(Journal, AFullQueueDropsAndSaysHowManyBeforeTheNextRecord) {
  test::TempDir dir;
  JournalOptions options;
  options.queue_capacity = 4;
  auto w = JournalWriter::open(dir.path() / "j", options);
  ASSERT_TRUE(w.ok());
  int accepted = 0;
  for (int i = 0; i < 100000; ++i) accepted += (*w)->append(record(std::uint64_t(i))) ? 1 : 0;
  ASSERT_TRUE((*w)->close().ok());
  auto j = read_journal(dir.path() / "j");
  ASSERT_TRUE(j.ok());
  ASSERT_EQ(j->records.size(), std::size_t(accepted));
  std::uint64_t dropped = 0;
  for (const auto& r : j->records) dropped += r.dropped_before;
  EXPECT_LE(dropped, (*w)->dropped());
  EXPECT_EQ(std::uint64_t(accepted) + (*w)->dropped(), 100000u);
}

// A child process appends records as fast as it can; the parent kills it with SIGKILL at a random
// moment. Every complete record must read back, in order, and a torn tail must be ignored.
TEST(Journal, SurvivesKillNineAtAnyMoment) {
  test::TempDir dir;
  std::mt19937 rng(7);
  int torn_tails = 0;
  for (int round = 0; round < 12; ++round) {
    const auto file = dir.path() / ("kill" + std::to_string(round) + ".journal");
    const pid_t child = fork();
    ASSERT_GE(child, 0);
    if (child == 0) {
      auto w = JournalWriter::open(file, {1 << 16, 1000});
      if (!w.ok()) _exit(2);
      for (std::uint64_t i = 0;; ++i) {
        while (!(*w)->append(record(i))) std::this_thread::yield();
      }
    }
    // The random moment starts once the child has written its header and a first record: on a
    // loaded host, starting the child can take longer than the shortest sleep, and a kill before
    // any write would test nothing. The child is killed on every path.
    const auto started = std::chrono::steady_clock::now();
    const auto first_record_bytes = static_cast<std::uintmax_t>(32 + 8 + sizeof(JournalRecord) + 4);
    bool writing = false;
    while (!writing && std::chrono::steady_clock::now() - started < std::chrono::seconds(10)) {
      std::error_code ec;
      writing = std::filesystem::file_size(file, ec) >= first_record_bytes && !ec;
      if (!writing) std::this_thread::sleep_for(std::chrono::microseconds(200));
    }
    if (writing) std::this_thread::sleep_for(std::chrono::microseconds(20000 + rng() % 80000));
    kill(child, SIGKILL);
    int status = 0;
    waitpid(child, &status, 0);
    ASSERT_TRUE(WIFSIGNALED(status));
    ASSERT_TRUE(writing) << "round " << round << ": the child wrote no record in 10 s";
    auto j = read_journal(file);
    ASSERT_TRUE(j.ok()) << "round " << round << ": " << j.status().message();
    ASSERT_GT(j->records.size(), 0u) << "round " << round;
    for (std::size_t i = 0; i < j->records.size(); ++i)
      ASSERT_EQ(j->records[i].cycle, i) << "round " << round;
    torn_tails += j->torn_tail_bytes > 0;
  }
  // Most kills land between writes; record that torn tails were seen and handled when they occur.
  RecordProperty("torn_tails", torn_tails);
}

}  // namespace
}  // namespace lftrack::host
