#pragma once
// How an operator talks to the running loop: leaving HOLD is always an explicit action about the
// HOLD the operator saw (DESIGN.md, "The operator boundary"). The loop polls once per cycle;
// polling never blocks and never allocates.
//
//   terminal        single keys on the controlling terminal (raw mode while the loop runs):
//                   r = resume the HOLD on screen, x = reset the FAULT on screen, s = stop, q = quit
//   control socket  datagrams on a local (AF_UNIX) socket, each exactly one command:
//                   "resume ID", "reset ID", "stop", "quit", "status" (one trailing newline
//                   allowed); e.g.  echo resume 3 | socat - UNIX-SENDTO:/tmp/lftrack.sock
//                   A sender with an address of its own gets a one-line reply (accepted, refused
//                   and why, or the status: state, HOLD id, reason).
//   scripted        an unattended operator that resumes a set time after each HOLD (tests and
//                   benchmark runs; says so in the journal's reason)
//
// Staleness: every entry into HOLD or FAULT gets a new random hold id (six digits, so that no
// command written before the HOLD can name it), shown on the status line, in the journal, on
// stderr and by "status". A command only acts on the state it was given in: a resume outside HOLD
// (or a reset outside FAULT) is discarded, never kept for later; a resume or reset over the
// socket must name the current hold id; when the loop enters HOLD or FAULT, every resume or reset
// typed or sent before that moment is discarded (on_hold); a resume or reset counts only once the
// HOLD has been shown for kMinHoldBeforeResumeS; and on the terminal only a fresh key press counts
// (a held or auto-repeating key never does). Every discarded or refused command is counted in the
// cycle's journal record, by reason, with the first and the last reason (OperatorRefusals).

#include <array>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include "lftrack/loop/tracking_states.hpp"
#include "lftrack/tracking/status.hpp"

