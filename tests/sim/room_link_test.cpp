// The room link between a served couch and simulated detectors in other processes
// (sim/room_link.hpp): what is written is read, never torn; the couch is read where it was at a
// given time; nothing that is not a link is replaced; a live writer's link is refused; a killed
// writer's link is taken over in place.

#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <fstream>
#include <thread>

#include "lftrack/sim/room_link.hpp"
#include "lftrack/sim/served_couch.hpp"
#include "test_data.hpp"

namespace lftrack::sim {
namespace {

tracking::Vector6d filled(double v) {
  return tracking::Vector6d::Constant(v);
}

TEST(RoomLink, WhatIsPublishedIsRead) {
  test::TempDir dir;
  auto writer = RoomLinkWriter::create(dir.path() / "room.link");
  ASSERT_TRUE(writer.ok()) << writer.status().message();
  auto reader = RoomLinkReader::open(dir.path() / "room.link");
  ASSERT_TRUE(reader.ok()) << reader.status().message();
  RoomLinkSample s;
  EXPECT_FALSE((*reader)->read(&s)) << "nothing written yet";
  (*writer)->publish(filled(1.5));
  ASSERT_TRUE((*reader)->read(&s));
  EXPECT_EQ(s.couch_position, filled(1.5));
  EXPECT_EQ(s.writer_pid, std::uint64_t(::getpid()));
  EXPECT_GT(s.written_ns, 0);
  // A non-finite position is never handed on.
  (*writer)->publish(filled(std::numeric_limits<double>::quiet_NaN()));
  EXPECT_FALSE((*reader)->read(&s));
}

// A detector that exposed at t sees the couch where it was at t, however much later it asks: on
// the straight line between the samples either side, the newest after the last, the oldest kept
// before the first.
TEST(RoomLink, ReadAtGivesTheCouchWhereItWasThen) {
  test::TempDir dir;
  auto writer = RoomLinkWriter::create(dir.path() / "room.link");
  ASSERT_TRUE(writer.ok()) << writer.status().message();
  auto reader = RoomLinkReader::open(dir.path() / "room.link");
  ASSERT_TRUE(reader.ok()) << reader.status().message();
  RoomLinkSample s;
  EXPECT_FALSE((*reader)->read_at(1000, &s)) << "nothing written yet";
  (*writer)->publish(filled(0), 1'000'000);
  (*writer)->publish(filled(10), 2'000'000);
  (*writer)->publish(filled(20), 3'000'000);
  ASSERT_TRUE((*reader)->read_at(1'500'000, &s));
  EXPECT_EQ(s.written_ns, 1'500'000);
  for (int i = 0; i < 6; ++i) EXPECT_DOUBLE_EQ(s.couch_position[i], 5.0);
  ASSERT_TRUE((*reader)->read_at(2'000'000, &s));
  EXPECT_EQ(s.couch_position, filled(10));
  ASSERT_TRUE((*reader)->read_at(2'750'000, &s));
  EXPECT_DOUBLE_EQ(s.couch_position[2], 17.5);
  ASSERT_TRUE((*reader)->read_at(9'000'000, &s));
  EXPECT_EQ(s.couch_position, filled(20)) << "after the newest: the newest";
  EXPECT_EQ(s.written_ns, 3'000'000);
  ASSERT_TRUE((*reader)->read_at(500'000, &s));
  EXPECT_EQ(s.couch_position, filled(0)) << "before the first: the oldest";
  EXPECT_EQ(s.written_ns, 1'000'000) << "with its own time, so the caller sees how far off it is";
  ASSERT_TRUE((*reader)->read(&s));
  EXPECT_EQ(s.couch_position, filled(20)) << "read() is the newest";
  // 3,000 samples more, 1 ms apart: about the last second is kept; older times get the oldest kept.
  for (int k = 1; k <= 3000; ++k) (*writer)->publish(filled(20 + k), 3'000'000 + std::int64_t(k) * 1'000'000);
  ASSERT_TRUE((*reader)->read_at(2'999'500'000, &s));
  EXPECT_DOUBLE_EQ(s.couch_position[0], 20 + 2996.5);  // sample k (20 + k) at 3 + k ms
  ASSERT_TRUE((*reader)->read_at(1'000'000, &s));
  EXPECT_GT(s.written_ns, 1'900'000'000) << "the history holds about a second, not everything";
  EXPECT_LT(s.written_ns, 2'100'000'000);
  // A non-finite sample is never handed on, by time either.
  (*writer)->publish(filled(std::numeric_limits<double>::quiet_NaN()), 3'004'000'000);
  EXPECT_FALSE((*reader)->read_at(3'004'000'000, &s));
}

TEST(RoomLink, ReadsAreNeverTorn) {
  test::TempDir dir;
  auto writer = RoomLinkWriter::create(dir.path() / "room.link");
  ASSERT_TRUE(writer.ok());
  auto reader = RoomLinkReader::open(dir.path() / "room.link");
  ASSERT_TRUE(reader.ok());
  (*writer)->publish(filled(0));
  std::atomic<bool> stop{false};
  // The writer publishes without pause; the reader reads until it has 5,000 samples (or 20 s).
  // On a loaded host 200,000 tries once gave no sample at all: every try met a write under way,
  // which says nothing about tearing, so the test now waits for enough samples to judge by.
  std::thread writing([&] {
    for (double v = 1; !stop.load(); v += 1) {
      (*writer)->publish(filled(v));
      std::this_thread::yield();
    }
  });
  int torn = 0, reads = 0;
  const auto until = std::chrono::steady_clock::now() + std::chrono::seconds(20);
  while (reads < 5000 && std::chrono::steady_clock::now() < until) {
    RoomLinkSample s, then;
    if (!(*reader)->read(&s)) continue;
    ++reads;
    for (int k = 1; k < 6; ++k) torn += s.couch_position[k] != s.couch_position[0];
    // Read by time too (between two samples, or the one at that time): every axis the same.
    if ((*reader)->read_at(s.written_ns - 1000, &then))
      for (int k = 1; k < 6; ++k) torn += then.couch_position[k] != then.couch_position[0];
  }
  stop.store(true);
  writing.join();
  EXPECT_GT(reads, 1000);
  EXPECT_EQ(torn, 0);
}

TEST(RoomLink, RefusesWhatIsNotALinkAndALiveWriter) {
  test::TempDir dir;
  const auto file = dir.path() / "journal.lfj";
  std::ofstream(file) << "precious";
  auto over = RoomLinkWriter::create(file);
  ASSERT_FALSE(over.ok());
  EXPECT_NE(over.status().message().find("not a room link"), std::string::npos);
  std::ifstream in(file);
  std::string kept;
  in >> kept;
  EXPECT_EQ(kept, "precious") << "left untouched";
  auto foreign = RoomLinkReader::open(file);
  ASSERT_FALSE(foreign.ok());
  EXPECT_NE(foreign.status().message().find("remove it"), std::string::npos)
      << "no server would replace it: " << foreign.status().message();
  auto missing = RoomLinkReader::open(dir.path() / "none.link");
  ASSERT_FALSE(missing.ok());
  EXPECT_NE(missing.status().message().find("lftrack serve couch|robot ... --room"), std::string::npos)
      << missing.status().message();
  auto first = RoomLinkWriter::create(dir.path() / "room.link");
  ASSERT_TRUE(first.ok());
  auto second = RoomLinkWriter::create(dir.path() / "room.link");
  ASSERT_FALSE(second.ok()) << "this process still writes it";
  EXPECT_NE(second.status().message().find("still writing"), std::string::npos);
  // A link of the first format (one sample, 128 bytes), left by an older lftrack: refused, and
  // said to be one, never replaced.
  const auto older = dir.path() / "older.link";
  {
    std::string bytes(128, '\0');
    bytes.replace(0, 13, "lftrack-room1");
    std::ofstream(older, std::ios::binary) << bytes;
  }
  auto over_older = RoomLinkWriter::create(older);
  ASSERT_FALSE(over_older.ok());
  EXPECT_NE(over_older.status().message().find("older lftrack"), std::string::npos) << over_older.status().message();
  EXPECT_EQ(std::filesystem::file_size(older), 128u) << "left untouched";
  auto read_older = RoomLinkReader::open(older);
  ASSERT_FALSE(read_older.ok());
  EXPECT_NE(read_older.status().message().find("older lftrack"), std::string::npos);
}

// A link that was removed and made again by another server is that server's: the first one's
// orderly end leaves it.
TEST(RoomLink, AWriterRemovesOnlyItsOwnLink) {
  test::TempDir dir;
  const auto path = dir.path() / "room.link";
  auto first = RoomLinkWriter::create(path);
  ASSERT_TRUE(first.ok()) << first.status().message();
  std::filesystem::remove(path);
  auto second = RoomLinkWriter::create(path);
  ASSERT_TRUE(second.ok()) << second.status().message();
  first->reset();
  EXPECT_TRUE(std::filesystem::exists(path)) << "the second server's link stays";
  EXPECT_TRUE(RoomLinkReader::open(path).ok());
  second->reset();
  EXPECT_FALSE(std::filesystem::exists(path)) << "its own writer removes it";
}

// A served couch that takes over a killed server's link starts where that couch stopped, but
// only within its own travel: a link left outside it is refused, named, and left in place.
TEST(RoomLink, AServedCouchRefusesALinkLeftOutsideItsTravel) {
  test::TempDir dir;
  const auto leave_link_at = [](const std::filesystem::path& path, const tracking::Vector6d& at) {
    const pid_t child = ::fork();
    if (child == 0) {
      auto writer = RoomLinkWriter::create(path);
      if (!writer.ok()) _exit(1);
      (*writer)->publish(at);
      ::kill(::getpid(), SIGKILL);
    }
    int status = 0;
    return ::waitpid(child, &status, 0) == child && WIFSIGNALED(status);
  };
  const auto far = dir.path() / "far.link";
  ASSERT_TRUE(leave_link_at(far, filled(1e308)));
  auto refused = ServedCouch::start(VirtualCouchSpec{}, far);
  ASSERT_FALSE(refused.ok());
  EXPECT_NE(refused.status().message().find("outside this couch's travel"), std::string::npos)
      << refused.status().message();
  EXPECT_TRUE(RoomLinkReader::open(far).ok()) << "the link is left as it was";
  const auto turned = dir.path() / "turned.link";
  ASSERT_TRUE(leave_link_at(turned, (tracking::Vector6d() << 0, 0, 0, 0, 0, 0.5).finished()));  // 28.6 deg
  EXPECT_FALSE(ServedCouch::start(VirtualCouchSpec{}, turned).ok());
  const auto near = dir.path() / "near.link";
  ASSERT_TRUE(leave_link_at(near, filled(0.01)));
  auto resumed = ServedCouch::start(VirtualCouchSpec{}, near);
  ASSERT_TRUE(resumed.ok()) << resumed.status().message();
  EXPECT_TRUE((*resumed)->position().isApprox(filled(0.01))) << "it stands where the killed couch stopped";
}

TEST(RoomLink, AKilledWritersLinkIsTakenOverInPlace) {
  test::TempDir dir;
  const auto path = dir.path() / "room.link";
  const pid_t child = ::fork();
  if (child == 0) {  // a couch server that dies without tidying up
    auto writer = RoomLinkWriter::create(path);
    if (!writer.ok()) _exit(1);
    (*writer)->publish(filled(-2.5));
    ::kill(::getpid(), SIGKILL);
  }
  int status = 0;
  ASSERT_EQ(::waitpid(child, &status, 0), child);
  ASSERT_TRUE(WIFSIGNALED(status));
  auto reader = RoomLinkReader::open(path);
  ASSERT_TRUE(reader.ok()) << "the killed writer left its link";
  auto writer = RoomLinkWriter::create(path);
  ASSERT_TRUE(writer.ok()) << writer.status().message();
  EXPECT_EQ((*writer)->resumed_position(), filled(-2.5)) << "the couch stands where it stopped";
  (*writer)->publish(filled(4));
  RoomLinkSample s;
  ASSERT_TRUE((*reader)->read(&s)) << "a reader opened before sees the new writer";
  EXPECT_EQ(s.couch_position, filled(4));
  EXPECT_EQ(s.writer_pid, std::uint64_t(::getpid()));
}

// A killed writer not yet reaped (a zombie whose pid still answers kill(pid, 0)) does not hold
// the link: the kernel released its lock when it died.
TEST(RoomLink, AKilledWriterNotYetReapedDoesNotBlockTheNext) {
  test::TempDir dir;
  const auto path = dir.path() / "room.link";
  const pid_t child = ::fork();
  if (child == 0) {
    auto writer = RoomLinkWriter::create(path);
    if (!writer.ok()) _exit(1);
    (*writer)->publish(filled(1.5));
    ::kill(::getpid(), SIGKILL);
  }
  siginfo_t info{};
  ASSERT_EQ(::waitid(P_PID, id_t(child), &info, WEXITED | WNOWAIT), 0) << "wait for the death, leave the zombie";
  ASSERT_EQ(info.si_code, CLD_KILLED);
  ASSERT_EQ(::kill(child, 0), 0) << "a zombie still answers kill(pid, 0)";
  auto writer = RoomLinkWriter::create(path);
  EXPECT_TRUE(writer.ok()) << writer.status().message();
  if (writer.ok()) {
    EXPECT_EQ((*writer)->resumed_position(), filled(1.5));
  }
  int status = 0;
  ASSERT_EQ(::waitpid(child, &status, 0), child);
}

}  // namespace
}  // namespace lftrack::sim
