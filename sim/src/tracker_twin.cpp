#include "lftrack/sim/tracker_twin.hpp"

#include <arpa/inet.h>
#include <igtlPositionMessage.h>
#include <igtlTransformMessage.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include <cerrno>
#include <cmath>
#include <cstring>
#include <string>
#include <vector>

#include "lftrack/drivers/igtl_surrogate.hpp"
#include "lftrack/drivers/wall_clock.hpp"

namespace lftrack::sim {

namespace {

void twin_sleep_until_ns(std::int64_t t_ns) {
  timespec ts{};
  ts.tv_sec = time_t(t_ns / 1'000'000'000);
  ts.tv_nsec = long(t_ns % 1'000'000'000);
  while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, nullptr) == EINTR) {
  }
}

// The marker's message, made once and packed again for each reading: a tick allocates nothing (a
// simulated device in the loop's process must not look like the loop's allocations).
class MarkerMessage {
 public:
  explicit MarkerMessage(const TrackerTwinOptions& o) : stamp_(igtl::TimeStamp::New()) {
    if (o.position_messages) {
      position_ = igtl::PositionMessage::New();
      position_->SetPackType(
          igtl::PositionMessage::ALL);  // with its orientation (identity), as PLUS sends it
      position_->SetQuaternion(0.0f, 0.0f, 0.0f, 1.0f);
      message_ = position_;
    } else {
      transform_ = igtl::TransformMessage::New();
      message_ = transform_;
    }
    message_->SetDeviceName(o.device.c_str());
  }
  // Packs the marker at `p_room` measured at `wall_ns`; the bytes stay valid until the next call.
  void pack(const Eigen::Vector3d& p_room, std::int64_t wall_ns) {
    float ras[3] = {float(-p_room.x()), float(-p_room.y()), float(p_room.z())};
    if (position_) {
      position_->SetPosition(ras);
    } else {
      igtl::Matrix4x4 matrix;
      igtl::IdentityMatrix(matrix);
      for (int i = 0; i < 3; ++i) matrix[i][3] = ras[i];
      transform_->SetMatrix(matrix);
    }
    stamp_->SetTime(static_cast<igtlUint32>(wall_ns / 1'000'000'000),
                    static_cast<igtlUint32>(wall_ns % 1'000'000'000));
    message_->SetTimeStamp(stamp_);
    message_->Pack();
  }
  const char* data() const { return static_cast<const char*>(message_->GetPackPointer()); }
  std::size_t size() const { return std::size_t(message_->GetPackSize()); }

 private:
  igtl::TimeStamp::Pointer stamp_;
  igtl::MessageBase::Pointer message_;
  igtl::TransformMessage::Pointer transform_;
  igtl::PositionMessage::Pointer position_;
};

}  // namespace

Result<std::unique_ptr<TrackerTwin>> TrackerTwin::start(const TrackerTwinOptions& options, MarkerAt marker) {
  if (!(options.rate_hz >= 1 && options.rate_hz <= 1000))
    return invalid_argument("the tracker's rate must be 1 to 1000 Hz");
  if (options.port < 0 || options.port > 65535) return invalid_argument("port must be 0 to 65535");
  if (const std::string why = drivers::igtl_device_name_problem(options.device); !why.empty())
    return invalid_argument("device name \"" + options.device + "\": " + why);
  sockaddr_in at{};
  at.sin_family = AF_INET;
  at.sin_port = htons(std::uint16_t(options.port));
  if (inet_pton(AF_INET, options.address.c_str(), &at.sin_addr) != 1)
    return invalid_argument("not a dotted IPv4 address: " + options.address);
  std::unique_ptr<TrackerTwin> twin(new TrackerTwin());
  twin->options_ = options;
  twin->marker_ = std::move(marker);
  twin->listen_fd_ = ::socket(AF_INET, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
  if (twin->listen_fd_ < 0) return io_error(std::string("socket: ") + std::strerror(errno));
  const int one = 1;
  setsockopt(twin->listen_fd_, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
  if (::bind(twin->listen_fd_, reinterpret_cast<const sockaddr*>(&at), sizeof at) != 0 ||
      ::listen(twin->listen_fd_, 128) != 0)
    return io_error("the tracker's twin cannot listen on " + options.address + ":" +
                    std::to_string(options.port) + ": " + std::strerror(errno) +
                    (errno == EADDRINUSE
                         ? " (another server is there: stop it, or listen on another port; 0 takes "
                           "any free one)"
                     : errno == EADDRNOTAVAIL ? " (not an address of this host)"
                                              : ""));
  socklen_t length = sizeof at;
  getsockname(twin->listen_fd_, reinterpret_cast<sockaddr*>(&at), &length);
  twin->port_ = ntohs(at.sin_port);
  twin->thread_ = std::thread([t = twin.get()] { t->run(); });
  return twin;
}

TrackerTwin::~TrackerTwin() {
  stop_.store(true, std::memory_order_release);
  if (thread_.joinable()) thread_.join();
  if (listen_fd_ >= 0) ::close(listen_fd_);
}

void TrackerTwin::run() {
  if (options_.on_thread_start) options_.on_thread_start();
  std::vector<int> clients;
  clients.reserve(64);
  MarkerMessage message(options_);
  const auto period_ns = std::int64_t(std::llround(1e9 / options_.rate_hz));
  std::int64_t tick_ns = drivers::clock_now_ns(CLOCK_MONOTONIC);
  while (!stop_.load(std::memory_order_acquire)) {
    for (int fd; (fd = ::accept4(listen_fd_, nullptr, nullptr, SOCK_NONBLOCK | SOCK_CLOEXEC)) >= 0;) {
      const int one = 1;
      setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
      clients.push_back(fd);
      clients_total_.fetch_add(1, std::memory_order_relaxed);
    }
    Eigen::Vector3d p = Eigen::Vector3d::Zero();
    if (!clients.empty() && marker_(tick_ns, &p)) {
      const std::int64_t wall_ns = tick_ns + drivers::realtime_minus_monotonic_ns();
      message.pack(p, wall_ns);
      for (std::size_t i = 0; i < clients.size();) {
        const ssize_t n = ::send(clients[i], message.data(), message.size(), MSG_NOSIGNAL | MSG_DONTWAIT);
        if (n == ssize_t(message.size())) {
          sent_.fetch_add(1, std::memory_order_relaxed);
          ++i;
          continue;
        }
        ::close(clients[i]);  // gone, or too slow to take a whole message
        clients.erase(clients.begin() + std::ptrdiff_t(i));
      }
    }
    clients_.store(std::int64_t(clients.size()), std::memory_order_relaxed);
    tick_ns += period_ns;
    const std::int64_t now = drivers::clock_now_ns(CLOCK_MONOTONIC);
    if (tick_ns < now) tick_ns = now;  // late: the next tick now, not a burst of old ones
    twin_sleep_until_ns(tick_ns);
  }
  for (const int fd : clients) ::close(fd);
}

}  // namespace lftrack::sim