namespace lftrack::loop {

// When several arrive in one cycle, a quit or stop wins over a resume or reset (OperatorPoll).
enum class OperatorCommand : std::uint8_t { kNone, kResume, kStop, kReset, kQuit, kStatus };
const char* to_string(OperatorCommand command);

// Why a command did not act (journal: JournalRecord::operator_refusal).
enum class OperatorRefusal : std::uint8_t {
  kNone = 0,
  kNotApplicable,  // the loop is not in the state the command answers (a resume outside HOLD): stale
  kWrongHold,      // names another HOLD or FAULT than the one the loop is in
  kNoHoldId,       // a resume or reset over the socket must name the hold id it answers
  kMalformed,      // not exactly one command (unknown word, trailing text, over-long datagram)
  kSender,         // from another user than the one running lftrack (peer credentials)
  kBeforeHold,     // typed or sent before the loop entered this HOLD or FAULT
  kTooSoon,        // the HOLD has been shown for less than kMinHoldBeforeResumeS
  kKeyHeld,        // a key held down or repeating (a fresh press counts)
  // The monitor page's actions (watch/page_operator.hpp), judged before the loop sees them:
  kBadToken,  // no operator token, or the wrong one
  kReplayed,  // a request already used, or too old (its single-use nonce)
  kOrigin,    // from a page of another origin, or for another host
  // The command for the other stopped state (since 2026-11-29):
  kResumeInFault,  // a resume while the loop is in FAULT: only a reset leaves a FAULT
  kResetInHold,    // a reset while the loop is in HOLD: a HOLD is left by a resume
};
// Every OperatorRefusal value is below this (the journal keeps a count for each; room for more).
inline constexpr std::size_t kOperatorRefusalCodes = 16;

// How long a HOLD or FAULT must have been shown before a resume or reset counts (seconds on the
// loop's clock): no person decides faster, so anything earlier is a script or a held key.
inline constexpr double kMinHoldBeforeResumeS = 1.0;
const char* to_string(OperatorRefusal refusal);

struct OperatorRequest {
  OperatorCommand command = OperatorCommand::kNone;
  bool names_hold = false;
  std::uint32_t hold_id = 0;  // when names_hold
};

// Exactly "WORD" or "WORD ID" (WORD: resume, stop, reset, quit, status; ID: 1 to 4294967295 in
// decimal, no leading zero), optionally followed by one "\n"; nothing before, nothing after.
// False otherwise.
bool parse_operator_request(const char* text, std::size_t length, OperatorRequest* request);

// What the operator is answering: the loop as it stands at the poll.
struct OperatorView {
  TrackingState state = TrackingState::kIdle;
  std::uint32_t hold_id = 0;  // the current HOLD or FAULT; 0 in other states
  std::int64_t cycle = 0;
  std::int64_t cycles_in_state = 0;
  double hold_age_s = 0;    // how long the current HOLD or FAULT has been shown (loop clock)
  const char* reason = "";  // why the loop entered its state (static text)
};

// kNone when `request` may act on the loop as `view` shows it. A stop, quit or status always
// may; a resume only in HOLD and a reset only in FAULT, naming that hold id when `id_required`
// (or, without an id, only where the channel shows exactly one HOLD: a key on the terminal), and
// only once the HOLD has been shown for kMinHoldBeforeResumeS.
OperatorRefusal judge_operator_request(const OperatorRequest& request, const OperatorView& view,
                                       bool id_required);

// The commands refused or discarded in one cycle: how many in all and for each reason (each count
// saturating at 65535), and the first and the last reason. Plain data; never allocates.
struct OperatorRefusals {
  std::uint16_t refused = 0;
  OperatorRefusal first_refusal = OperatorRefusal::kNone;
  OperatorRefusal last_refusal = OperatorRefusal::kNone;
  std::array<std::uint16_t, kOperatorRefusalCodes> by_reason{};  // index: OperatorRefusal
  // Counts `count` commands refused for `why` (kNone counts nothing).
  void refuse(OperatorRefusal why, std::uint32_t count = 1);
};

// One poll's outcome: the command to act on (the highest-precedence accepted one) and the others,
// refused or discarded, by reason.
struct OperatorPoll : OperatorRefusals {
  OperatorCommand command = OperatorCommand::kNone;
  void accept(OperatorCommand c);
};

class OperatorInput {
 public:
  virtual ~OperatorInput() = default;
  // Takes everything waiting (never blocks) and judges it against `view`.
  virtual void poll(const OperatorView& view, OperatorPoll* out) = 0;
  // The loop has just entered HOLD or FAULT `view.hold_id`: a resume or reset that arrived
  // before this moment answers no HOLD the operator saw, and is discarded (counted in `out` as
  // kBeforeHold); a stop or quit is accepted into `out` (the loop acts on it next cycle).
  virtual void on_hold(const OperatorView& view, OperatorPoll* out) {
    (void)view;
    (void)out;
  }
  // True for an input that is no person: a script that answers HOLDs by itself. A session on the
  // room's devices refuses it (LoopSession::create), so that only a person's decision ends a HOLD
  // there.
  virtual bool unattended() const { return false; }
};

// Tells a fresh key press from a held or auto-repeating key: a key counts only when the same key
// was not seen in the `gap_ns` before it (auto-repeat sends one every 30-50 ms, and the loop
// reads the keys every cycle, so a held key is seen again and again).
class FreshKeyPress {
 public:
  explicit FreshKeyPress(std::int64_t gap_ns = 300'000'000) : gap_ns_(gap_ns) {}
  // Records the key seen at `now_ns`; true when it is a fresh press.
  bool seen(std::int64_t now_ns) {
    const bool fresh = !any_ || now_ns - last_ns_ >= gap_ns_;
    any_ = true;
    last_ns_ = now_ns;
    return fresh;
  }

