#pragma once
// The optical tracker's twin: an OpenIGTLink server, as PLUS runs one for a tracker, streaming one
// marker's position to every client at `rate_hz`: TRANSFORM messages (identity rotation, the
// position as translation) or POSITION messages, device name `device`, each stamped with the time
// it was measured (CLOCK_REALTIME, as OpenIGTLink's clients read it). Positions are given in the
// room frame (LPS-like) and sent in OpenIGTLink's RAS: x and y negated.
//
// The marker is asked on the twin's own thread, at each tick of CLOCK_MONOTONIC; it may say there
// is nothing to send (a room that has not started, a stopped stream). A client that cannot take a
// whole message at once is disconnected: a tracker does not wait for its slowest reader. Used by
// `lftrack sim` (the simulated chest marker behind the real protocol, surrogate.source igtl),
// by `lftrack serve tracker` (a process of its own), and by the protocol tests.

#include <Eigen/Core>
#include <atomic>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <thread>

#include "lftrack/tracking/status.hpp"

namespace lftrack::sim {

struct TrackerTwinOptions {
  std::string address = "127.0.0.1";  // dotted IPv4 to listen on
  int port = 0;                       // 0: any free port (port() says which)
  std::string device = "Marker";
  bool position_messages = false;  // POSITION instead of TRANSFORM
  double rate_hz = 30;             // 1 to 1000
  // Called first on the twin's thread (a session lowers it below the cycle's priority, as it does
  // the simulated detectors': the twin stands for a device outside the host).
  std::function<void()> on_thread_start;
};

// The marker at `t_mono_ns` (CLOCK_MONOTONIC), room frame, mm; false: nothing to send this tick.
using MarkerAt = std::function<bool(std::int64_t t_mono_ns, Eigen::Vector3d* position_room_mm)>;

class TrackerTwin {
 public:
  static Result<std::unique_ptr<TrackerTwin>> start(const TrackerTwinOptions& options, MarkerAt marker);
  ~TrackerTwin();
  int port() const { return port_; }
  std::int64_t messages_sent() const { return sent_.load(std::memory_order_relaxed); }  // over all clients
  std::int64_t clients_now() const { return clients_.load(std::memory_order_relaxed); }
  std::int64_t clients_total() const { return clients_total_.load(std::memory_order_relaxed); }

 private:
  TrackerTwin() = default;
  void run();

  TrackerTwinOptions options_;
  MarkerAt marker_;
  int listen_fd_ = -1, port_ = 0;
  std::thread thread_;
  std::atomic<bool> stop_{false};
  std::atomic<std::int64_t> sent_{0}, clients_{0}, clients_total_{0};
};

}  // namespace lftrack::sim
