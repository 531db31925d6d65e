// The control socket (operator_input.hpp): a Unix datagram socket of mode 0600 whose senders are
// checked by their credentials; every datagram is one whole command, judged and answered.

#include <fcntl.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/un.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstring>

#include "lftrack/loop/operator_input.hpp"

namespace lftrack::loop {

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
  // A bounded share of the cycle: a sender that writes as fast as this reads (issue 50 probe)
  // cannot keep the cycle here; what is left waits for the next cycle's poll, judged then.
  for (int taken = 0; taken < kMaxDatagramsPerPoll; ++taken) {
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

}  // namespace lftrack::loop