 private:
  std::int64_t gap_ns_;
  std::int64_t last_ns_ = 0;
  bool any_ = false;
};

// Keys on standard input when it is a terminal (raw, non-blocking; restored on destruction).
class TerminalOperator final : public OperatorInput {
 public:
  // Fails when standard input is not a terminal.
  static Result<std::unique_ptr<TerminalOperator>> open();
  ~TerminalOperator() override;
  void poll(const OperatorView& view, OperatorPoll* out) override;
  void on_hold(const OperatorView& view, OperatorPoll* out) override;

 private:
  TerminalOperator() = default;
  // Judges one key; `now_ns` (CLOCK_MONOTONIC) tells a fresh press from a held one.
  void take_key(char key, const OperatorView& view, bool before_hold, std::int64_t now_ns, OperatorPoll* out);
  FreshKeyPress fresh_;
  bool restore_ = false;
  unsigned char saved_[64] = {};  // struct termios, kept opaque here
  int saved_flags_ = 0;
};

// A datagram socket at `path`, mode 0600, that takes commands only from the user running
// lftrack (or root), checked per datagram with SCM_CREDENTIALS. open() refuses a path that exists
// and is not a stale socket (a socket nobody listens on, owned by this user), so it never removes
// anyone's file; the socket is removed on destruction.
class ControlSocket final : public OperatorInput {
 public:
  static Result<std::unique_ptr<ControlSocket>> open(const std::filesystem::path& path);
  // What open() would refuse, checked without creating or removing anything.
  static Status check_path(const std::filesystem::path& path);
  ~ControlSocket() override;
  void poll(const OperatorView& view, OperatorPoll* out) override;
  void on_hold(const OperatorView& view, OperatorPoll* out) override;
  const std::filesystem::path& path() const { return path_; }
  std::uint64_t refused_senders() const { return refused_senders_; }

 private:
  ControlSocket() = default;
  // Receives one datagram; false when none is waiting. Sets *text_length (the datagram's real
  // length, which may exceed the buffer), *sender_ok and the reply address.
  bool receive(char* text, std::size_t capacity, std::size_t* text_length, bool* sender_ok,
               void* reply_to, unsigned* reply_to_length);
  void reply(const void* to, unsigned to_length, const char* line, std::size_t length);
  // Takes the waiting datagrams, at most kMaxDatagramsPerPoll (the rest wait for the next
  // poll): judged against `view`, or, `before_hold`, refused as sent before the HOLD (a status
  // is still answered). Replies to senders of this user that have an address.
  static constexpr int kMaxDatagramsPerPoll = 64;
  void take_waiting(const OperatorView& view, OperatorPoll* out, bool before_hold);
  int fd_ = -1;
  std::filesystem::path path_;
  std::uint64_t refused_senders_ = 0;
};

// Resumes the current HOLD `after_cycles` cycles into it (and resets a FAULT never).
class ScriptedOperator final : public OperatorInput {
 public:
  explicit ScriptedOperator(std::int64_t after_cycles) : after_cycles_(after_cycles) {}
  void poll(const OperatorView& view, OperatorPoll* out) override;
  bool unattended() const override { return true; }

 private:
  std::int64_t after_cycles_;
};

// Polls every input (each is drained every cycle); the highest-precedence accepted command wins.
class OperatorInputs final : public OperatorInput {
 public:
  void add(std::unique_ptr<OperatorInput> input) { inputs_.push_back(std::move(input)); }
  bool empty() const { return inputs_.empty(); }
  void poll(const OperatorView& view, OperatorPoll* out) override;
  void on_hold(const OperatorView& view, OperatorPoll* out) override;
  bool unattended() const override;  // any of them is

 private:
  std::vector<std::unique_ptr<OperatorInput>> inputs_;
};

// The longest --auto-resume a run takes (seconds): an unattended resume is for tests and
// benchmarks, not for leaving a HOLD alone for hours.
inline constexpr double kMaxAutoResumeS = 3600.0;
// Checks an --auto-resume value: finite, at least 0, at most kMaxAutoResumeS.
Status check_auto_resume_s(double seconds);

}  // namespace lftrack::loop
