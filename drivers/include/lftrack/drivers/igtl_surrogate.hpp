#pragma once
// The breathing surrogate from an optical tracker over OpenIGTLink (scene: surrogate.source igtl):
// a client of the tracker's server (PLUS, or a navigation system's tracker bridge, listens on
// 18944) that takes the marker's position from TRANSFORM messages (the matrix's translation) or
// POSITION messages of one device, and gives the loop the marker's displacement along the
// scene's axis. Headers are unpacked by Debian's libopenigtlink; the two bodies it reads (48 and
// 12-28 bytes of big-endian float32) are read here, their CRC by the library's crc64: the
// library's message classes allocate on every message, which a thread feeding the cycle must
// not, and its POSITION unpacks a short body as if it held 28 bytes. Header version 2 (OpenIGTLink
// 3: an extended header and metadata around the content) is read as well. The socket is our own:
// the library's client has no connect time-out, and a thread blocked in it could not be stopped.
//
// Frames: OpenIGTLink carries positions in RAS; the room frame is LPS-like (as the OpenIGTLink
// server, igtl_server.hpp), so a position's x and y are negated before the axis is applied.
//
// Devices: `device` names the marker's tool. Empty, the stream must carry one device: the client
// follows the first it sees, and once a second appears (PLUS sends every tool, the reference
// among them) it takes nothing more and says so: the loop holds, "surrogate stopped".
//
// Time: a message's time stamp (seconds and a 2^-32 fraction on CLOCK_REALTIME) is when the marker
// was measured; it becomes the loop's CLOCK_MONOTONIC through the offset between the two clocks at
// arrival. A message without one (time stamp 0) is taken as measured when it arrived. Refused,
// counted, and logged the first time: a reading older than `stale_ms` when it arrives (the
// tracker's clock is behind, or the network held it), one stamped more than `future_ms` ahead of
// this host's clock, and one whose time stamp is not after the last reading's (out of order or
// repeated). A reading that is not finite is passed on: the loop's watch holds on it.
//
// Threads: one of its own reads the socket and, after the server goes away, goes silent for
// `idle_ms`, or sends what is not OpenIGTLink, reconnects every `retry_ms`; it inherits the
// priority of the thread that opens it (the cycle's, in a real-time run). The loop's read() takes
// the readings without allocating and without waiting on that thread (a reading the thread is
// writing at that instant is taken by the next cycle). The reader allocates nothing per message.

#include <netinet/in.h>

#include <Eigen/Core>
#include <array>
#include <atomic>
#include <cstdint>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "lftrack/drivers/surrogate_source.hpp"

namespace lftrack::drivers {

// Why `name` cannot be an OpenIGTLink device name (its header's 20 bytes; printable ASCII, no
// spaces, as PLUS names tools), or "" when it can.
std::string igtl_device_name_problem(const std::string& name);

struct IgtlSurrogateOptions {
  std::string host = "127.0.0.1";  // the tracker's server: a name or dotted IPv4 (resolved at open())
  int port = 18944;
  std::string device;                                    // the marker's device name ("": the only one)
  Eigen::Vector3d axis_room = Eigen::Vector3d::UnitZ();  // unit, room frame (LPS)
  double stale_ms = 200;                                 // older at arrival: refused
  double future_ms = 50;                                 // stamped further ahead: refused
  int connect_timeout_ms = 2000;                         // open(): the first connection
  int retry_ms = 200;                                    // between connections
  int idle_ms = 1000;                                    // no message this long: connect again
};

// Each counter is read on its own.
struct IgtlSurrogateCounters {
  std::int64_t connections = 0;      // made, the first included
  std::int64_t readings = 0;         // taken into the buffer
  std::int64_t ignored = 0;          // other devices or message types, skipped whole
  std::int64_t refused_stale = 0;    // older than stale_ms at arrival
  std::int64_t refused_future = 0;   // stamped ahead of this host's clock
  std::int64_t refused_order = 0;    // not after the last reading
  std::int64_t protocol_errors = 0;  // bad CRC, absurd sizes, a message cut off: connection dropped
  std::int64_t dropped_unread = 0;   // the loop did not read them before the buffer filled
  bool several_devices = false;      // `device` empty and a second device seen: nothing taken since
};

class IgtlSurrogateSource final : public SurrogateSource {
 public:
  explicit IgtlSurrogateSource(const IgtlSurrogateOptions& options);
  ~IgtlSurrogateSource() override;
  // Resolves the host, connects within connect_timeout_ms (else an error naming the server), and
  // starts the reader.
  Status open() override;
  void close() override;
  int read(std::int64_t now_ns, SurrogateReading* out, int capacity) override;
  IgtlSurrogateCounters counters() const;
  // The first device name skipped on the stream (another than `device`, or a second one with none
  // named), "" none; read after close().
  const std::string& other_device_seen() const { return other_device_; }
  bool connected() const { return connected_.load(std::memory_order_acquire); }

 private:
  void run();
  bool serve_connection(int fd);  // until the server goes, falls silent, errs, or close(): true
  bool take_marker(const unsigned char* header, std::uint64_t body_bytes, std::int64_t arrived_ns);
  void take(std::int64_t measured_ns, std::int64_t arrived_ns, std::int64_t stamp_wall_ns, double amplitude);
  void protocol_error(const char* what, std::uint64_t value);

  IgtlSurrogateOptions options_;
  std::string where_;  // host:port, for messages
  sockaddr_in address_{};
  int first_fd_ = -1;  // open()'s connection, handed to the thread
  std::thread thread_;
  std::atomic<bool> stop_{false}, connected_{false};

  // The reader thread's own: buffers sized once, the device followed, the last reading.
  std::vector<unsigned char> body_;
  std::string followed_device_;
  std::int64_t last_taken_ns_ = 0, last_stamp_wall_ns_ = 0;
  bool warned_stale_ = false, warned_future_ = false, warned_order_ = false;
  std::string other_device_;  // the first device skipped (not `device`, or a second one with none named)

  // Readings between the threads: a ring the reader writes under the lock and read() takes with
  // try_lock. Ordered by time (take() keeps it so).
  static constexpr std::size_t kRing = 1024;
  mutable std::mutex ring_mutex_;
  std::array<SurrogateReading, kRing> ring_{};
  std::uint64_t ring_written_ = 0, ring_read_ = 0;  // readings ever written, ever read (or dropped)

  std::atomic<std::int64_t> connections_{0}, readings_{0}, ignored_{0}, refused_stale_{0}, refused_future_{0},
      refused_order_{0}, protocol_errors_{0}, dropped_unread_{0};
  std::atomic<bool> several_devices_{false};
};

}  // namespace lftrack::drivers
