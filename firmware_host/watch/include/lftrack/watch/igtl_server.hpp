#pragma once
// The pose for the room's navigation software (`--igtl [ADDRESS:]PORT`): an OpenIGTLink server
// (protocol version 2; messages built and packed by Debian's libopenigtlink) that 3D Slicer's
// OpenIGTLinkIF or PLUS connects to as a client. Every connected client gets, in cycle order:
//   TRANSFORM "T_room_from_ct"  each cycle with a registration: the registered pose (CT to room)
//   TRANSFORM "Correction"      each cycle that sent a correction: the couch move as a transform
//                               of the room frame about the registration origin
//   STATUS    "lftrack"         on connection and on every state change: the state as the error
//                               name, the reason as the status string, the cycle as the sub-code
//                               (TRACK: OK; ALIGN: BUSY; IDLE: NOT_READY; HOLD: DISABLED;
//                               FAULT: HARDWARE_FAILURE)
// Transforms are sent in OpenIGTLink's RAS convention: the room and CT frames (LPS-like, as
// lftrack's CT frame is DICOM's patient frame) have x and y negated, T_ras = F T F with
// F = diag(-1, -1, 1). Time stamps are the frame's exposure time as wall-clock time.
//
// The server reads the cycle hub on a thread of its own (best effort, never above the cycle) and
// writes to each client without blocking: what a slow client cannot take now waits in its own
// buffer, and a client more than kMaxPendingBytes behind (stalled) is disconnected. A client that
// connects, stalls or disconnects changes nothing in the cycle.

#include <atomic>
#include <chrono>
#include <memory>
#include <thread>

#include "lftrack/watch/cycle_hub.hpp"
#include "lftrack/watch/listen_address.hpp"

namespace lftrack::watch {

struct IgtlOptions {
  ListenAddress listen;
  int max_clients = 8;  // more are accepted and closed at once
  // The loop runs on a simulated clock (sim --fast): its exposure times have no place on the wall
  // clock (a fast run's ran minutes ahead of it; issue 50 probe), so a message is stamped with
  // the wall time it is sent.
  bool simulated_clock = false;
};

// Each field is read on its own, not as one snapshot; clients_now changes with the list of clients,
// so once clients_total counts a connection, clients_now already counts every one accepted before it.
struct IgtlCounters {
  std::int64_t clients_now = 0, clients_total = 0, clients_dropped = 0;  // dropped: stalled or refused
  std::int64_t transforms_sent = 0, statuses_sent = 0;  // messages written, over all clients
  std::uint64_t records_skipped = 0;  // the server fell more than the hub's history behind
};

// The transform OpenIGTLink carries for a room/CT transform: F T F, F = diag(-1, -1, 1).
Eigen::Matrix4d ras_from_lps(const Eigen::Matrix4d& T);

class IgtlServer {
 public:
  static constexpr std::size_t kMaxPendingBytes = 1 << 20;

  // Listens and serves on a thread of its own; `hub` must outlive the server.
  static Result<std::unique_ptr<IgtlServer>> start(CycleHub* hub, const IgtlOptions& options);
  ~IgtlServer();
  int port() const { return port_; }
  IgtlCounters counters() const;
  // When the loop has ended and the hub has caught up (CycleHub::catch_up): waits until the
  // server has written every cycle up to the hub's `seq` to each client's socket, or `timeout`.
  // True when it has; a client that has stopped reading (but not yet queued enough to be
  // dropped) keeps it false until the timeout, and the others get everything all the same.
  bool catch_up(std::uint64_t seq, std::chrono::milliseconds timeout) const;

 private:
  struct Client;
  IgtlServer() = default;
  void run();

  CycleHub* hub_ = nullptr;
  IgtlOptions options_;
  int listen_fd_ = -1;
  int port_ = 0;
  std::thread thread_;
  std::atomic<bool> stop_{false};
  std::atomic<std::int64_t> clients_now_{0}, clients_total_{0}, clients_dropped_{0}, transforms_{0}, statuses_{0};
  std::atomic<std::uint64_t> skipped_{0};
  std::atomic<std::uint64_t> written_through_seq_{0};  // every client's socket took the cycles up to it
};

}  // namespace lftrack::watch
