#include "lftrack/host/operator_input.hpp"

#include <fcntl.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <termios.h>
#include <unistd.h>

#include <cerrno>
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
  }
  return "?";
}

OperatorCommand parse_operator_command(const char* text, std::size_t length) {
  std::size_t b = 0, e = length;
  while (b < e && (text[b] == ' ' || text[b] == '\n' || text[b] == '\r' || text[b] == '\t')) ++b;
  while (e > b && (text[e - 1] == ' ' || text[e - 1] == '\n' || text[e - 1] == '\r' || text[e - 1] == '\t'))
    --e;
  const auto is = [&](const char* word) {
    return e - b == std::strlen(word) && std::memcmp(text + b, word, e - b) == 0;
  };
  if (is("resume")) return OperatorCommand::kResume;
  if (is("stop")) return OperatorCommand::kStop;
  if (is("reset")) return OperatorCommand::kReset;
  if (is("quit")) return OperatorCommand::kQuit;
  return OperatorCommand::kNone;
}

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

OperatorCommand TerminalOperator::poll(TrackingState, std::int64_t) {
  char keys[16];
  const ssize_t n = ::read(STDIN_FILENO, keys, sizeof keys);
  for (ssize_t i = 0; i < n; ++i) {
    switch (keys[i]) {
      case 'r':
        return OperatorCommand::kResume;
      case 's':
        return OperatorCommand::kStop;
      case 'x':
        return OperatorCommand::kReset;
      case 'q':
        return OperatorCommand::kQuit;
      default:
        break;
    }
  }
  return OperatorCommand::kNone;
}

Result<std::unique_ptr<ControlSocket>> ControlSocket::open(const std::filesystem::path& path) {
  sockaddr_un address{};
  const std::string p = path.string();
  if (p.empty() || p.size() >= sizeof(address.sun_path))
    return invalid_argument("control socket path '" + p + "' is empty or longer than " +
                            std::to_string(sizeof(address.sun_path) - 1) + " characters");
  std::unique_ptr<ControlSocket> s(new ControlSocket());
  s->fd_ = ::socket(AF_UNIX, SOCK_DGRAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
  if (s->fd_ < 0) return failed_precondition(std::string("control socket: ") + std::strerror(errno));
  address.sun_family = AF_UNIX;
  std::memcpy(address.sun_path, p.c_str(), p.size() + 1);
  ::unlink(p.c_str());  // a stale socket of an earlier run
  if (::bind(s->fd_, reinterpret_cast<const sockaddr*>(&address), sizeof address) != 0)
    return failed_precondition("control socket " + p + ": " + std::strerror(errno));
  s->path_ = path;
  return s;
}

ControlSocket::~ControlSocket() {
  if (fd_ >= 0) ::close(fd_);
  if (!path_.empty()) ::unlink(path_.c_str());
}

OperatorCommand ControlSocket::poll(TrackingState, std::int64_t) {
  char message[64];
  for (;;) {
    const ssize_t n = ::recv(fd_, message, sizeof message, 0);
    if (n < 0) return OperatorCommand::kNone;  // EAGAIN: nothing waiting
    const OperatorCommand c = parse_operator_command(message, static_cast<std::size_t>(n));
    if (c != OperatorCommand::kNone) return c;  // unknown datagrams are dropped
  }
}

OperatorCommand ScriptedOperator::poll(TrackingState state, std::int64_t cycles_in_state) {
  if (state == TrackingState::kHold && cycles_in_state >= after_cycles_) return OperatorCommand::kResume;
  return OperatorCommand::kNone;
}

OperatorCommand OperatorInputs::poll(TrackingState state, std::int64_t cycles_in_state) {
  for (auto& input : inputs_)
    if (const OperatorCommand c = input->poll(state, cycles_in_state); c != OperatorCommand::kNone) return c;
  return OperatorCommand::kNone;
}

}  // namespace lftrack::host
