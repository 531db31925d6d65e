// Operator commands (operator_input.hpp): parsing and judging a request against the loop's state,
// the terminal's keys, the scripted operator, and several inputs read as one.

#include "lftrack/loop/operator_input.hpp"

#include <fcntl.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>

namespace lftrack::loop {

static_assert(sizeof(termios) <= 64, "TerminalOperator keeps a termios in 64 bytes");

const char* to_string(OperatorCommand c) {
  switch (c) {
    case OperatorCommand::kNone:
      return "none";
    case OperatorCommand::kResume:
      return "resume";
    case OperatorCommand::kStop:
      return "stop";
    case OperatorCommand::kReset:
      return "reset";
    case OperatorCommand::kQuit:
      return "quit";
    case OperatorCommand::kStatus:
      return "status";
  }
  return "?";
}

const char* to_string(OperatorRefusal r) {
  switch (r) {
    case OperatorRefusal::kNone:
      return "";
    case OperatorRefusal::kNotApplicable:
      return "not in the state it answers (stale)";
    case OperatorRefusal::kWrongHold:
      return "names another HOLD";
    case OperatorRefusal::kNoHoldId:
      return "does not name the HOLD it answers";
    case OperatorRefusal::kMalformed:
      return "not exactly one command";
    case OperatorRefusal::kSender:
      return "sender is another user";
    case OperatorRefusal::kBeforeHold:
      return "sent before the HOLD";
    case OperatorRefusal::kTooSoon:
      return "the HOLD has been shown for less than a second";
    case OperatorRefusal::kKeyHeld:
      return "key held down (press it again)";
    case OperatorRefusal::kBadToken:
      return "no operator token, or a wrong one";
    case OperatorRefusal::kReplayed:
      return "replayed or stale request";
    case OperatorRefusal::kOrigin:
      return "from another origin or host";
    case OperatorRefusal::kResumeInFault:
      return "in FAULT: a resume answers a HOLD; use reset";
    case OperatorRefusal::kResetInHold:
      return "in HOLD: a reset answers a FAULT; use resume";
  }
  return "?";
}

bool parse_operator_request(const char* text, std::size_t length, OperatorRequest* request) {
  *request = {};
  if (length > 0 && text[length - 1] == '\n') --length;  // echo's newline
  std::size_t word_end = 0;
  while (word_end < length && text[word_end] >= 'a' && text[word_end] <= 'z') ++word_end;
  const auto is = [&](const char* word) {
    return word_end == std::strlen(word) && std::memcmp(text, word, word_end) == 0;
  };
  OperatorCommand c = OperatorCommand::kNone;
  if (is("resume")) c = OperatorCommand::kResume;
  if (is("stop")) c = OperatorCommand::kStop;
  if (is("reset")) c = OperatorCommand::kReset;
  if (is("quit")) c = OperatorCommand::kQuit;
  if (is("status")) c = OperatorCommand::kStatus;
  if (c == OperatorCommand::kNone) return false;
  if (word_end == length) {
    request->command = c;
    return true;
  }
  // " ID": one space, then 1 to 10 digits, nothing else.
  if (text[word_end] != ' ' || length - word_end - 1 < 1 || length - word_end - 1 > 10) return false;
  if (text[word_end + 1] == '0') return false;  // no leading zero: one spelling per id
  std::uint64_t id = 0;
  for (std::size_t i = word_end + 1; i < length; ++i) {
    if (text[i] < '0' || text[i] > '9') return false;
    id = id * 10 + std::uint64_t(text[i] - '0');
  }
  if (id == 0 || id > 0xFFFFFFFFull) return false;
  request->command = c;
  request->names_hold = true;
  request->hold_id = static_cast<std::uint32_t>(id);
  return true;
}

OperatorRefusal judge_operator_request(const OperatorRequest& q, const OperatorView& view, bool id_required) {
  TrackingState answers = TrackingState::kIdle;
  switch (q.command) {
    case OperatorCommand::kNone:
      return OperatorRefusal::kMalformed;
    case OperatorCommand::kStop:
    case OperatorCommand::kQuit:
    case OperatorCommand::kStatus:
      return OperatorRefusal::kNone;  // stopping is always safe; status changes nothing
    case OperatorCommand::kResume:
      answers = TrackingState::kHold;
      break;
    case OperatorCommand::kReset:
      answers = TrackingState::kFault;
      break;
  }
  // The other stopped state's command: say which one it needs, not "stale".
  if (view.hold_id != 0 && q.command == OperatorCommand::kResume && view.state == TrackingState::kFault)
    return OperatorRefusal::kResumeInFault;
  if (view.hold_id != 0 && q.command == OperatorCommand::kReset && view.state == TrackingState::kHold)
    return OperatorRefusal::kResetInHold;
  if (view.state != answers || view.hold_id == 0) return OperatorRefusal::kNotApplicable;
  if (!q.names_hold && id_required) return OperatorRefusal::kNoHoldId;
  if (q.names_hold && q.hold_id != view.hold_id) return OperatorRefusal::kWrongHold;
  if (!(view.hold_age_s >= kMinHoldBeforeResumeS)) return OperatorRefusal::kTooSoon;
  return OperatorRefusal::kNone;
}

namespace {
int precedence(OperatorCommand c) {
  switch (c) {
    case OperatorCommand::kQuit:
      return 4;
    case OperatorCommand::kStop:
      return 3;
    case OperatorCommand::kReset:
    case OperatorCommand::kResume:
      return 2;
    case OperatorCommand::kStatus:
      return 1;
    case OperatorCommand::kNone:
      return 0;
  }
  return 0;
}
}  // namespace

void OperatorPoll::accept(OperatorCommand c) {
  if (precedence(c) > precedence(command)) command = c;
}

void OperatorRefusals::refuse(OperatorRefusal why, std::uint32_t count) {
  if (why == OperatorRefusal::kNone || count == 0) return;
  const auto add = [count](std::uint16_t* n) { *n = static_cast<std::uint16_t>(std::min<std::uint32_t>(0xFFFF, *n + count)); };
  add(&refused);
  const auto code = static_cast<std::size_t>(why);
  if (code < by_reason.size()) add(&by_reason[code]);
  if (first_refusal == OperatorRefusal::kNone) first_refusal = why;
  last_refusal = why;
}

Status check_auto_resume_s(double s) {
  if (!std::isfinite(s) || s < 0 || s > kMaxAutoResumeS) {
    char text[160];
    std::snprintf(text, sizeof text,
                  "auto-resume %g s: seconds into each HOLD must be from 0 to %g (NaN, infinite and negative "
                  "values are refused)",
                  s, kMaxAutoResumeS);
    return invalid_argument(text);
  }
  return {};
}

// ---- terminal ----

Result<std::unique_ptr<TerminalOperator>> TerminalOperator::open() {
  if (::isatty(STDIN_FILENO) != 1) return failed_precondition("standard input is not a terminal");
  std::unique_ptr<TerminalOperator> t(new TerminalOperator());
  termios saved{};
  if (::tcgetattr(STDIN_FILENO, &saved) != 0)
    return failed_precondition(std::string("tcgetattr: ") + std::strerror(errno));
  std::memcpy(t->saved_, &saved, sizeof saved);
  termios raw = saved;
  raw.c_lflag &= static_cast<tcflag_t>(~(ICANON | ECHO));
  raw.c_cc[VMIN] = 0;
  raw.c_cc[VTIME] = 0;
  if (::tcsetattr(STDIN_FILENO, TCSANOW, &raw) != 0)
    return failed_precondition(std::string("tcsetattr: ") + std::strerror(errno));
  t->saved_flags_ = ::fcntl(STDIN_FILENO, F_GETFL);
  ::fcntl(STDIN_FILENO, F_SETFL, t->saved_flags_ | O_NONBLOCK);
  t->restore_ = true;
  return t;
}

TerminalOperator::~TerminalOperator() {
  if (!restore_) return;
  termios saved{};
  std::memcpy(&saved, saved_, sizeof saved);
  ::tcsetattr(STDIN_FILENO, TCSANOW, &saved);
  ::fcntl(STDIN_FILENO, F_SETFL, saved_flags_);
}

namespace {
std::int64_t monotonic_ns() {
  timespec t{};
  ::clock_gettime(CLOCK_MONOTONIC, &t);
  return std::int64_t(t.tv_sec) * 1'000'000'000 + t.tv_nsec;
}
}  // namespace

void TerminalOperator::take_key(char key, const OperatorView& view, bool before_hold, std::int64_t now_ns,
                                OperatorPoll* out) {
  OperatorRequest q;
  switch (key) {
    case 'r':
      q.command = OperatorCommand::kResume;  // the HOLD on the status line
      break;
    case 'x':
      q.command = OperatorCommand::kReset;
      break;
    case 's':
      out->accept(OperatorCommand::kStop);  // a stop always stops
      return;
    case 'q':
      out->accept(OperatorCommand::kQuit);
      return;
    default:
      return;  // other keys mean nothing
  }
  const bool fresh = fresh_.seen(now_ns);
  OperatorRefusal why = before_hold ? OperatorRefusal::kBeforeHold
                        : !fresh    ? OperatorRefusal::kKeyHeld
                                    : judge_operator_request(q, view, /*id_required=*/false);
  if (why == OperatorRefusal::kNone)
    out->accept(q.command);
  else
    out->refuse(why);
}

void TerminalOperator::poll(const OperatorView& view, OperatorPoll* out) {
  char keys[64];
  for (;;) {  // every key waiting: none is left for a later state
    const ssize_t n = ::read(STDIN_FILENO, keys, sizeof keys);
    if (n <= 0) return;
    const std::int64_t now = monotonic_ns();
    for (ssize_t i = 0; i < n; ++i) take_key(keys[i], view, /*before_hold=*/false, now, out);
  }
}

void TerminalOperator::on_hold(const OperatorView& view, OperatorPoll* out) {
  char keys[64];
  for (;;) {
    const ssize_t n = ::read(STDIN_FILENO, keys, sizeof keys);
    if (n <= 0) return;
    const std::int64_t now = monotonic_ns();
    for (ssize_t i = 0; i < n; ++i) take_key(keys[i], view, /*before_hold=*/true, now, out);
  }
}

// ---- scripted and several ----

void ScriptedOperator::poll(const OperatorView& view, OperatorPoll* out) {
  // An unattended operator the user set up at the start (--auto-resume): its own delay, not the
  // person's minimum, applies.
  if (view.state == TrackingState::kHold && view.hold_id != 0 && view.cycles_in_state >= after_cycles_)
    out->accept(OperatorCommand::kResume);
}

void OperatorInputs::poll(const OperatorView& view, OperatorPoll* out) {
  for (auto& input : inputs_) input->poll(view, out);
}

void OperatorInputs::on_hold(const OperatorView& view, OperatorPoll* out) {
  for (auto& input : inputs_) input->on_hold(view, out);
}

bool OperatorInputs::unattended() const {
  for (const auto& input : inputs_)
    if (input->unattended()) return true;
  return false;
}

}  // namespace lftrack::loop
