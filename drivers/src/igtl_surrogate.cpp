#include "lftrack/drivers/igtl_surrogate.hpp"

#include <fcntl.h>
#include <igtl_util.h>
#include <netdb.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstring>

#include "lftrack/drivers/wall_clock.hpp"

namespace lftrack::drivers {

std::string igtl_device_name_problem(const std::string& name) {
  if (name.empty() || name.size() > 20) return "an OpenIGTLink device name has 1 to 20 bytes";
  for (const char c : name)
    if (c < 0x21 || c > 0x7e) return "an OpenIGTLink device name is printable ASCII without spaces";
  return {};
}

namespace {

// OpenIGTLink's header, 58 bytes, big-endian: version u16 (1, or 2 for OpenIGTLink 3's extended
// header), type char[12], device name char[20], time stamp (seconds u32, fraction u32 of 2^-32 s),
// body size u64, the body's CRC u64.
constexpr std::size_t kHeaderBytes = 58;
constexpr std::size_t kMaxMarkerBody = 64 * 1024;        // a marker's message, with any metadata
constexpr std::uint64_t kMaxSkippedBody = 1ull << 32;    // another type (a PLUS IMAGE) is skipped whole
constexpr std::int64_t kBodyDeadlineNs = 1'000'000'000;  // a marker's body follows its header within this
constexpr std::int64_t kSkipDeadlineNs = 30'000'000'000;

std::uint64_t be(const unsigned char* at, int bytes) {
  std::uint64_t value = 0;
  for (int i = 0; i < bytes; ++i) value = (value << 8) | at[i];
  return value;
}
float be_float(const unsigned char* at) {
  const auto word = static_cast<std::uint32_t>(be(at, 4));
  float value = 0;
  std::memcpy(&value, &word, sizeof value);
  return value;
}
// A NUL-padded header field equal to `text`.
bool field_is(const unsigned char* field, std::size_t size, const char* text) {
  const std::size_t n = std::strlen(text);
  return n <= size && std::memcmp(field, text, n) == 0 && (n == size || field[n] == 0);
}
std::string field_text(const unsigned char* field, std::size_t size) {
  const auto* begin = reinterpret_cast<const char*>(field);
  return std::string(begin, strnlen(begin, size));
}
// Logs the 1st, 10th, 100th, ... of a repeated event: a peer that errs a thousand times a second
// must not fill the log.
bool worth_logging(std::int64_t n) {
  while (n >= 10 && n % 10 == 0) n /= 10;
  return n == 1;
}

Result<sockaddr_in> resolve(const std::string& host, int port, const std::string& where) {
  if (port < 1 || port > 65535)
    return invalid_argument("the tracker's port must be 1 to 65535, not " + where);
  addrinfo hints{};
  hints.ai_family = AF_INET;
  hints.ai_socktype = SOCK_STREAM;
  addrinfo* found = nullptr;
  if (const int rc = getaddrinfo(host.c_str(), std::to_string(port).c_str(), &hints, &found); rc != 0)
    return not_found("no address for " + where + ": " + gai_strerror(rc));
  sockaddr_in address{};
  std::memcpy(&address, found->ai_addr, std::min<std::size_t>(sizeof address, found->ai_addrlen));
  freeaddrinfo(found);
  return address;
}

// A non-blocking TCP connection within timeout_ms (given up at once on `stop`), or an error.
Result<int> connect_to(const sockaddr_in& address, const std::string& where, int timeout_ms,
                       const std::atomic<bool>& stop) {
  const int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
  if (fd < 0) return io_error(std::string("socket: ") + std::strerror(errno));
  int error = 0;
  if (::connect(fd, reinterpret_cast<const sockaddr*>(&address), sizeof address) != 0) {
    error = errno;
    const std::int64_t deadline = clock_now_ns(CLOCK_MONOTONIC) + std::int64_t{timeout_ms} * 1'000'000;
    while (error == EINPROGRESS) {
      if (stop.load(std::memory_order_acquire) || clock_now_ns(CLOCK_MONOTONIC) > deadline) {
        ::close(fd);
        return io_error("no answer from " + where + " within " + std::to_string(timeout_ms) + " ms");
      }
      pollfd p{fd, POLLOUT, 0};
      const int ready = ::poll(&p, 1, 100);
      if (ready < 0 && errno != EINTR) error = errno;
      if (ready <= 0) continue;
      socklen_t length = sizeof error;
      if (getsockopt(fd, SOL_SOCKET, SO_ERROR, &error, &length) != 0) error = errno;
    }
  }
  if (error != 0) {
    ::close(fd);
    return io_error("cannot connect to " + where + ": " + std::strerror(error));
  }
  const int one = 1;
  setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
  return fd;
}

enum class Got { kAll, kClosed, kStopped, kTimedOut };

// Reads exactly `length` bytes, looking at `stop` every 100 ms; gives up at `deadline_ns`
// (CLOCK_MONOTONIC).
Got read_fully(int fd, void* data, std::size_t length, const std::atomic<bool>& stop,
               std::int64_t deadline_ns) {
  auto* at = static_cast<char*>(data);
  std::size_t got = 0;
  while (got < length) {
    if (stop.load(std::memory_order_acquire)) return Got::kStopped;
    if (clock_now_ns(CLOCK_MONOTONIC) > deadline_ns) return Got::kTimedOut;
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

// Waits `ms`, or less on `stop`; false when stopped.
bool wait_unless_stopped(const std::atomic<bool>& stop, int ms) {
  const std::int64_t until = clock_now_ns(CLOCK_MONOTONIC) + std::int64_t{ms} * 1'000'000;
  while (!stop.load(std::memory_order_acquire)) {
    if (clock_now_ns(CLOCK_MONOTONIC) >= until) return true;
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  return false;
}

}  // namespace

IgtlSurrogateSource::IgtlSurrogateSource(const IgtlSurrogateOptions& options)
    : options_(options), where_(options.host + ":" + std::to_string(options.port)) {}

IgtlSurrogateSource::~IgtlSurrogateSource() {
  close();
}

Status IgtlSurrogateSource::open() {
  if (thread_.joinable()) return failed_precondition("the OpenIGTLink surrogate is already open");
  if (!(options_.axis_room.allFinite() && std::abs(options_.axis_room.norm() - 1) < 1e-6))
    return invalid_argument("the surrogate's axis must be a unit vector");
  const std::string context = "surrogate.igtl: the optical tracker's OpenIGTLink server; is it running?";
  auto address = resolve(options_.host, options_.port, where_);
  if (!address.ok()) return address.status().with_context(context);
  address_ = *address;
  stop_.store(false, std::memory_order_release);
  auto fd = connect_to(address_, where_, options_.connect_timeout_ms, stop_);
  if (!fd.ok()) return fd.status().with_context(context);
  first_fd_ = *fd;
  body_.assign(kMaxMarkerBody, 0);
  followed_device_.reserve(24);
  thread_ = std::thread([this] { run(); });
  return {};
}

void IgtlSurrogateSource::close() {
  stop_.store(true, std::memory_order_release);
  if (thread_.joinable()) {
    thread_.join();
    const IgtlSurrogateCounters c = counters();
    spdlog::info(
        "surrogate: {} readings from {} over {} connection(s); refused {} stale, {} from the future, {} out "
        "of "
        "order; {} other messages skipped, {} protocol errors, {} unread{}",
        c.readings, where_, c.connections, c.refused_stale, c.refused_future, c.refused_order, c.ignored,
        c.protocol_errors, c.dropped_unread, c.several_devices ? "; several devices on the stream" : "");
  }
  if (first_fd_ >= 0) ::close(first_fd_);
  first_fd_ = -1;
  connected_.store(false, std::memory_order_release);
}

void IgtlSurrogateSource::run() {
  int fd = first_fd_;
  first_fd_ = -1;
  std::int64_t ends = 0, failures = 0, reconnections = 0;
  while (!stop_.load(std::memory_order_acquire)) {
    if (fd < 0) {
      // Always a pause between connections: a server that accepts and closes at once, or one
      // that sends what is refused, is not asked a thousand times a second.
      if (!wait_unless_stopped(stop_, options_.retry_ms)) break;
      auto again = connect_to(address_, where_, options_.connect_timeout_ms, stop_);
      if (!again.ok()) {
        if (worth_logging(++failures))
          spdlog::warn("surrogate: {} (retrying every {} ms; {} tries)", again.status().message(),
                       options_.retry_ms, failures);
        continue;
      }
      fd = *again;
      if (worth_logging(++reconnections))
        spdlog::info("surrogate: connected to {} again ({} times)", where_, reconnections);
      failures = 0;
    }
    connections_.fetch_add(1, std::memory_order_relaxed);
    connected_.store(true, std::memory_order_release);
    const bool stopped = serve_connection(fd);
    connected_.store(false, std::memory_order_release);
    ::close(fd);
    fd = -1;
    if (stopped) break;
    if (worth_logging(++ends))
      spdlog::warn(
          "surrogate: the connection to {} ended ({} times: the server closed it, sent nothing for {} ms, or "
          "sent "
          "what is not OpenIGTLink); connecting again",
          where_, ends, options_.idle_ms);
  }
  if (fd >= 0) ::close(fd);
}

void IgtlSurrogateSource::protocol_error(const char* what, std::uint64_t value) {
  const std::int64_t n = protocol_errors_.fetch_add(1, std::memory_order_relaxed) + 1;
  if (worth_logging(n))
    spdlog::warn(
        "surrogate: {} {} from {}: not the tracker's OpenIGTLink; dropping the connection ({} so far)", what,
        value, where_, n);
}

// One connection's messages, until it ends (false) or close() (true).
bool IgtlSurrogateSource::serve_connection(int fd) {
  unsigned char header[kHeaderBytes];
  const auto ended = [&](Got got, bool in_message) {
    if (got == Got::kTimedOut && in_message) protocol_error("a message cut off, bytes", 0);
    return got == Got::kStopped;
  };
  while (true) {
    const std::int64_t idle_deadline =
        clock_now_ns(CLOCK_MONOTONIC) + std::int64_t{options_.idle_ms} * 1'000'000;
    if (const Got got = read_fully(fd, header, kHeaderBytes, stop_, idle_deadline); got != Got::kAll)
      return ended(got, false);
    const std::int64_t arrived_ns = clock_now_ns(CLOCK_MONOTONIC);
    const std::uint64_t version = be(header, 2), body_bytes = be(header + 42, 8);
    if (version != 1 && version != 2) {
      protocol_error("a header of version", version);
      return false;
    }
    const unsigned char* type = header + 2;
    const unsigned char* name = header + 14;
    const bool marker_type = field_is(type, 12, "TRANSFORM") || field_is(type, 12, "POSITION");
    bool wanted = marker_type && !several_devices_.load(std::memory_order_relaxed);
    if (wanted && !options_.device.empty()) {
      wanted = field_is(name, 20, options_.device.c_str());
      if (!wanted && other_device_.empty()) {
        other_device_ = field_text(name, 20);
        spdlog::warn(
            "surrogate: the tracker streams device \"{}\", which is not surrogate.igtl.device \"{}\": "
            "skipped (said "
            "once; the marker's readings are taken when they come)",
            other_device_, options_.device);
      }
    } else if (wanted && followed_device_.empty()) {
      followed_device_ = field_text(name, 20);
      spdlog::info("surrogate: following device \"{}\" (surrogate.igtl.device names none)", followed_device_);
    } else if (wanted && !field_is(name, 20, followed_device_.c_str())) {
      several_devices_.store(true, std::memory_order_relaxed);
      wanted = false;
      other_device_ = field_text(name, 20);
      spdlog::error(
          "surrogate: the tracker sends device \"{}\" besides \"{}\": name the marker's in "
          "surrogate.igtl.device. "
          "No reading is taken until then (the loop holds, surrogate stopped)",
          field_text(name, 20), followed_device_);
    }
    if (!wanted) {
      if (body_bytes > kMaxSkippedBody) {
        protocol_error("a body of bytes", body_bytes);
        return false;
      }
      for (std::uint64_t left = body_bytes; left > 0;) {
        const std::size_t part = std::size_t(std::min<std::uint64_t>(left, body_.size()));
        if (const Got got = read_fully(fd, body_.data(), part, stop_, arrived_ns + kSkipDeadlineNs);
            got != Got::kAll)
          return ended(got, true);
        left -= part;
      }
      ignored_.fetch_add(1, std::memory_order_relaxed);
      continue;
    }
    if (body_bytes > kMaxMarkerBody) {
      protocol_error("a marker's message with a body of bytes", body_bytes);
      return false;
    }
    if (const Got got = read_fully(fd, body_.data(), body_bytes, stop_, arrived_ns + kBodyDeadlineNs);
        got != Got::kAll)
      return ended(got, true);
    if (!take_marker(header, body_bytes, arrived_ns)) return false;
  }
}

// The marker's position from a TRANSFORM (48 bytes: the rotation's 9 big-endian float32, then the
// translation's 3) or a POSITION (12, 24 or 28 bytes: x, y, z, then 3 or 4 quaternion
// components), inside OpenIGTLink 3's extended header and metadata for a version 2 header.
bool IgtlSurrogateSource::take_marker(const unsigned char* header, std::uint64_t body_bytes,
                                      std::int64_t arrived_ns) {
  const unsigned char* body = body_.data();
  if (::crc64(body_.data(), body_bytes, 0) != be(header + 50, 8)) {
    protocol_error("a body whose CRC fails, bytes", body_bytes);
    return false;
  }
  const unsigned char* content = body;
  std::uint64_t content_bytes = body_bytes;
  if (be(header, 2) ==
      2) {  // extended header: its size u16, metadata header size u16, metadata size u32, id u32
    const std::uint64_t extended = body_bytes >= 12 ? be(body, 2) : 0;
    const std::uint64_t around = body_bytes >= 12 ? extended + be(body + 2, 2) + be(body + 4, 4) : 0;
    if (extended < 12 || around > body_bytes) {
      protocol_error("an extended header that does not fit its body, bytes", body_bytes);
      return false;
    }
    content = body + extended;
    content_bytes = body_bytes - around;
  }
  const bool transform = field_is(header + 2, 12, "TRANSFORM");
  if (transform ? content_bytes != 48 : content_bytes != 12 && content_bytes != 24 && content_bytes != 28) {
    protocol_error(transform ? "a TRANSFORM of bytes" : "a POSITION of bytes", content_bytes);
    return false;
  }
  const unsigned char* p = transform ? content + 36 : content;
  // RAS to the room's LPS.
  const Eigen::Vector3d p_room(-double(be_float(p)), -double(be_float(p + 4)), double(be_float(p + 8)));
  const std::uint64_t seconds = be(header + 34, 4), fraction = be(header + 38, 4);
  const auto stamp_wall_ns = std::int64_t(seconds * 1'000'000'000 + ((fraction * 1'000'000'000) >> 32));
  const std::int64_t measured_ns =
      stamp_wall_ns == 0 ? arrived_ns : stamp_wall_ns - realtime_minus_monotonic_ns();
  take(measured_ns, arrived_ns, stamp_wall_ns, options_.axis_room.dot(p_room));
  return true;
}

void IgtlSurrogateSource::take(std::int64_t measured_ns, std::int64_t arrived_ns, std::int64_t stamp_wall_ns,
                               double amplitude) {
  const double age_ms = 1e-6 * double(arrived_ns - measured_ns);
  if (age_ms > options_.stale_ms) {
    refused_stale_.fetch_add(1, std::memory_order_relaxed);
    if (!warned_stale_)
      spdlog::warn(
          "surrogate: a reading {:.0f} ms old at its arrival refused (surrogate.stale_ms {:g}): is the "
          "tracker's "
          "clock synchronised with this host's (PTP, NTP)? Said once; the run's last line counts them",
          age_ms, options_.stale_ms);
    warned_stale_ = true;
    return;
  }
  if (-age_ms > options_.future_ms) {
    refused_future_.fetch_add(1, std::memory_order_relaxed);
    if (!warned_future_)
      spdlog::warn(
          "surrogate: a reading stamped {:.0f} ms ahead of this host's clock refused: is the tracker's clock "
          "synchronised with this host's (PTP, NTP)? Said once; the run's last line counts them",
          -age_ms);
    warned_future_ = true;
    return;
  }
  // Order on the sender's own time stamps where there are some: their conversion to this host's
  // clock moves with the offset read at each arrival.
  if (stamp_wall_ns != 0 ? stamp_wall_ns <= last_stamp_wall_ns_ : measured_ns <= last_taken_ns_) {
    refused_order_.fetch_add(1, std::memory_order_relaxed);
    if (!warned_order_)
      spdlog::warn("surrogate: a reading not after the last one refused (repeated, or out of order)");
    warned_order_ = true;
    return;
  }
  if (stamp_wall_ns != 0) last_stamp_wall_ns_ = stamp_wall_ns;
  measured_ns = std::max(measured_ns, last_taken_ns_ + 1);  // the ring stays in time order
  last_taken_ns_ = measured_ns;
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
  c.several_devices = several_devices_.load(std::memory_order_relaxed);
  return c;
}

}  // namespace lftrack::drivers
