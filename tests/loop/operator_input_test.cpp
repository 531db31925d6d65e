// Operator input (operator_input.hpp): a command is exactly one datagram, acts only on the state
// and the HOLD it answers, is never kept for a later state, and comes from the user running
// lftrack; the control socket never removes someone else's file.

#include <gtest/gtest.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/un.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstring>
#include <fstream>
#include <limits>
#include <string>
#include <thread>
#include <vector>

#include "lftrack/loop/operator_input.hpp"
#include "test_data.hpp"

namespace lftrack::loop {
namespace {

OperatorRequest parsed(const std::string& text) {
  OperatorRequest q;
  EXPECT_TRUE(parse_operator_request(text.data(), text.size(), &q)) << "'" << text << "'";
  return q;
}

bool refused_as_malformed(const std::string& text) {
  OperatorRequest q;
  return !parse_operator_request(text.data(), text.size(), &q);
}

OperatorView in_state(TrackingState state, std::uint32_t hold_id = 0, std::int64_t cycles_in_state = 0) {
  OperatorView v;
  v.state = state;
  v.hold_id = hold_id;
  v.cycles_in_state = cycles_in_state;
  v.hold_age_s = hold_id != 0 ? 10.0 : 0.0;  // shown long enough for a person to decide
  v.reason = "correction step above limit";
  return v;
}

TEST(OperatorRequest, IsExactlyOneCommandWithAnOptionalHoldId) {
  EXPECT_EQ(parsed("stop").command, OperatorCommand::kStop);
  EXPECT_EQ(parsed("quit\n").command, OperatorCommand::kQuit);
  EXPECT_EQ(parsed("status").command, OperatorCommand::kStatus);
  const OperatorRequest resume = parsed("resume 3\n");
  EXPECT_EQ(resume.command, OperatorCommand::kResume);
  EXPECT_TRUE(resume.names_hold);
  EXPECT_EQ(resume.hold_id, 3u);
  EXPECT_FALSE(parsed("resume").names_hold);
  EXPECT_EQ(parsed("reset 4294967295").hold_id, 4294967295u);
  for (const std::string& bad : std::vector<std::string>{"resume ... do NOT resume", "resume 3 do NOT resume", "resume 3 ", " resume 3", "resume  3", "resume 0",
        "resume 4294967296", "resume 12345678901", "resume -1", "resume 3x", "resumes", "RESUME", "resume\n\n",
        "resume\r\n", "", "\n", std::string("resume\0 3", 9), "stop now", "resume 01"})
    EXPECT_TRUE(refused_as_malformed(bad)) << "'" << bad << "'";
}

TEST(OperatorRequest, ActsOnlyOnTheStateAndTheHoldItAnswers) {
  const OperatorRequest resume3 = parsed("resume 3"), resume2 = parsed("resume 2"), bare = parsed("resume");
  const OperatorView hold3 = in_state(TrackingState::kHold, 3);
  EXPECT_EQ(judge_operator_request(resume3, hold3, true), OperatorRefusal::kNone);
  EXPECT_EQ(judge_operator_request(resume2, hold3, true), OperatorRefusal::kWrongHold);
  EXPECT_EQ(judge_operator_request(bare, hold3, true), OperatorRefusal::kNoHoldId);
  EXPECT_EQ(judge_operator_request(bare, hold3, false), OperatorRefusal::kNone) << "a key answers the HOLD on screen";
  for (TrackingState s : {TrackingState::kIdle, TrackingState::kAlign, TrackingState::kTrack}) {
    EXPECT_EQ(judge_operator_request(resume3, in_state(s), true), OperatorRefusal::kNotApplicable) << to_string(s);
    EXPECT_EQ(judge_operator_request(bare, in_state(s), false), OperatorRefusal::kNotApplicable) << to_string(s);
  }
  // The other stopped state's command is refused with the command it needs, not as "stale" (an
  // outside probe's `resume <FAULT id>` was told "not in the state it answers (stale)").
  EXPECT_EQ(judge_operator_request(resume3, in_state(TrackingState::kFault, 3), true),
            OperatorRefusal::kResumeInFault)
      << "a resume does not leave a FAULT";
  EXPECT_NE(std::string(to_string(OperatorRefusal::kResumeInFault)).find("use reset"), std::string::npos);
  EXPECT_EQ(judge_operator_request(parsed("reset 3"), in_state(TrackingState::kHold, 3), true),
            OperatorRefusal::kResetInHold);
  EXPECT_NE(std::string(to_string(OperatorRefusal::kResetInHold)).find("use resume"), std::string::npos);
  EXPECT_EQ(judge_operator_request(parsed("reset 4"), in_state(TrackingState::kFault, 4), true),
            OperatorRefusal::kNone);
  EXPECT_EQ(judge_operator_request(parsed("stop"), in_state(TrackingState::kTrack), true), OperatorRefusal::kNone);
}

TEST(OperatorRequest, AResumeCountsOnlyOnceTheHoldHasBeenShownForASecond) {
  OperatorView hold = in_state(TrackingState::kHold, 123456);
  const OperatorRequest resume = parsed("resume 123456");
  for (double age : {0.0, 0.1, 0.99}) {
    hold.hold_age_s = age;
    EXPECT_EQ(judge_operator_request(resume, hold, true), OperatorRefusal::kTooSoon) << age;
  }
  hold.hold_age_s = std::nan("");
  EXPECT_EQ(judge_operator_request(resume, hold, true), OperatorRefusal::kTooSoon);
  hold.hold_age_s = kMinHoldBeforeResumeS;
  EXPECT_EQ(judge_operator_request(resume, hold, true), OperatorRefusal::kNone);
}

TEST(FreshKeyPress, AHeldOrRepeatingKeyNeverCountsAFreshPressDoes) {
  FreshKeyPress key(300'000'000);
  EXPECT_TRUE(key.seen(0)) << "the first press";
  for (std::int64_t t = 33'000'000; t < 3'000'000'000; t += 33'000'000)
    EXPECT_FALSE(key.seen(t)) << "auto-repeat at 30 Hz, at " << t << " ns";
  EXPECT_TRUE(key.seen(3'500'000'000)) << "released, then pressed again";
}

TEST(OperatorPoll, AStopWinsOverAResumeInTheSameCycle) {
  OperatorPoll p;
  p.accept(OperatorCommand::kResume);
  p.accept(OperatorCommand::kStop);
  p.accept(OperatorCommand::kResume);
  EXPECT_EQ(p.command, OperatorCommand::kStop);
}

// Several refusals in one cycle: each reason is counted, with the first and the last (an outside
// probe's token failures were lost behind the last reason of their cycles).
TEST(OperatorRefusals, KeepsEveryReasonWithTheFirstAndTheLast) {
  OperatorPoll p;
  p.refuse(OperatorRefusal::kNone);
  p.refuse(OperatorRefusal::kReplayed, 0);
  EXPECT_EQ(p.refused, 0) << "no reason, or none of them, counts nothing";
  EXPECT_EQ(p.first_refusal, OperatorRefusal::kNone);
  p.refuse(OperatorRefusal::kBadToken, 15);
  p.refuse(OperatorRefusal::kTooSoon);
  p.refuse(OperatorRefusal::kMalformed, 2);
  EXPECT_EQ(p.refused, 18);
  EXPECT_EQ(p.first_refusal, OperatorRefusal::kBadToken);
  EXPECT_EQ(p.last_refusal, OperatorRefusal::kMalformed);
  EXPECT_EQ(p.by_reason[std::size_t(OperatorRefusal::kBadToken)], 15);
  EXPECT_EQ(p.by_reason[std::size_t(OperatorRefusal::kTooSoon)], 1);
  EXPECT_EQ(p.by_reason[std::size_t(OperatorRefusal::kMalformed)], 2);
  EXPECT_EQ(p.by_reason[std::size_t(OperatorRefusal::kReplayed)], 0);
  p.refuse(OperatorRefusal::kBadToken, 4'000'000'000u);
  EXPECT_EQ(p.refused, 0xFFFF) << "saturates";
  EXPECT_EQ(p.by_reason[std::size_t(OperatorRefusal::kBadToken)], 0xFFFF);
  EXPECT_EQ(p.last_refusal, OperatorRefusal::kBadToken);
  for (std::size_t code = 1; code <= std::size_t(OperatorRefusal::kResetInHold); ++code)
    EXPECT_LT(code, kOperatorRefusalCodes) << "every code has its count";
}

TEST(ScriptedOperator, ResumesTheCurrentHoldAfterItsTimeAndNeverAFault) {
  ScriptedOperator op(10);
  OperatorPoll p;
  op.poll(in_state(TrackingState::kHold, 1, 9), &p);
  EXPECT_EQ(p.command, OperatorCommand::kNone);
  op.poll(in_state(TrackingState::kHold, 1, 10), &p);
  EXPECT_EQ(p.command, OperatorCommand::kResume);
  OperatorPoll fault;
  op.poll(in_state(TrackingState::kFault, 2, 100), &fault);
  EXPECT_EQ(fault.command, OperatorCommand::kNone) << "a FAULT needs a person";
}

// What a session on the room's devices refuses (LoopSession::create): an input that is no person,
// alone or among others.
TEST(ScriptedOperator, SaysItIsUnattendedAndSoDoInputsHoldingIt) {
  EXPECT_TRUE(ScriptedOperator(10).unattended());
  OperatorInputs people;
  EXPECT_FALSE(people.unattended());
  OperatorInputs with_a_script;
  with_a_script.add(std::make_unique<ScriptedOperator>(10));
  EXPECT_TRUE(with_a_script.unattended());
}

TEST(AutoResume, RefusesNonFiniteNegativeAndHugeValues) {
  for (double bad : {std::numeric_limits<double>::infinity(), std::nan(""), -1.0, -0.001, 1e12, 3600.5})
    EXPECT_FALSE(check_auto_resume_s(bad).ok()) << bad;
  for (double good : {0.0, 0.5, 1.0, 3600.0}) EXPECT_TRUE(check_auto_resume_s(good).ok()) << good;
}

// A client of the control socket, bound to an address of its own so that it gets replies.
class Client {
 public:
  Client(const std::filesystem::path& server, const std::filesystem::path& self) {
    fd_ = ::socket(AF_UNIX, SOCK_DGRAM | SOCK_CLOEXEC, 0);
    to_.sun_family = AF_UNIX;
    std::strncpy(to_.sun_path, server.c_str(), sizeof(to_.sun_path) - 1);
    if (!self.empty()) {
      sockaddr_un me{};
      me.sun_family = AF_UNIX;
      std::strncpy(me.sun_path, self.c_str(), sizeof(me.sun_path) - 1);
      EXPECT_EQ(::bind(fd_, reinterpret_cast<const sockaddr*>(&me), sizeof me), 0) << std::strerror(errno);
    }
    timeval timeout{1, 0};
    ::setsockopt(fd_, SOL_SOCKET, SO_RCVTIMEO, &timeout, sizeof timeout);
    ::setsockopt(fd_, SOL_SOCKET, SO_SNDTIMEO, &timeout, sizeof timeout);
  }
  ~Client() { ::close(fd_); }
  bool send(const std::string& text) {
    return ::sendto(fd_, text.data(), text.size(), 0, reinterpret_cast<const sockaddr*>(&to_), sizeof to_) ==
           ssize_t(text.size());
  }
  std::string reply() {
    char buffer[256];
    const ssize_t n = ::recv(fd_, buffer, sizeof buffer, 0);
    return n > 0 ? std::string(buffer, std::size_t(n)) : std::string();
  }

 private:
  int fd_ = -1;
  sockaddr_un to_{};
};

TEST(ControlSocket, ResumesSentOutsideAHoldAreDiscardedNotKeptForTheNextHold) {
  test::TempDir dir;
  auto socket = ControlSocket::open(dir.path() / "control.sock");
  ASSERT_TRUE(socket.ok()) << socket.status().message();
  Client client(dir.path() / "control.sock", {});
  for (int i = 0; i < 10; ++i) ASSERT_TRUE(client.send("resume 1"));
  OperatorPoll tracking;
  (*socket)->poll(in_state(TrackingState::kTrack), &tracking);
  EXPECT_EQ(tracking.command, OperatorCommand::kNone);
  EXPECT_EQ(tracking.refused, 10) << "every waiting datagram is taken and judged in one poll";
  EXPECT_EQ(tracking.last_refusal, OperatorRefusal::kNotApplicable);
  OperatorPoll held;
  (*socket)->poll(in_state(TrackingState::kHold, 1), &held);
  EXPECT_EQ(held.command, OperatorCommand::kNone) << "nothing sent during TRACK resumes HOLD 1";
  EXPECT_EQ(held.refused, 0);
}

// Issue 50 probe: the cycle read the control socket until it was empty, so a sender writing as
// fast as the loop read (the kernel queues only a few datagrams, and each read frees room for the
// next) could hold the cycle there. A poll takes at most 64 datagrams; the rest are judged by the
// next polls, none lost.
TEST(ControlSocket, AFloodIsTakenASliceAPollAndNothingIsLost) {
  test::TempDir dir;
  auto socket = ControlSocket::open(dir.path() / "control.sock");
  ASSERT_TRUE(socket.ok()) << socket.status().message();
  constexpr int kSent = 2000;
  std::atomic<int> sent{0};
  std::thread flood([&] {
    Client client(dir.path() / "control.sock", {});
    while (sent.load() < kSent)
      if (client.send("resume 1")) ++sent;  // a full queue times out after a second: send again
  });
  int refused = 0, largest = 0;
  for (const auto until = std::chrono::steady_clock::now() + std::chrono::seconds(60);
       refused < kSent && std::chrono::steady_clock::now() < until;) {
    OperatorPoll p;
    (*socket)->poll(in_state(TrackingState::kTrack), &p);
    refused += p.refused;
    largest = std::max(largest, int(p.refused));
    if (p.refused == 0) std::this_thread::sleep_for(std::chrono::milliseconds(1));
  }
  flood.join();
  EXPECT_EQ(refused, kSent) << "every datagram judged";
  EXPECT_LE(largest, 64) << "no poll took more than its slice";
}

TEST(ControlSocket, WhatWasSentBeforeTheHoldIsDiscardedWhenItBegins) {
  test::TempDir dir;
  auto socket = ControlSocket::open(dir.path() / "control.sock");
  ASSERT_TRUE(socket.ok());
  Client client(dir.path() / "control.sock", {});
  ASSERT_TRUE(client.send("resume 1"));  // a guess at the next id, sent while tracking
  ASSERT_TRUE(client.send("stop"));
  OperatorPoll at_hold;
  (*socket)->on_hold(in_state(TrackingState::kHold, 1), &at_hold);
  EXPECT_EQ(at_hold.refused, 1);
  EXPECT_EQ(at_hold.last_refusal, OperatorRefusal::kBeforeHold);
  EXPECT_EQ(at_hold.command, OperatorCommand::kStop) << "a stop still stops";
  ASSERT_TRUE(client.send("resume 1"));  // after the HOLD was shown
  OperatorPoll next;
  (*socket)->poll(in_state(TrackingState::kHold, 1), &next);
  EXPECT_EQ(next.command, OperatorCommand::kResume);
}

TEST(ControlSocket, AResumeMustNameTheHoldAndBeTheWholeDatagram) {
  test::TempDir dir;
  auto socket = ControlSocket::open(dir.path() / "control.sock");
  ASSERT_TRUE(socket.ok());
  Client client(dir.path() / "control.sock", dir.path() / "me.sock");
  const OperatorView hold = in_state(TrackingState::kHold, 7);
  const std::string long_text = "resume 7" + std::string(100, ' ') + "do NOT resume";
  for (const std::string& text : {std::string("resume"), std::string("resume 6"),
                                  std::string("resume ... do NOT resume"), long_text}) {
    ASSERT_TRUE(client.send(text));
    OperatorPoll p;
    (*socket)->poll(hold, &p);
    EXPECT_EQ(p.command, OperatorCommand::kNone) << text;
    EXPECT_EQ(p.refused, 1) << text;
    EXPECT_EQ(client.reply().rfind("refused: ", 0), 0u) << text;
  }
  ASSERT_TRUE(client.send("status"));
  OperatorPoll status;
  (*socket)->poll(hold, &status);
  EXPECT_EQ(status.refused, 0);
  EXPECT_EQ(client.reply(), "HOLD 7 cycle 0: correction step above limit\n") << "the id a resume must name";
  ASSERT_TRUE(client.send("resume 7\n"));
  OperatorPoll p;
  (*socket)->poll(hold, &p);
  EXPECT_EQ(p.command, OperatorCommand::kResume);
  EXPECT_EQ(client.reply(), "accepted: resume\n");
}

TEST(ControlSocket, IsTheOwnersOnlyWhateverTheUmask) {
  test::TempDir dir;
  const mode_t saved = ::umask(0);
  auto socket = ControlSocket::open(dir.path() / "control.sock");
  ::umask(saved);
  ASSERT_TRUE(socket.ok());
  struct stat st {};
  ASSERT_EQ(::stat((dir.path() / "control.sock").c_str(), &st), 0);
  EXPECT_TRUE(S_ISSOCK(st.st_mode));
  EXPECT_EQ(st.st_mode & 0777, 0600u);
}

TEST(ControlSocket, RefusesAnotherUsersCommands) {
  if (::geteuid() != 0) GTEST_SKIP() << "needs root to send as another user";
  test::TempDir dir;
  const auto path = dir.path() / "control.sock";
  auto socket = ControlSocket::open(path);
  ASSERT_TRUE(socket.ok());
  // Open the file mode as a mistaken installation might: the credentials still refuse.
  ASSERT_EQ(::chmod(path.c_str(), 0666), 0);
  ASSERT_EQ(::chmod(dir.path().c_str(), 0755), 0);
  const pid_t child = ::fork();
  if (child == 0) {
    if (::setgid(65534) != 0 || ::setuid(65534) != 0) ::_exit(2);
    const int fd = ::socket(AF_UNIX, SOCK_DGRAM, 0);
    sockaddr_un to{};
    to.sun_family = AF_UNIX;
    std::strncpy(to.sun_path, path.c_str(), sizeof(to.sun_path) - 1);
    const char text[] = "stop";
    ::_exit(::sendto(fd, text, 4, 0, reinterpret_cast<const sockaddr*>(&to), sizeof to) == 4 ? 0 : 3);
  }
  int status = 0;
  ASSERT_EQ(::waitpid(child, &status, 0), child);
  ASSERT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 0) << "the other user could send";
  OperatorPoll p;
  (*socket)->poll(in_state(TrackingState::kTrack), &p);
  EXPECT_EQ(p.command, OperatorCommand::kNone);
  EXPECT_EQ(p.refused, 1);
  EXPECT_EQ(p.last_refusal, OperatorRefusal::kSender);
  EXPECT_EQ((*socket)->refused_senders(), 1u);
}

TEST(ControlSocket, NeverRemovesAFileThatIsNotAStaleSocket) {
  test::TempDir dir;
  const auto journal = dir.path() / "journal.lfj";
  std::ofstream(journal) << "a record of treatment";
  auto over_file = ControlSocket::open(journal);
  ASSERT_FALSE(over_file.ok());
  EXPECT_NE(over_file.status().message().find("not a socket"), std::string::npos) << over_file.status().message();
  std::ifstream kept(journal);
  std::string text;
  std::getline(kept, text);
  EXPECT_EQ(text, "a record of treatment");

  const auto path = dir.path() / "control.sock";
  auto live = ControlSocket::open(path);
  ASSERT_TRUE(live.ok());
  auto second = ControlSocket::open(path);
  ASSERT_FALSE(second.ok()) << "another run listens there";
  EXPECT_NE(second.status().message().find("listening"), std::string::npos) << second.status().message();

  // A socket left by a run that was killed (bound, never removed) is stale: replaced.
  const auto stale = dir.path() / "stale.sock";
  const int fd = ::socket(AF_UNIX, SOCK_DGRAM, 0);
  sockaddr_un address{};
  address.sun_family = AF_UNIX;
  std::strncpy(address.sun_path, stale.c_str(), sizeof(address.sun_path) - 1);
  ASSERT_EQ(::bind(fd, reinterpret_cast<const sockaddr*>(&address), sizeof address), 0);
  ::close(fd);
  EXPECT_TRUE(ControlSocket::open(stale).ok());
  EXPECT_FALSE(ControlSocket::open(std::string(200, 'x')).ok()) << "too long for sun_path";
}

TEST(ControlSocket, IsRemovedOnClose) {
  test::TempDir dir;
  const auto path = dir.path() / "control.sock";
  auto socket = ControlSocket::open(path);
  ASSERT_TRUE(socket.ok());
  socket->reset();
  EXPECT_FALSE(std::filesystem::exists(path));
}

}  // namespace
}  // namespace lftrack::loop
