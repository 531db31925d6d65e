#pragma once
// A flat-panel detector through Video4Linux2: the driver of `frames: v4l2` detectors.
//
// open() (outside the cycle): opens the device non-blocking, checks it can capture and stream,
// negotiates a 16-bit grey format (Y16 first, then 12- and 10-bit values in 16-bit containers,
// then 8-bit GREY as a stated fallback, widened to 16 bits), checks the size against the scene,
// maps `buffers` buffers, queues them, switches the external trigger on where asked (a
// camera-specific control; refused with a message where the device lacks it) and starts
// streaming.
//
// capture() (in the cycle): polls with the cycle's deadline, then takes the newest filled
// buffer (older ones are requeued unread, so a slow cycle never gets a stale frame), copies it
// into the caller's frame and requeues it. Every fault is a status and a counter:
//   poll timeout                           -> kTimeout
//   V4L2_BUF_FLAG_ERROR, EIO from DQBUF    -> kFault (the buffer is requeued, nothing delivered)
//   sequence going backwards               -> kFault (the device restarted: not the next frame)
//   a buffer the driver did not map, bytes used short of a whole frame (a torn transfer), a
//   time stamp outside CLOCK_MONOTONIC's range, a device that keeps handing buffers over
//                                          -> kFault (counted in bad_buffers; nothing delivered)
//   sequence gap                           -> counted (frames lost before this fresh one)
//   ENODEV, POLLERR (unplugged)            -> kDisconnected: the device is closed at once;
//                                             reopen() (outside the cycle) opens it again
// The sequence counter is 32-bit and wraps; a wrap is not a gap.

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "lftrack/drivers/frame_source.hpp"
#include "lftrack/drivers/v4l2_syscalls.hpp"

namespace lftrack::drivers {

struct V4l2DetectorOptions {
  std::string device;  // e.g. /dev/video0
  int rows = 0, cols = 0;
  int buffers = 4;
  std::uint32_t trigger_control_id = 0;  // 0: free-running; else a control set to trigger_value
  std::int32_t trigger_value = 1;
};

struct V4l2Counters {
  std::int64_t frames = 0, timeouts = 0, error_buffers = 0, io_errors = 0, sequence_gaps = 0, frames_lost = 0,
               backwards = 0, stale_dropped = 0, disconnects = 0, reopens = 0, bad_buffers = 0;
};

class V4l2Detector {
 public:
  explicit V4l2Detector(V4l2DetectorOptions options, V4l2Syscalls& sys = real_v4l2_syscalls());
  ~V4l2Detector();
  V4l2Detector(const V4l2Detector&) = delete;
  V4l2Detector& operator=(const V4l2Detector&) = delete;

  Status open();
  Status reopen();  // after kDisconnected; outside the cycle
  // `frame->pixels` must be rows x cols.
  DeviceStatus capture(Frame* frame, Deadline deadline);
  void close();

  bool is_open() const { return fd_ >= 0; }
  std::uint32_t pixel_format() const { return pixel_format_; }  // V4L2 fourcc negotiated
  const V4l2Counters& counters() const { return counters_; }

 private:
  struct Buffer {
    void* data = nullptr;
    std::size_t length = 0;
  };
  Status fail(const std::string& what);  // closes, and names the device
  DeviceStatus disconnected();
  void requeue(std::uint32_t index);
  void copy_out(const Buffer& buffer, Frame* frame) const;

  V4l2DetectorOptions options_;
  V4l2Syscalls& sys_;
  int fd_ = -1;
  std::uint32_t pixel_format_ = 0;
  std::uint32_t bytes_per_line_ = 0;
  std::size_t frame_bytes_ = 0;  // bytes a filled buffer must hold: rows - 1 strides and one line
  std::vector<Buffer> buffers_;
  bool have_sequence_ = false;
  std::uint32_t last_sequence_ = 0;
  V4l2Counters counters_;
};

// Two (or more) detectors as one frame source: each acquire() captures one frame from every
// detector by the deadline, and refuses a pair whose exposure times lie further apart than
// `max_skew_ms` (kFault, counted): never half a pair.
class V4l2FrameSource final : public FrameSource {
 public:
  V4l2FrameSource(std::vector<std::unique_ptr<V4l2Detector>> detectors, double max_skew_ms);
  Status open(FramePair* pair) override;
  DeviceStatus acquire(FramePair* pair, Deadline deadline) override;
  void close() override;
  // Outside the cycle: reopens any detector that was unplugged.
  Status reopen_disconnected();
  const V4l2Detector& detector(std::size_t i) const { return *detectors_[i]; }
  std::int64_t skewed_pairs() const { return skewed_pairs_; }

 private:
  std::vector<std::unique_ptr<V4l2Detector>> detectors_;
  double max_skew_ms_;
  std::int64_t skewed_pairs_ = 0;
};

}  // namespace lftrack::drivers
