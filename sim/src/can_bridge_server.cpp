#include "lftrack/sim/can_bridge_server.hpp"

#include <poll.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/un.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

namespace lftrack::sim {

namespace {

// A socket file nobody listens on (connect refused) is stale and may be replaced.
bool is_stale_socket(const std::filesystem::path& path, const sockaddr_un& address) {
  struct stat st {};
  if (::lstat(path.c_str(), &st) != 0 || !S_ISSOCK(st.st_mode)) return false;
  const int probe = ::socket(AF_UNIX, SOCK_SEQPACKET | SOCK_CLOEXEC, 0);
  if (probe < 0) return false;
  const bool refused = ::connect(probe, reinterpret_cast<const sockaddr*>(&address), sizeof address) != 0 &&
                       errno == ECONNREFUSED;
  ::close(probe);
  return refused;
}

}  // namespace

Result<std::unique_ptr<CanBridgeServer>> CanBridgeServer::start(const std::filesystem::path& path,
                                                                drivers::Actuator* device,
                                                                const VirtualRobotOptions& options) {
  if (device == nullptr) return invalid_argument("CAN bridge: no robot device");
  sockaddr_un address{};
  address.sun_family = AF_UNIX;
  const std::string p = path.string();
  if (p.empty() || p.size() >= sizeof address.sun_path)
    return invalid_argument("CAN bridge socket path must be 1 to " + std::to_string(sizeof address.sun_path - 1) +
                            " bytes: " + p);
  std::memcpy(address.sun_path, p.data(), p.size());
  std::error_code ec;
  if (std::filesystem::exists(std::filesystem::symlink_status(path, ec))) {
    if (!is_stale_socket(path, address))
      return failed_precondition("CAN bridge " + p + ": something is there (a file, or a bridge that is running); "
                                 "refusing to replace it");
    std::filesystem::remove(path, ec);
  }
  const int fd = ::socket(AF_UNIX, SOCK_SEQPACKET | SOCK_CLOEXEC, 0);
  if (fd < 0) return io_error(std::string("CAN bridge: socket: ") + std::strerror(errno));
  if (::bind(fd, reinterpret_cast<sockaddr*>(&address), sizeof address) != 0 || ::chmod(p.c_str(), 0600) != 0 ||
      ::listen(fd, 4) != 0) {
    const int e = errno;
    ::close(fd);
    return io_error("CAN bridge " + p + ": " + std::strerror(e));
  }
  std::unique_ptr<CanBridgeServer> server(new CanBridgeServer(path, fd, device, options));
  server->thread_ = std::thread([s = server.get()] { s->accept_loop(); });
  return server;
}

CanBridgeServer::~CanBridgeServer() {
  stop_.store(true);
  if (thread_.joinable()) thread_.join();
  {
    std::lock_guard lock(mutex_);
    robot_.reset();
  }
  ::close(listen_fd_);
  std::error_code ec;
  std::filesystem::remove(path_, ec);
}

bool CanBridgeServer::linked() const {
  std::lock_guard lock(mutex_);
  return robot_ && !robot_->link_closed();
}

void CanBridgeServer::unplug() {
  std::lock_guard lock(mutex_);
  robot_.reset();  // closes the robot's end: the driver reads end of file
}

bool CanBridgeServer::inject(RobotFault fault) {
  std::lock_guard lock(mutex_);
  if (!robot_ || robot_->link_closed()) return false;
  robot_->inject(fault);
  return true;
}

void CanBridgeServer::accept_loop() {
  while (!stop_.load()) {
    pollfd p{listen_fd_, POLLIN, 0};
    if (::poll(&p, 1, 50) <= 0) continue;
    const int fd = ::accept4(listen_fd_, nullptr, nullptr, SOCK_CLOEXEC);
    if (fd < 0) continue;
    std::lock_guard lock(mutex_);
    if (robot_ && !robot_->link_closed()) {  // one controller at a time
      ::close(fd);
      ++refused_;
      continue;
    }
    robot_.reset();
    auto robot = VirtualRobot::start(device_, fd, options_);
    if (!robot.ok()) {  // the robot takes the socket only when it starts
      ::close(fd);
      continue;
    }
    robot_ = std::move(robot).value();
    ++connections_;
  }
}

}  // namespace lftrack::sim
