#include "lftrack/drivers/igtl_surrogate.hpp"

#include <fcntl.h>
#include <igtlMessageHeader.h>
#include <igtl_util.h>
#include <netdb.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstring>
#include <vector>

namespace lftrack::drivers {

namespace {

std::int64_t clock_ns(clockid_t clock) {
  timespec ts{};
  clock_gettime(clock, &ts);
  return std::int64_t{ts.tv_sec} * 1'000'000'000 + ts.tv_nsec;
}

// OpenIGTLink's header (58 bytes, big-endian): version 2, type 12, device name 20, time stamp 8,
// body size 8, CRC 8. The body size is read here as the 64-bit number it is: the library gives it
// as an int, which a hostile or broken peer's 2^40 would wrap.
constexpr int kHeaderBytes = 58;
std::uint64_t big_endian_u64(const unsigned char* at) {
  std::uint64_t value = 0;
  for (int i = 0; i < 8; ++i) value = (value << 8) | at[i];
  return value;
}
std::uint64_t header_body_bytes(const unsigned char* header) {
  return big_endian_u64(header + 42);
}
std::uint64_t header_crc(const unsigned char* header) {
  return big_endian_u64(header + 50);
}

// The marker's position from a message body whose CRC is `crc`: a TRANSFORM's (48 bytes: the
// rotation's 9 and then the translation's 3 big-endian float32) or a POSITION's (12, 24 or 28
// bytes: x, y, z, then 3 or 4 quaternion components). The bodies are read here, their CRC by the
// library's crc64: the library's message classes allocate on every message (SetMessageHeader,
// AllocatePack), which the thread that feeds the cycle must not, and its PositionMessage
// unpacks a 12- or 24-byte body as if it held 28 (reading past it).
bool body_position(bool transform, const unsigned char* body, std::uint64_t bytes, std::uint64_t crc,
                   float position[3]) {
  if (transform ? bytes != 48 : bytes != 12 && bytes != 24 && bytes != 28) return false;
  if (::crc64(const_cast<unsigned char*>(body), bytes, 0) != crc) return false;
  const unsigned char* at = transform ? body + 36 : body;
  for (int i = 0; i < 3; ++i) {
    std::uint32_t word = 0;
    for (int b = 0; b < 4; ++b) word = (word << 8) | at[4 * i + b];
    std::memcpy(&position[i], &word, sizeof word);
  }
  return true;
}

// A non-blocking TCP connection to host:port within timeout_ms, or an error naming it.
Result<int> connect_to(const std::string& host, int port, int timeout_ms) {
  addrinfo hints{};
  hints.ai_family = AF_INET;
  hints.ai_socktype = SOCK_STREAM;
  addrinfo* found = nullptr;
  const std::string where = host + ":" + std::to_string(port);
  if (const int rc = getaddrinfo(host.c_str(), std::to_string(port).c_str(), &hints, &found); rc != 0)
    return not_found("no address for " + where + ": " + gai_strerror(rc));
  const int fd = ::socket(found->ai_family, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
  if (fd < 0) {
    freeaddrinfo(found);
    return io_error(std::string("socket: ") + std::strerror(errno));
  }
  int rc = ::connect(fd, found->ai_addr, found->ai_addrlen);
  freeaddrinfo(found);
  if (rc != 0 && errno == EINPROGRESS) {
    pollfd p{fd, POLLOUT, 0};
    rc = ::poll(&p, 1, timeout_ms);
    if (rc == 0) {
      ::close(fd);
      return io_error("no answer from " + where + " within " + std::to_string(timeout_ms) + " ms");
    }
    int error = 0;
    socklen_t length = sizeof error;
    if (rc < 0 || getsockopt(fd, SOL_SOCKET, SO_ERROR, &error, &length) != 0) error = errno;
    if (error != 0) errno = error;
    rc = error == 0 ? 0 : -1;
  }
  if (rc != 0) {
    const int error = errno;
    ::close(fd);
    return io_error("cannot connect to " + where + ": " + std::strerror(error));
  }
  const int one = 1;
  setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
  return fd;
}

enum class Got { kAll, kClosed, kStopped, kTimedOut };

// Reads exactly `length` bytes, looking at `stop` every 100 ms; gives up at `deadline_ns`
// (CLOCK_MONOTONIC; 0: none).
Got read_fully(int fd, void* data, std::size_t length, const std::atomic<bool>& stop,
               std::int64_t deadline_ns) {
  auto* at = static_cast<char*>(data);
  std::size_t got = 0;
  while (got < length) {
    if (stop.load(std::memory_order_acquire)) return Got::kStopped;
    if (deadline_ns > 0 && clock_ns(CLOCK_MONOTONIC) > deadline_ns) return Got::kTimedOut;
    pollfd p{fd, POLLIN, 0};
    const int ready = ::poll(&p, 1, 100);
    if (ready < 0 && errno != EINTR) return Got::kClosed;
    if (ready <= 0) continue;
    const ssize_t n = ::recv(fd, at + got, length - got, MSG_DONTWAIT);
    if (n == 0) return Got::kClosed;
    if (n < 0) {
      if (errno == EAGAIN || errno == EWOULDBLOCK || errno == EINTR) continue;
      return Got::kClosed;
    }
    got += std::size_t(n);
  }
  return Got::kAll;
}

// The rest of a message, once its header has come, must follow within this.
constexpr std::int64_t kBodyDeadlineNs = 1'000'000'000;

}  // namespace

IgtlSurrogateSource::IgtlSurrogateSource(const IgtlSurrogateOptions& options) : options_(options) {}

IgtlSurrogateSource::~IgtlSurrogateSource() {
  close();
}

Status IgtlSurrogateSource::open() {
  if (thread_.joinable()) return failed_precondition("the OpenIGTLink surrogate is already open");
  if (!(options_.axis_room.allFinite() && std::abs(options_.axis_room.norm() - 1) < 1e-6))
    return invalid_argument("the surrogate's axis must be a unit vector");
  auto fd = connect_to(options_.host, options_.port, options_.connect_timeout_ms);
  if (!fd.ok())
    return fd.status().with_context(
        "surrogate.igtl: the optical tracker's OpenIGTLink server (PLUS listens on 18944); is it running?");
  first_fd_ = *fd;
  stop_.store(false, std::memory_order_release);
  thread_ = std::thread([this] { run(); });
  return {};
}

void IgtlSurrogateSource::close() {
  stop_.store(true, std::memory_order_release);
  if (thread_.joinable()) {
    thread_.join();
    const IgtlSurrogateCounters c = counters();
    spdlog::info(
        "surrogate: {} readings from {}:{} over {} connection(s); refused {} stale, {} from the future, {} "
        "out of "
        "order; {} other messages skipped, {} protocol errors, {} unread",
        c.readings, options_.host, options_.port, c.connections, c.refused_stale, c.refused_future,
        c.refused_order, c.ignored, c.protocol_errors, c.dropped_unread);
  }
  if (first_fd_ >= 0) ::close(first_fd_);
  first_fd_ = -1;
  connected_.store(false, std::memory_order_release);
}

void IgtlSurrogateSource::run() {
  int fd = first_fd_;
  first_fd_ = -1;
  const std::string where = options_.host + ":" + std::to_string(options_.port);
  bool said_lost = false;
  while (!stop_.load(std::memory_order_acquire)) {
    if (fd < 0) {
      auto again = connect_to(options_.host, options_.port, options_.connect_timeout_ms);
      if (!again.ok()) {
        if (!said_lost)
          spdlog::warn("surrogate: {} (retrying every {} ms)", again.status().message(), options_.retry_ms);
        said_lost = true;
        const std::int64_t until = clock_ns(CLOCK_MONOTONIC) + std::int64_t{options_.retry_ms} * 1'000'000;
        while (!stop_.load(std::memory_order_acquire) && clock_ns(CLOCK_MONOTONIC) < until)
          std::this_thread::sleep_for(std::chrono::milliseconds(10));
        continue;
      }
      fd = *again;
      if (said_lost) spdlog::info("surrogate: connected to {} again", where);
      said_lost = false;
    }
    connections_.fetch_add(1, std::memory_order_relaxed);
    connected_.store(true, std::memory_order_release);
    const bool stopped = serve_connection(fd);
    connected_.store(false, std::memory_order_release);
    ::close(fd);
    fd = -1;
    if (stopped) break;
    if (!said_lost) spdlog::warn("surrogate: the connection to {} ended; reconnecting", where);
    said_lost = true;
  }
  if (fd >= 0) ::close(fd);
}

// One connection's messages, until it ends (false) or close() (true).
bool IgtlSurrogateSource::serve_connection(int fd) {
  std::vector<char> skipped(4096);
  const auto ended = [&](Got got) {
    if (got == Got::kTimedOut) protocol_errors_.fetch_add(1, std::memory_order_relaxed);
    return got == Got::kStopped;
  };
  // Made once per connection and reused: a message read allocates nothing.
  igtl::MessageHeader::Pointer header = igtl::MessageHeader::New();
  igtl::TimeStamp::Pointer stamp = igtl::TimeStamp::New();
  while (true) {
    header->InitPack();
    if (header->GetPackSize() != kHeaderBytes) return false;  // not the library this was written for
    if (const Got got = read_fully(fd, header->GetPackPointer(), kHeaderBytes, stop_, 0); got != Got::kAll)
      return ended(got);
    const std::int64_t arrived_ns = clock_ns(CLOCK_MONOTONIC);
    const std::int64_t wall_minus_mono_ns = clock_ns(CLOCK_REALTIME) - arrived_ns;
    // Read before Unpack(), which turns the header's bytes to this host's order in place.
    const auto* raw_header = static_cast<const unsigned char*>(header->GetPackPointer());
    const std::uint64_t body_bytes = header_body_bytes(raw_header), body_crc = header_crc(raw_header);
    if (!(header->Unpack() & igtl::MessageHeader::UNPACK_HEADER) ||
        body_bytes > std::uint64_t(options_.max_body_bytes)) {
      protocol_errors_.fetch_add(1, std::memory_order_relaxed);
      spdlog::warn("surrogate: not an OpenIGTLink message (a body of {} bytes); dropping the connection",
                   body_bytes);
      return false;
    }
    const std::int64_t body_deadline = arrived_ns + kBodyDeadlineNs;
    const bool is_transform = std::strcmp(header->GetDeviceType(), "TRANSFORM") == 0;
    const bool wanted = (is_transform || std::strcmp(header->GetDeviceType(), "POSITION") == 0) &&
                        (options_.device.empty() || options_.device == header->GetDeviceName());
    const char* type = is_transform ? "TRANSFORM" : "POSITION";
    if (!wanted) {
      for (std::uint64_t left = body_bytes; left > 0;) {
        const std::size_t part = std::size_t(std::min<std::uint64_t>(left, skipped.size()));
        if (const Got got = read_fully(fd, skipped.data(), part, stop_, body_deadline); got != Got::kAll)
          return ended(got);
        left -= part;
      }
      ignored_.fetch_add(1, std::memory_order_relaxed);
      continue;
    }
    float position_ras[3] = {0, 0, 0};
    unsigned char body[48];
    if (body_bytes > (is_transform ? 48u : 28u)) {
      protocol_errors_.fetch_add(1, std::memory_order_relaxed);
      spdlog::warn("surrogate: a {} of {} bytes ({}); dropping the connection", type, body_bytes,
                   is_transform ? "48 expected" : "12, 24 or 28 expected");
      return false;
    }
    if (const Got got = read_fully(fd, body, body_bytes, stop_, body_deadline); got != Got::kAll)
      return ended(got);
    if (!body_position(is_transform, body, body_bytes, body_crc, position_ras)) {
      protocol_errors_.fetch_add(1, std::memory_order_relaxed);
      spdlog::warn("surrogate: a {} message of {} bytes failed its CRC or size; dropping the connection",
                   type, body_bytes);
      return false;
    }
    const Eigen::Vector3d p_room(-double(position_ras[0]), -double(position_ras[1]), double(position_ras[2]));
    igtlUint32 seconds = 0, nanoseconds = 0;
    header->GetTimeStamp(stamp);
    stamp->GetTimeStamp(&seconds, &nanoseconds);
    const std::int64_t stamp_wall_ns = std::int64_t{seconds} * 1'000'000'000 + std::int64_t{nanoseconds};
    const std::int64_t measured_ns = stamp_wall_ns == 0 ? arrived_ns : stamp_wall_ns - wall_minus_mono_ns;
    take(measured_ns, arrived_ns, stamp_wall_ns, options_.axis_room.dot(p_room));
  }
}

void IgtlSurrogateSource::take(std::int64_t measured_ns, std::int64_t arrived_ns, std::int64_t stamp_wall_ns,
                               double amplitude) {
  if (double(arrived_ns - measured_ns) > options_.stale_ms * 1e6) {
    refused_stale_.fetch_add(1, std::memory_order_relaxed);
    return;
  }
  if (double(measured_ns - arrived_ns) > options_.future_ms * 1e6) {
    refused_future_.fetch_add(1, std::memory_order_relaxed);
    return;
  }
  // A repeated time stamp is compared as sent: its conversion to this host's clock moves with the
  // nanoseconds between reading the two clocks.
  if (measured_ns <= last_taken_ns_ || (stamp_wall_ns != 0 && stamp_wall_ns <= last_stamp_wall_ns_)) {
    refused_order_.fetch_add(1, std::memory_order_relaxed);
    return;
  }
  last_taken_ns_ = measured_ns;
  if (stamp_wall_ns != 0) last_stamp_wall_ns_ = stamp_wall_ns;
  {
    const std::lock_guard<std::mutex> lock(ring_mutex_);
    if (ring_written_ - ring_read_ == kRing) {  // the loop has not asked for a while: its oldest go
      ++ring_read_;
      dropped_unread_.fetch_add(1, std::memory_order_relaxed);
    }
    ring_[ring_written_ % kRing] = SurrogateReading{measured_ns, amplitude};
    ++ring_written_;
  }
  readings_.fetch_add(1, std::memory_order_relaxed);
}

int IgtlSurrogateSource::read(std::int64_t now_ns, SurrogateReading* out, int capacity) {
  if (capacity <= 0) return 0;
  const std::unique_lock<std::mutex> lock(ring_mutex_, std::try_to_lock);
  if (!lock.owns_lock()) return 0;  // the reader thread is writing one: the next cycle takes it
  // Readings up to now_ns, oldest first; of more than `capacity`, the newest.
  std::uint64_t end = ring_read_;
  while (end < ring_written_ && ring_[end % kRing].t_ns <= now_ns) ++end;
  const std::uint64_t begin =
      std::max(ring_read_, end - std::min<std::uint64_t>(end, std::uint64_t(capacity)));
  int n = 0;
  for (std::uint64_t i = begin; i < end; ++i) out[n++] = ring_[i % kRing];
  ring_read_ = end;
  return n;
}

IgtlSurrogateCounters IgtlSurrogateSource::counters() const {
  IgtlSurrogateCounters c;
  c.connections = connections_.load(std::memory_order_relaxed);
  c.readings = readings_.load(std::memory_order_relaxed);
  c.ignored = ignored_.load(std::memory_order_relaxed);
  c.refused_stale = refused_stale_.load(std::memory_order_relaxed);
  c.refused_future = refused_future_.load(std::memory_order_relaxed);
  c.refused_order = refused_order_.load(std::memory_order_relaxed);
  c.protocol_errors = protocol_errors_.load(std::memory_order_relaxed);
  c.dropped_unread = dropped_unread_.load(std::memory_order_relaxed);
  return c;
}

}  // namespace lftrack::drivers
