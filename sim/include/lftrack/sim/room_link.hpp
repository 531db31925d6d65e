#pragma once
// The room link: where a served couch (or robot) has moved the patient, shared with the
// simulator's detectors in another process. It stands for the physics of the room, not for a
// protocol: the controller never reads it. The couch server writes its position about every
// millisecond; the detector server (or `lftrack run` on simulated frames) reads where the couch
// was when a pair was exposed (read_at), or the newest.
//
// The link is a small file mapped shared: 64 bytes of header, then the last 1,024 samples (about
// a second), each under a sequence lock of its own (odd while it is being written). A reader never
// blocks the writer; a torn read is retried. A link no longer written (its server gone) keeps its
// last position: the couch stopped where it was, as a couch whose controller died would; a
// reader sees how old it is from written_ns.

#include <cstdint>
#include <filesystem>
#include <memory>

#include "lftrack/tracking/pose.hpp"
#include "lftrack/tracking/status.hpp"

namespace lftrack::sim {

struct RoomLinkSample {
  tracking::Vector6d couch_position = tracking::Vector6d::Zero();  // couch coordinates (mm, rad)
  std::int64_t written_ns = 0;  // CLOCK_MONOTONIC: when the couch was there (read_at: the time asked)
  std::uint64_t writer_pid = 0;
};

class RoomLinkReader;

// Now, on the clock a link's samples are stamped with (RoomLinkSample::written_ns).
std::int64_t room_link_now_ns();

class RoomLinkWriter {
 public:
  // Creates the link file (mode 0600). An existing room link whose writer has gone (a couch
  // server killed) is taken over in place, so readers keep their mapping, and its last position
  // is where the couch stands (resumed_position()). A link whose writer still runs, or a file
  // that is not a room link, is refused, never overwritten. "Still runs" is an exclusive flock
  // the writer holds on the file for its life: the kernel drops it when the process ends, so a
  // killed writer not yet reaped (a zombie) does not block the next, and a reused pid never
  // looks alive.
  static Result<std::unique_ptr<RoomLinkWriter>> create(const std::filesystem::path& path);
  // An orderly end removes the file (readers keep the last position and see it go stale); a
  // writer killed leaves it, for the next server to take over.
  ~RoomLinkWriter();
  // The position found in a link taken over; zero for a new link.
  const tracking::Vector6d& resumed_position() const { return resumed_; }
  // The destructor leaves the file where it is (a server that refused the link it took over).
  void leave_file() { leave_file_ = true; }
  RoomLinkWriter(const RoomLinkWriter&) = delete;
  RoomLinkWriter& operator=(const RoomLinkWriter&) = delete;
  // Where the couch is at `at_ns` (CLOCK_MONOTONIC; now, without it). Never blocks; not
  // thread-safe (one writer); times must not go backwards.
  void publish(const tracking::Vector6d& couch_position);
  void publish(const tracking::Vector6d& couch_position, std::int64_t at_ns);
  const std::filesystem::path& path() const { return path_; }

 private:
  RoomLinkWriter(std::filesystem::path path, void* map, int lock_fd)
      : path_(std::move(path)), map_(map), lock_fd_(lock_fd) {}
  std::filesystem::path path_;
  void* map_;
  int lock_fd_;  // holds the flock that marks this writer alive
  tracking::Vector6d resumed_ = tracking::Vector6d::Zero();
  bool leave_file_ = false;
};

class RoomLinkReader {
 public:
  // Opens an existing link; fails with a message if the file is missing or not a room link.
  static Result<std::unique_ptr<RoomLinkReader>> open(const std::filesystem::path& path);
  // Whether a writer holds the link now (its flock, RoomLinkWriter::create): false for a link
  // whose server has ended or was killed, whatever its samples' time stamps say. Probes with a
  // shared lock held for the probe only.
  static bool writer_running(const std::filesystem::path& path);
  ~RoomLinkReader();
  RoomLinkReader(const RoomLinkReader&) = delete;
  RoomLinkReader& operator=(const RoomLinkReader&) = delete;
  // The newest sample; false if none has been written yet (or every read was torn).
  bool read(RoomLinkSample* sample) const;
  // Where the couch was at `t_ns` (CLOCK_MONOTONIC): on the straight line between the samples
  // written either side of it (written_ns = t_ns), the newest if t_ns is after it, the oldest kept
  // if before (their own written_ns: the caller sees how far off). False as read() is.
  bool read_at(std::int64_t t_ns, RoomLinkSample* sample) const;

 private:
  friend class RoomLinkWriter;
  explicit RoomLinkReader(const void* map) : map_(map) {}
  const void* map_;
};

}  // namespace lftrack::sim
