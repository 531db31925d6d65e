// Who may act from the monitor page: listening addresses, the run's token and its file, single-use
// nonces, and the page's actions judged by the loop (listen_address.hpp, operator_token.hpp,
// page_operator.hpp).

#include <gtest/gtest.h>
#include <sys/stat.h>
#include <unistd.h>

#include <fstream>
#include <set>
#include <thread>

#include "lftrack/watch/listen_address.hpp"
#include "lftrack/watch/operator_token.hpp"
#include "lftrack/watch/page_operator.hpp"
#include "test_data.hpp"
#include "watch_fixture.hpp"

namespace lftrack::watch {

using loop::OperatorCommand;
using loop::OperatorPoll;
using loop::OperatorRefusal;
using loop::OperatorRequest;
using loop::OperatorView;
using loop::TrackingState;
namespace {

namespace fs = std::filesystem;
using test_watch::PollingLoop;

TEST(ListenAddress, TakesPortOrAddressAndPortAndRefusesTheRest) {
  auto a = parse_listen_address("8080");
  ASSERT_TRUE(a.ok());
  EXPECT_EQ(a->address, "127.0.0.1") << "loopback unless an address is named";
  EXPECT_EQ(a->port, 8080);
  EXPECT_TRUE(a->loopback());
  auto b = parse_listen_address("localhost:0");
  ASSERT_TRUE(b.ok());
  EXPECT_EQ(b->address, "127.0.0.1");
  EXPECT_EQ(b->port, 0);
  auto c = parse_listen_address("0.0.0.0:18944");
  ASSERT_TRUE(c.ok());
  EXPECT_TRUE(c->wildcard());
  for (const char* bad : {"", "-1", "65536", "99999999999", "1e3", "abc", "1.2.3:80", "1.2.3.4.5:80", ":80",
                          "127.0.0.1:", "127.0.0.1:80:81", "::1:80", "127.0.0.1: 80", "nan", "8080 "})
    EXPECT_FALSE(parse_listen_address(bad).ok()) << "'" << bad << "'";
  EXPECT_FALSE(parse_listen_address(std::string(100000, '9')).ok());
}

TEST(ListenAddress, ListensOnAFreePortAndRefusesABusyOne) {
  int port = 0;
  auto fd = open_listening_socket({"127.0.0.1", 0}, &port);
  ASSERT_TRUE(fd.ok()) << fd.status().message();
  EXPECT_GT(port, 0);
  int again = 0;
  EXPECT_FALSE(open_listening_socket({"127.0.0.1", port}, &again).ok()) << "the port is taken";
  ::close(*fd);
}

TEST(ListenAddress, WarnsOfAServerOtherHostsCanReachAndOnlyThen) {
  EXPECT_EQ(reachable_warning({"127.0.0.1", 8080}, "the monitor page", "watch the treatment"), "");
  EXPECT_EQ(reachable_warning({"127.0.0.5", 8080}, "the monitor page", "watch the treatment"), "");
  EXPECT_EQ(
      reachable_warning({"192.0.2.7", 8080}, "the monitor page", "watch the treatment"),
      "the monitor page listens on 192.0.2.7:8080: other hosts can reach it and watch the treatment; listen "
      "on 127.0.0.1 unless another host must reach it");
  EXPECT_NE(
      reachable_warning({"0.0.0.0", 1502}, "the modbus couch server", "move the couch")
          .find("listens on 0.0.0.0:1502 (every interface): other hosts can reach it and move the couch"),
      std::string::npos);
}

TEST(OperatorToken, IsRandomHexComparedExactly) {
  std::set<std::string> tokens;
  for (int i = 0; i < 100; ++i) {
    auto t = random_hex(32);
    ASSERT_TRUE(t.ok());
    EXPECT_EQ(t->size(), 64u);
    EXPECT_EQ(t->find_first_not_of("0123456789abcdef"), std::string::npos);
    tokens.insert(*t);
  }
  EXPECT_EQ(tokens.size(), 100u);
  const std::string token = *tokens.begin();
  EXPECT_TRUE(token_matches(token, token));
  EXPECT_FALSE(token_matches(token, token.substr(0, 63)));
  EXPECT_FALSE(token_matches(token, token + "0"));
  EXPECT_FALSE(token_matches(token, ""));
  EXPECT_FALSE(token_matches("", ""));
  std::string last = token;
  last.back() = last.back() == '0' ? '1' : '0';
  EXPECT_FALSE(token_matches(token, last));
}

// Issue 50 probe: a second run given a live run's token file replaced it with its own token and
// removed it at its exit, leaving the live run's operator without one. A running lftrack's token
// file is locked while it serves, and never replaced.
TEST(OperatorToken, ALiveRunsTokenFileIsNeverTakenOver) {
  test::TempDir dir;
  const fs::path file = dir.path() / "monitor.token";
  const std::string live_token(64, 'a');
  auto live = TokenFile::write(file, live_token);
  ASSERT_TRUE(live.ok()) << live.status().message();
  auto second = TokenFile::write(file, std::string(64, 'b'));
  ASSERT_FALSE(second.ok());
  EXPECT_NE(second.status().message().find("running lftrack"), std::string::npos) << second.status().message();
  std::string line;
  std::getline(std::ifstream(file) >> std::ws, line);
  EXPECT_EQ(line, live_token) << "the live run's token is still there";
  live->reset();
  EXPECT_FALSE(fs::exists(file)) << "removed by its own run";
}

TEST(OperatorToken, FileIsTheRunsOwnAndNeverReplacesAnotherFile) {
  test::TempDir dir;
  const fs::path file = dir.path() / "monitor.token";
  {
    auto written = TokenFile::write(file, "abc123");
    ASSERT_TRUE(written.ok()) << written.status().message();
    struct stat st {};
    ASSERT_EQ(::stat(file.c_str(), &st), 0);
    EXPECT_EQ(st.st_mode & 0777, 0600u) << "only this user may read the token";
    std::ifstream in(file);
    std::string line;
    std::getline(in, line);
    EXPECT_EQ(line, "abc123");
    // A second run at the same path while the first holds it replaces only a token file.
  }
  EXPECT_FALSE(fs::exists(file)) << "removed when the run ends";
  // An earlier run's file (a crash left it: 64 hexadecimal digits, mode 0600) is replaced.
  const std::string earlier(64, 'e');
  std::ofstream(file) << earlier << "\n";
  fs::permissions(file, fs::perms::owner_read | fs::perms::owner_write);
  EXPECT_TRUE(TokenFile::write(file, "0123").ok());
  // A user's file that merely looks like one (another mode, or other text) is kept.
  const fs::path lookalike = dir.path() / "lookalike.token";
  std::ofstream(lookalike) << earlier << "\n";
  fs::permissions(lookalike, fs::perms::owner_read | fs::perms::owner_write | fs::perms::group_read |
                                 fs::perms::others_read);
  EXPECT_FALSE(TokenFile::write(lookalike, "0123").ok());
  const fs::path short_hex = dir.path() / "short.token";
  std::ofstream(short_hex) << "deadbeef\n";
  fs::permissions(short_hex, fs::perms::owner_read | fs::perms::owner_write);
  EXPECT_FALSE(TokenFile::write(short_hex, "0123").ok());
  for (const fs::path& kept : {lookalike, short_hex}) {
    std::ifstream in(kept);
    std::string line;
    std::getline(in, line);
    EXPECT_TRUE(line == earlier || line == "deadbeef") << kept << " was replaced";
  }
  // Anything else is refused and kept: a file with other text, a link, a folder.
  const fs::path notes = dir.path() / "notes.token";
  std::ofstream(notes) << "treatment notes, not a token\n";
  EXPECT_FALSE(TokenFile::write(notes, "0123").ok());
  EXPECT_TRUE(fs::exists(notes));
  const fs::path link = dir.path() / "link.token";
  fs::create_symlink(dir.path() / "elsewhere", link);
  EXPECT_FALSE(TokenFile::write(link, "0123").ok());
  EXPECT_FALSE(fs::exists(dir.path() / "elsewhere")) << "never written through a link";
  fs::create_directory(dir.path() / "folder.token");
  EXPECT_FALSE(TokenFile::write(dir.path() / "folder.token", "0123").ok());
  EXPECT_FALSE(TokenFile::write(dir.path() / "missing" / "x.token", "0123").ok());
  // A token file replaced by another file while the run holds it is left alone at the end.
  {
    auto written = TokenFile::write(dir.path() / "moved.token", "abcd");
    ASSERT_TRUE(written.ok());
    fs::remove(dir.path() / "moved.token");
    std::ofstream(dir.path() / "moved.token") << "someone else's\n";
  }
  EXPECT_TRUE(fs::exists(dir.path() / "moved.token"));
}

TEST(NonceBook, EachNonceActsOnceWithinItsLifetime) {
  NonceBook book;
  const auto t0 = NonceBook::Clock::now();
  auto n = book.issue(t0);
  ASSERT_TRUE(n.ok());
  EXPECT_EQ(n->size(), 32u);
  EXPECT_TRUE(book.spend(*n, t0 + std::chrono::seconds(1)));
  EXPECT_FALSE(book.spend(*n, t0 + std::chrono::seconds(1))) << "a replay";
  auto old = book.issue(t0);
  EXPECT_FALSE(book.spend(*old, t0 + NonceBook::kNonceLifetime + std::chrono::seconds(1))) << "too old";
  EXPECT_FALSE(book.spend(*old, t0)) << "spent even when refused as too old";
  EXPECT_FALSE(book.spend("", t0));
  EXPECT_FALSE(book.spend(std::string(32, '0'), t0)) << "never issued";
  EXPECT_FALSE(book.spend(std::string(1 << 20, 'a'), t0));
  // The oldest is forgotten when more than kNonces are outstanding.
  auto first = book.issue(t0);
  for (int i = 0; i < NonceBook::kNonces; ++i) ASSERT_TRUE(book.issue(t0).ok());
  EXPECT_FALSE(book.spend(*first, t0));
}

OperatorView hold_view(std::uint32_t hold_id, double age_s) {
  OperatorView v;
  v.state = TrackingState::kHold;
  v.hold_id = hold_id;
  v.hold_age_s = age_s;
  return v;
}

OperatorRequest resume(std::uint32_t id) {
  OperatorRequest q;
  q.command = OperatorCommand::kResume;
  q.names_hold = true;
  q.hold_id = id;
  return q;
}

TEST(PageOperator, TheLoopJudgesEachActionAndAnswersIt) {
  PageOperator page;
  PollingLoop loop(&page, hold_view(123456, 2.0));
  auto right = page.submit(resume(123456), std::chrono::seconds(2));
  EXPECT_EQ(right.outcome, PageOperator::Verdict::Outcome::kAccepted);
  auto wrong = page.submit(resume(654321), std::chrono::seconds(2));
  EXPECT_EQ(wrong.outcome, PageOperator::Verdict::Outcome::kRefused);
  EXPECT_EQ(wrong.refusal, OperatorRefusal::kWrongHold);
  OperatorRequest no_id;
  no_id.command = OperatorCommand::kResume;
  EXPECT_EQ(page.submit(no_id, std::chrono::seconds(2)).refusal, OperatorRefusal::kNoHoldId);
  OperatorRequest stop;
  stop.command = OperatorCommand::kStop;
  EXPECT_EQ(page.submit(stop, std::chrono::seconds(2)).outcome, PageOperator::Verdict::Outcome::kAccepted);
}

TEST(PageOperator, TooSoonAndStaleResumesAreRefused) {
  PageOperator page;
  {
    PollingLoop loop(&page, hold_view(100001, 0.2));
    EXPECT_EQ(page.submit(resume(100001), std::chrono::seconds(2)).refusal, OperatorRefusal::kTooSoon);
  }
  OperatorView tracking;
  tracking.state = TrackingState::kTrack;
  PollingLoop loop(&page, tracking);
  EXPECT_EQ(page.submit(resume(100001), std::chrono::seconds(2)).refusal, OperatorRefusal::kNotApplicable);
}

TEST(PageOperator, AResumeSentBeforeTheHoldNeverActsOnIt) {
  PageOperator page;
  std::thread sender([&] {
    auto v = page.submit(resume(222222), std::chrono::seconds(3));
    EXPECT_EQ(v.outcome, PageOperator::Verdict::Outcome::kRefused);
    EXPECT_EQ(v.refusal, OperatorRefusal::kBeforeHold);
  });
  // Queued before the HOLD (however late the sender's thread runs), the loop has not polled.
  for (int i = 0; i < 2000 && page.waiting() == 0; ++i) std::this_thread::sleep_for(std::chrono::milliseconds(1));
  EXPECT_EQ(page.waiting(), 1);
  OperatorPoll at_hold;
  page.on_hold(hold_view(222222, 0), &at_hold);  // the loop enters HOLD 222222 now
  OperatorPoll poll;
  page.poll(hold_view(222222, 5.0), &poll);
  EXPECT_EQ(poll.command, OperatorCommand::kNone);
  EXPECT_EQ(poll.last_refusal, OperatorRefusal::kBeforeHold);
  sender.join();
}

TEST(PageOperator, AnUnansweredActionIsWithdrawnAndNeverActsLater) {
  PageOperator page;
  const auto v = page.submit(resume(333333), std::chrono::milliseconds(50));
  EXPECT_EQ(v.outcome, PageOperator::Verdict::Outcome::kNoAnswer);
  OperatorPoll poll;
  page.poll(hold_view(333333, 5.0), &poll);
  EXPECT_EQ(poll.command, OperatorCommand::kNone) << "withdrawn when its sender stopped waiting";
}

TEST(PageOperator, RefusalsBeforeTheLoopAreJournaledAtTheNextPoll) {
  PageOperator page;
  for (int i = 0; i < 5; ++i) page.refused_before_loop(OperatorRefusal::kBadToken);
  page.refused_before_loop(OperatorRefusal::kReplayed);
  page.refused_before_loop(OperatorRefusal::kOrigin);
  page.refused_before_loop(OperatorRefusal::kMalformed);
  OperatorPoll poll;
  page.poll(hold_view(1, 5), &poll);
  EXPECT_EQ(poll.refused, 8);
  EXPECT_EQ(poll.command, OperatorCommand::kNone);
  // Every kind counted, not only the last one polled.
  EXPECT_EQ(poll.by_reason[std::size_t(OperatorRefusal::kBadToken)], 5);
  EXPECT_EQ(poll.by_reason[std::size_t(OperatorRefusal::kReplayed)], 1);
  EXPECT_EQ(poll.by_reason[std::size_t(OperatorRefusal::kOrigin)], 1);
  EXPECT_EQ(poll.by_reason[std::size_t(OperatorRefusal::kMalformed)], 1);
  OperatorPoll next;
  page.poll(hold_view(1, 5), &next);
  EXPECT_EQ(next.refused, 0) << "each counted once";
}

TEST(PageOperator, AFloodIsBoundedAndAnsweredBusy) {
  PageOperator page;
  std::vector<std::thread> senders;
  std::atomic<int> busy{0};
  for (int i = 0; i < PageOperator::kSlots + 8; ++i)
    senders.emplace_back([&] {
      if (page.submit(resume(444444), std::chrono::milliseconds(300)).outcome == PageOperator::Verdict::Outcome::kBusy)
        ++busy;
    });
  for (auto& t : senders) t.join();
  EXPECT_GE(busy.load(), 8) << "no more than kSlots wait at once";
}

}  // namespace
}  // namespace lftrack::watch
