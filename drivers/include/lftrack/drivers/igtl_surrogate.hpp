#pragma once
// The breathing surrogate from an optical tracker over OpenIGTLink (scene: surrogate.source igtl):
// a client of the tracker's server (PLUS, or a navigation system's tracker bridge, listens on
// 18944) that takes the marker's position from TRANSFORM messages (the matrix's translation) or
// POSITION messages, from one device name or any, and gives the loop the marker's displacement
// along the scene's axis. Messages are unpacked, CRC checked, by Debian's libopenigtlink; the
// socket is our own (the library's client has no connect time-out, and a thread blocked in it
// could not be stopped).
//
// Frames: OpenIGTLink carries positions in RAS; the room frame is LPS-like (as the OpenIGTLink
// server, igtl_server.hpp), so a position's x and y are negated before the axis is applied.
//
// Time: a message's time stamp (CLOCK_REALTIME, seconds since 1970) is when the marker was
// measured; it becomes the loop's CLOCK_MONOTONIC through the offset between the two clocks at
// arrival. A message without one (time stamp 0) is taken as measured when it arrived. Refused,
// and counted: a reading older than `stale_ms` when it arrives (the tracker's clock is behind, or
// the network held it), one stamped more than `future_ms` ahead of this host's clock, and one not
// after the last reading taken (out of order or repeated). A reading that is not finite is passed
// on: the loop's watch holds on it (SurrogateMonitor).
//
// Threads: one of its own reads the socket (at the tracker's rate, up to 1 kHz) and reconnects
// (every `retry_ms`) after the server goes away or sends what is not OpenIGTLink; the loop's
// read() takes the readings without allocating and without waiting on that thread (a reading
// the thread is writing at that instant is taken by the next cycle).

#include <Eigen/Core>
#include <array>
#include <atomic>
#include <cstdint>
#include <memory>
#include <mutex>
#include <string>
#include <thread>

#include "lftrack/drivers/surrogate_source.hpp"

namespace lftrack::drivers {

struct IgtlSurrogateOptions {
  std::string host = "127.0.0.1";  // the tracker's server: a name or dotted IPv4
  int port = 18944;
  std::string device;                                    // "" any device name
  Eigen::Vector3d axis_room = Eigen::Vector3d::UnitZ();  // unit, room frame (LPS)
  double stale_ms = 200;                                 // older at arrival: refused
  double future_ms = 50;                                 // stamped further ahead: refused
  int connect_timeout_ms = 2000;                         // open(): the first connection
  int retry_ms = 200;                                    // after the server went away
  int max_body_bytes = 1 << 20;                          // a message claiming more is not OpenIGTLink
};

// Each counter is read on its own.
struct IgtlSurrogateCounters {
  std::int64_t connections = 0;      // made, the first included
  std::int64_t readings = 0;         // taken into the buffer
  std::int64_t ignored = 0;          // other devices or message types, skipped whole
  std::int64_t refused_stale = 0;    // older than stale_ms at arrival
  std::int64_t refused_future = 0;   // stamped ahead of this host's clock
  std::int64_t refused_order = 0;    // not after the last reading
  std::int64_t protocol_errors = 0;  // bad CRC, absurd body size, unreadable: connection dropped
  std::int64_t dropped_unread = 0;   // the loop did not read them before the buffer filled
};

class IgtlSurrogateSource final : public SurrogateSource {
 public:
  explicit IgtlSurrogateSource(const IgtlSurrogateOptions& options);
  ~IgtlSurrogateSource() override;
  // Connects within connect_timeout_ms (else an error naming the server) and starts the reader.
  Status open() override;
  void close() override;
  int read(std::int64_t now_ns, SurrogateReading* out, int capacity) override;
  IgtlSurrogateCounters counters() const;
  bool connected() const { return connected_.load(std::memory_order_acquire); }

 private:
  void run();
  bool serve_connection(int fd);  // until the server goes, a protocol error, or close()
  // The reader thread's: a reading measured at measured_ns (CLOCK_MONOTONIC), time stamped
  // stamp_wall_ns (CLOCK_REALTIME; 0: none), arrived at arrived_ns.
  void take(std::int64_t measured_ns, std::int64_t arrived_ns, std::int64_t stamp_wall_ns, double amplitude);

  IgtlSurrogateOptions options_;
  int first_fd_ = -1;  // open()'s connection, handed to the thread
  std::thread thread_;
  std::atomic<bool> stop_{false}, connected_{false};

  // Readings between the threads: a ring the reader writes under the lock and read() takes
  // with try_lock. Ordered by time (take() refuses the rest).
  static constexpr std::size_t kRing = 1024;
  mutable std::mutex ring_mutex_;
  std::array<SurrogateReading, kRing> ring_{};
  std::uint64_t ring_written_ = 0, ring_read_ = 0;           // readings ever written, ever read (or dropped)
  std::int64_t last_taken_ns_ = 0, last_stamp_wall_ns_ = 0;  // the reader thread's own

  std::atomic<std::int64_t> connections_{0}, readings_{0}, ignored_{0}, refused_stale_{0}, refused_future_{0},
      refused_order_{0}, protocol_errors_{0}, dropped_unread_{0};
};

}  // namespace lftrack::drivers
