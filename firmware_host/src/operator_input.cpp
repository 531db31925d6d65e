#include "lftrack/host/operator_input.hpp"

#include <fcntl.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/un.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>

namespace lftrack::host {

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

void OperatorPoll::refuse(OperatorRefusal why) {
  if (refused < 0xFFFF) ++refused;
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

// ---- control socket ----

namespace {

// With `remove_stale`, a stale socket is removed; without, only checked.
Status check_path_is_free(const std::string& p, bool remove_stale) {
  struct stat st {};
  if (::lstat(p.c_str(), &st) != 0) {
    if (errno == ENOENT) return {};
    return failed_precondition("control socket " + p + ": " + std::strerror(errno));
  }
  if (!S_ISSOCK(st.st_mode))
    return failed_precondition("control socket " + p +
                          ": a file that is not a socket is there; lftrack removes only a stale socket of "
                          "its own (choose another --control path)");
  if (st.st_uid != ::geteuid())
    return failed_precondition("control socket " + p + ": a socket of another user is there");
  // A socket nobody listens on is stale (an earlier run that was killed); a live one is refused.
  const int probe = ::socket(AF_UNIX, SOCK_DGRAM | SOCK_CLOEXEC, 0);
  if (probe < 0) return failed_precondition(std::string("control socket: ") + std::strerror(errno));
  sockaddr_un address{};
  address.sun_family = AF_UNIX;
  std::memcpy(address.sun_path, p.c_str(), p.size() + 1);
  const int connected = ::connect(probe, reinterpret_cast<const sockaddr*>(&address), sizeof address);
  const int connect_errno = errno;
  ::close(probe);
  if (connected == 0)
    return failed_precondition("control socket " + p + ": another process is listening on it (another lftrack run?)");
  if (connect_errno != ECONNREFUSED)
    return failed_precondition("control socket " + p + ": " + std::strerror(connect_errno));
  if (remove_stale && ::unlink(p.c_str()) != 0)
    return failed_precondition("control socket " + p + ": cannot remove the stale socket: " + std::strerror(errno));
  return {};
}

}  // namespace

Status ControlSocket::check_path(const std::filesystem::path& path) {
  const std::string p = path.string();
  if (p.empty() || p.size() >= sizeof(sockaddr_un::sun_path))
    return invalid_argument("control socket path '" + p + "' is empty or longer than " +
                            std::to_string(sizeof(sockaddr_un::sun_path) - 1) + " characters");
  return check_path_is_free(p, /*remove_stale=*/false);
}

Result<std::unique_ptr<ControlSocket>> ControlSocket::open(const std::filesystem::path& path) {
  sockaddr_un address{};
  const std::string p = path.string();
  if (p.empty() || p.size() >= sizeof(address.sun_path))
    return invalid_argument("control socket path '" + p + "' is empty or longer than " +
                            std::to_string(sizeof(address.sun_path) - 1) + " characters");
  LFTRACK_RETURN_IF_ERROR(check_path_is_free(p, /*remove_stale=*/true));
  std::unique_ptr<ControlSocket> s(new ControlSocket());
  s->fd_ = ::socket(AF_UNIX, SOCK_DGRAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
  if (s->fd_ < 0) return failed_precondition(std::string("control socket: ") + std::strerror(errno));
  const int on = 1;
  if (::setsockopt(s->fd_, SOL_SOCKET, SO_PASSCRED, &on, sizeof on) != 0)
    return failed_precondition(std::string("control socket: SO_PASSCRED: ") + std::strerror(errno));
  address.sun_family = AF_UNIX;
  std::memcpy(address.sun_path, p.c_str(), p.size() + 1);
  if (::bind(s->fd_, reinterpret_cast<const sockaddr*>(&address), sizeof address) != 0)
    return failed_precondition("control socket " + p + ": " + std::strerror(errno));
  s->path_ = path;  // from here on removed on destruction
  // Owner only, whatever the umask; a datagram that slipped in before the chmod is still checked
  // against its sender's credentials.
  if (::chmod(p.c_str(), 0600) != 0)
    return failed_precondition("control socket " + p + ": chmod 0600: " + std::strerror(errno));
  return s;
}

ControlSocket::~ControlSocket() {
  if (fd_ >= 0) ::close(fd_);
  if (!path_.empty()) ::unlink(path_.c_str());
}

bool ControlSocket::receive(char* text, std::size_t capacity, std::size_t* text_length, bool* sender_ok,
                            void* reply_to, unsigned* reply_to_length) {
  iovec io{text, capacity};
  alignas(cmsghdr) unsigned char control[CMSG_SPACE(sizeof(ucred))];
  msghdr m{};
  m.msg_name = reply_to;
  m.msg_namelen = sizeof(sockaddr_un);
  m.msg_iov = &io;
  m.msg_iovlen = 1;
  m.msg_control = control;
  m.msg_controllen = sizeof control;
  // MSG_TRUNC: the datagram's real length, so an over-long one is refused whole, never cut.
  const ssize_t n = ::recvmsg(fd_, &m, MSG_TRUNC);
  if (n < 0) return false;  // EAGAIN: nothing waiting
  *text_length = static_cast<std::size_t>(n);
  *reply_to_length = m.msg_namelen;
  *sender_ok = false;
  for (cmsghdr* c = CMSG_FIRSTHDR(&m); c != nullptr; c = CMSG_NXTHDR(&m, c)) {
    if (c->cmsg_level != SOL_SOCKET || c->cmsg_type != SCM_CREDENTIALS) continue;
    ucred who{};
    std::memcpy(&who, CMSG_DATA(c), sizeof who);
    *sender_ok = who.uid == ::geteuid() || who.uid == 0;
  }
  return true;
}

void ControlSocket::reply(const void* to, unsigned to_length, const char* line, std::size_t length) {
  if (to_length <= sizeof(sa_family_t)) return;  // an unnamed sender: nowhere to answer
  (void)::sendto(fd_, line, length, MSG_DONTWAIT | MSG_NOSIGNAL, static_cast<const sockaddr*>(to),
                 static_cast<socklen_t>(to_length));
}

void ControlSocket::poll(const OperatorView& view, OperatorPoll* out) {
  take_waiting(view, out, /*before_hold=*/false);
}

void ControlSocket::on_hold(const OperatorView& view, OperatorPoll* out) {
  take_waiting(view, out, /*before_hold=*/true);
}

void ControlSocket::take_waiting(const OperatorView& view, OperatorPoll* out, bool before_hold) {
  char text[64];
  char line[200];
  sockaddr_un from{};
  for (;;) {
    std::size_t length = 0;
    unsigned from_length = 0;
    bool sender_ok = false;
    if (!receive(text, sizeof text, &length, &sender_ok, &from, &from_length)) return;
    OperatorRequest q;
    OperatorRefusal why = OperatorRefusal::kNone;
    if (!sender_ok) {
      why = OperatorRefusal::kSender;
      ++refused_senders_;
    } else if (length > sizeof text || !parse_operator_request(text, length, &q)) {
      why = OperatorRefusal::kMalformed;
    } else if (before_hold && (q.command == OperatorCommand::kResume || q.command == OperatorCommand::kReset)) {
      why = OperatorRefusal::kBeforeHold;  // a stop still stops; a status is still answered
    } else {
      why = judge_operator_request(q, view, /*id_required=*/true);
    }
    if (!sender_ok) {
      out->refuse(why);
      continue;  // nothing is told to another user
    }
    int n = 0;
    if (why != OperatorRefusal::kNone) {
      out->refuse(why);
      n = std::snprintf(line, sizeof line, "refused: %s; the loop is %s", to_string(why), to_string(view.state));
    } else if (q.command == OperatorCommand::kStatus) {
      n = std::snprintf(line, sizeof line, "%s", to_string(view.state));
    } else {
      out->accept(q.command);
      n = std::snprintf(line, sizeof line, "accepted: %s", to_string(q.command));
    }
    const bool show_state = why != OperatorRefusal::kNone || q.command == OperatorCommand::kStatus;
    if (show_state && n > 0 && view.hold_id != 0 && std::size_t(n) < sizeof line)
      n += std::snprintf(line + n, sizeof line - std::size_t(n), " %u", view.hold_id);
    if (q.command == OperatorCommand::kStatus && why == OperatorRefusal::kNone && n > 0 && std::size_t(n) < sizeof line)
      n += std::snprintf(line + n, sizeof line - std::size_t(n), " cycle %lld: %s",
                         static_cast<long long>(view.cycle), view.reason);
    if (n <= 0) continue;
    if (std::size_t(n) >= sizeof line - 1) n = int(sizeof line) - 2;
    line[n++] = '\n';
    reply(&from, from_length, line, std::size_t(n));
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

}  // namespace lftrack::host
