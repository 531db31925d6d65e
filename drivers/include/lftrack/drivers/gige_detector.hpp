#pragma once
// A flat-panel detector through GigE Vision (Aravis 0.8): the driver of `frames: gige` detectors.
//
// open() (outside the cycle): opens the camera through Aravis's GigE Vision interface only (an
// IPv4 address or host name is opened directly; anything else is looked up by GigE Vision
// discovery, 1 s, as one of the names Aravis gives a camera: "<vendor>-<model>-<serial>",
// "<vendor>-<serial>", its user-defined name or its MAC address), takes control of it
// (Aravis then sends a heartbeat every second), negotiates a 16-bit grey pixel format (Mono16
// first, then Mono14, Mono12 and Mono10 in 16-bit containers, then Mono8 as a stated fallback,
// widened to 16 bits, not scaled), checks Width x Height against the scene (refused, never
// cropped: the calibrated geometry is the whole panel), sets the trigger (free-running at the
// camera's or a given frame rate, software trigger, or a hardware line), sets the packet size,
// the stream's receive-buffer size and its packet timeouts, creates the stream with `buffers`
// preallocated buffers and starts acquisition. A refusal names the camera and the reason.
//
// capture() (in the cycle): waits for a finished buffer until the cycle's deadline, then drains
// every other finished buffer and keeps the newest complete one (older complete ones are handed
// back unread, so a late cycle does not get a stale frame), copies it into the caller's frame and
// hands the buffer back to the stream. A cycle later than `buffers` frame periods finds every
// buffer full: the frames after them found none and are lost (counted as underruns), so what it
// gets is older than the camera's newest; its timestamp says so, for the freshness check.
// Every fault is a status and a counter:
//   nothing finished by the deadline                 -> kTimeout
//   only incomplete buffers (missing packets, packet
//   timeout, wrong packet id, size mismatch)         -> kFault (the buffers go back, nothing delivered)
//   a frame of another size or pixel format          -> kFault (counted as corrupt)
//   frame id going backwards                         -> kFault (the camera restarted: not the next frame)
//   frame id gap                                     -> counted (frames lost before this fresh one)
//   control lost (the heartbeat read back that we no
//   longer hold the camera: it restarted, or stayed
//   silent for ~5 s)                                 -> kDisconnected: the camera is marked gone at
//                                                       once; reopen() (outside the cycle) releases
//                                                       it and opens it again
// A camera that goes silent gives kTimeout until Aravis's heartbeat gives up on it (about 5 to
// 8 s with Aravis 0.8.26's defaults: 1 s period, 5 s retry window, 5 x 500 ms GVCP retries);
// one that restarts gives kDisconnected within about a second. close() and reopen() talk to the
// camera (GVCP, up to 2.5 s per unanswered command): never call them in the cycle.
//
// Frame ids: GigE Vision 1.x ids are 16 bits, 0 is invalid, so they run ..., 65535, 1, 2, ...;
// GigE Vision 2.x extended ids are 64 bits. Frame::sequence is the camera's id unwrapped to
// 32 bits (the first frame after open() takes the camera's id as it is), so it always increases
// while the camera runs and a gap in it is a gap in the camera's frames.
//
// Transport: Aravis's UDP socket (or, with packet_socket, its PF_PACKET ring: Aravis 0.8.26
// hands that ring's blocks over after up to 5 ms (tp_retire_blk_tov), which measured 4.1 ms p50
// per 512 x 512 frame on loopback against 2.2 ms for the socket). The stream's receive buffer is
// two frames by default, and open() refuses where net.core.rmem_max caps it below that: one
// frame is a burst of back-to-back packets, and a buffer that cannot hold it loses packets.
//
// Timestamps: Frame::timestamp_ns is the exposure on the host's CLOCK_MONOTONIC. With
// `exposure_clock` kDevice (the default) it is the camera's own timestamp from the frame's leader
// (GigE Vision: the camera's clock at the frame's start, in ticks of its tick frequency), mapped
// onto the host's clock by timestamp latches (device_clock.hpp): a round of 8 at open(), and one
// of 3 each time sync_clock() is called (GigeFrameSource: every second, from its own thread; each
// latch is two GVCP transactions, which wait on Aravis's per-device GVCP lock as the software
// trigger and Aravis's heartbeat do). A camera that does not latch (no tick frequency, a latched
// 0, no answer) is timed as with kArrival, and open() says so in clock_source(); so is one whose
// mapping is more than 5 s old (its rounds failing). A frame whose mapped timestamp lies after
// its leader's arrival (beyond the mapping's uncertainty, which grows by 100 ppm of its age), or
// more than 0.5 s before it, is not believed: it is timed by its arrival and counted
// (clock_fallbacks). GigeFrameSource times a pair by one clock: where any of its frames was timed
// by arrival, all are. With kArrival the timestamp is when the frame's leader packet
// reached this host (Aravis's system timestamp, CLOCK_REALTIME, moved to CLOCK_MONOTONIC) less
// `leader_latency_ms` (the camera's delay from the middle of the exposure to its leader packet,
// from its documentation or a measurement; 0 by default): the time the panel's read-out takes is
// then not in the latency chain's first link. The camera's raw timestamp is kept as
// last_device_timestamp_ns(). Both detectors of a pair are timed on the host's clock, which is
// what the pair's skew check needs.
//
// Allocation and locking: capture() itself allocates nothing. Aravis's part: handing a buffer
// back (arv_stream_push_buffer -> g_async_queue_push) takes one GList node from GLib's slice
// allocator (per-thread magazines in GLib 2.74, so no malloc in the steady state) and every
// queue operation takes the queue's mutex, which Aravis's receive thread holds only to push or
// pop one pointer. Aravis's receive thread allocates per frame (its frame record and packet
// table, g_new0), outside the cycle's thread. The software trigger is sent from a thread of this
// detector (a GVCP write waits for the camera's acknowledgement), so trigger() never blocks.

#include <atomic>
#include <cstdint>
#include <memory>
#include <mutex>
#include <shared_mutex>
#include <string>
#include <thread>
#include <vector>

#include "lftrack/drivers/device_clock.hpp"
#include "lftrack/drivers/frame_source.hpp"

namespace lftrack::drivers {

enum class ExposureClock {
  kDevice,   // the camera's timestamp, mapped onto the host's clock by timestamp latches
  kArrival,  // the leader's arrival on the host, less leader_latency_ms
};

enum class GigeTrigger {
  kFreeRun,   // the camera exposes at its frame rate (or frame_rate_hz)
  kSoftware,  // one exposure per trigger() (TriggerSource = Software, TriggerSoftware command)
  kLine,      // one exposure per edge on `trigger_line` (the X-ray generator's sync)
};

struct GigeDetectorOptions {
  // The camera: an IPv4 address or host name (opened directly, no discovery), or a name GigE
  // Vision discovery finds: "<vendor>-<model>-<serial>" (as arv-tool-0.8 from Debian's
  // aravis-tools lists it), "<vendor>-<serial>", the camera's user-defined name or its MAC.
  std::string camera;
  int rows = 0, cols = 0;
  int buffers = 4;  // stream buffers, 2 to 64
  GigeTrigger trigger = GigeTrigger::kFreeRun;
  double frame_rate_hz = 0;            // kFreeRun: AcquisitionFrameRate; 0 leaves the camera's
  std::string trigger_line = "Line0";  // kLine: the TriggerSource the generator drives
  int packet_size = 0;  // GevSCPSPacketSize in bytes (e.g. 8192 on jumbo frames); 0 keeps the camera's
  double packet_timeout_ms = 20;    // a missing packet is waited for (and re-requested) this long
  double frame_retention_ms = 100;  // an incomplete frame is given up after this long without packets
  bool packet_resend = false;       // ask the camera to resend lost packets (costs latency)
  int socket_buffer_bytes = -1;     // stream receive buffer: -1 two frames, 0 the OS default
  bool packet_socket = false;       // Aravis's PF_PACKET ring (needs CAP_NET_RAW); false: UDP socket
  double leader_latency_ms = 0;     // kArrival: mid-exposure to leader packet, subtracted from timestamps
  ExposureClock exposure_clock = ExposureClock::kDevice;
};

// Checks that need no camera (sizes, counts, times), with messages that name the camera.
Status validate_gige_options(const GigeDetectorOptions& options);

struct GigeCounters {
  std::int64_t frames = 0;            // frames delivered
  std::int64_t timeouts = 0;          // captures that met their deadline with nothing finished
  std::int64_t incomplete = 0;        // buffers Aravis finished without every packet (any status but success)
  std::int64_t corrupt = 0;           // complete buffers of the wrong size or pixel format
  std::int64_t frame_id_gaps = 0;     // deliveries after a gap in the camera's frame ids
  std::int64_t frames_lost = 0;       // frames missing in those gaps
  std::int64_t backwards = 0;         // frame ids going backwards (camera restarted)
  std::int64_t stale_dropped = 0;     // complete frames handed back unread because a newer one was there
  std::int64_t underruns = 0;         // frames that found no free buffer (Aravis's n_underruns), lost
  std::int64_t disconnects = 0;       // control of the camera lost
  std::int64_t reopens = 0;           // successful reopen()s
  std::int64_t trigger_failures = 0;  // software triggers the camera did not acknowledge
  std::int64_t clock_fallbacks = 0;   // frames timed by their arrival although the device clock was asked for
};

class GigeDetector {
 public:
  explicit GigeDetector(GigeDetectorOptions options);
  ~GigeDetector();
  GigeDetector(const GigeDetector&) = delete;
  GigeDetector& operator=(const GigeDetector&) = delete;

  Status open();
  Status reopen();  // after kDisconnected; outside the cycle
  // `frame->pixels` must be rows x cols.
  DeviceStatus capture(Frame* frame, Deadline deadline);
  // kSoftware: asks for one exposure at `at_monotonic_ns` (CLOCK_MONOTONIC; 0 or a time past:
  // now); never blocks. The command leaves from this detector's trigger thread at that time; a
  // request made before the previous one has left replaces it. Otherwise nothing.
  void trigger(std::int64_t at_monotonic_ns = 0);
  void close();
  // One round of `latches` timestamp latches (exposure_clock kDevice, a camera that latches): the
  // mapping of the camera's clock onto the host's follows the tightest. Safe beside capture() on
  // another thread (never beside open(), reopen() or close()). True where the mapping was renewed.
  bool sync_clock(int latches = 3);

  // Open and not marked gone.
  bool is_open() const;
  // Buffers Aravis has finished (complete or not) that no capture() has taken yet; 0 when closed.
  // Takes the stream queue's mutex for a moment: a diagnostic, not for the cycle.
  int frames_waiting() const;
  const std::string& camera() const { return options_.camera; }
  const GigeDetectorOptions& options() const { return options_; }
  std::uint32_t pixel_format() const { return pixel_format_; }  // GenICam PFNC value negotiated
  const std::string& pixel_format_name() const { return pixel_format_name_; }
  const std::string& device_id() const { return device_id_; }  // as the camera names itself
  std::int64_t last_device_timestamp_ns() const { return last_device_timestamp_ns_; }
  // What times this camera's frames: "device clock (+-N us)" or "arrival (...)", with the reason
  // where the device clock was asked for and could not be used.
  std::string clock_source() const;
  // The device clock was asked for and is mapped (a latch round has succeeded since open()).
  bool device_clock_mapped() const;
  // How far the device clock mapping can be off now: its latch's half round trip and 100 ppm of
  // drift since (0 when frames are timed by arrival).
  std::int64_t timestamp_uncertainty_ns() const;
  // The last frame captured: timed by the camera's clock (else by its arrival), how far its
  // timestamp can be off (a frame stamped this much before an exposure was asked for may still
  // be that exposure's), and its arrival less leader_latency_ms.
  bool last_frame_timed_by_device() const { return last_timed_by_device_; }
  std::int64_t last_timestamp_uncertainty_ns() const { return last_uncertainty_ns_; }
  std::int64_t last_arrival_timestamp_ns() const { return last_arrival_timestamp_ns_; }
  const GigeCounters& counters() const { return counters_; }

 private:
  struct Arv;                            // Aravis's objects (arv.h stays out of this header)
  Status fail(const std::string& what);  // releases the camera, and names it
  void release();
  void start_trigger_thread();
  void start_device_clock();                        // open(): the tick frequency and a first round of latches
  bool latch_round(int latches, std::string* why);  // why: set where the round maps nothing
  // The mapping, if it is there and under 5 s old, its uncertainty grown by the drift since.
  bool usable_mapping(std::int64_t now_ns, DeviceClockMap::Mapping* m) const;
  void stop_trigger_thread();
  bool copy_out(const void* data, std::size_t size, std::size_t stride, Frame* frame) const;

  GigeDetectorOptions options_;
  std::unique_ptr<Arv> arv_;
  std::uint32_t pixel_format_ = 0;
  std::string pixel_format_name_;
  std::string device_id_;
  int bytes_per_pixel_ = 2;
  bool have_id_ = false;
  std::uint64_t last_id_ = 0;
  std::uint32_t sequence_ = 0;
  std::int64_t last_device_timestamp_ns_ = 0;
  std::unique_ptr<DeviceClockMap> clock_;  // made by open(); valid() once a round has ended
  bool last_timed_by_device_ = false;
  std::int64_t last_uncertainty_ns_ = 0, last_arrival_timestamp_ns_ = 0;
  std::uint64_t tick_hz_ = 0;           // the camera's timestamp tick frequency; 0: none
  std::string clock_problem_;           // why the device clock is not used, if it is not
  std::int64_t underruns_at_open_ = 0;  // Aravis counts per stream; ours run across reopens
  GigeCounters counters_;
};

// Two (or more) GigE detectors as one frame source: each acquire() captures one frame from every
// detector by the deadline, and refuses a pair whose exposure times lie further apart than
// `max_skew_ms` (kFault, counted): never half a pair. request_exposure(t) has every
// software-triggered detector triggered at t (the loop's real clock, CLOCK_MONOTONIC), and a
// frame that reached the host before t is an earlier exposure's, late (stale_frames): it is
// passed over and acquire() waits on for this exposure's, so a cycle never registers the
// previous cycle's frame. A detector marked gone (kDisconnected) is reopened by a thread of the
// source, never the cycle's: acquire() answers kDisconnected while that runs (it only tries the
// lock), and frames resume once the camera is back; the loop journals the gap.
class GigeFrameSource final : public FrameSource {
 public:
  GigeFrameSource(std::vector<GigeDetectorOptions> detectors, double max_skew_ms);
  ~GigeFrameSource() override;
  // Sizes every frame of `pair` (rows x cols per detector), then opens the detectors in order.
  Status open(FramePair* pair) override;
  void request_exposure(std::int64_t exposure_time_ns) override;
  DeviceStatus acquire(FramePair* pair, Deadline deadline) override;
  // The camera as given (GigeDetectorOptions::camera) and the device id it named itself by at
  // open (GenICam DeviceID: a fake camera's serial number).
  DetectorIdentity identity(std::size_t detector) const override;
  void close() override;
  // Outside the cycle: reopens any detector that was marked gone (or never opened). Takes the
  // same lock as the source's own reopen thread, so the two never open one camera at once (two
  // Aravis devices opening one camera together deadlocked inside Aravis: a test that called
  // this while the thread was reopening hung in the thread's join).
  Status reopen_disconnected();
  std::size_t size() const { return detectors_.size(); }
  GigeDetector& detector(std::size_t i) { return *detectors_[i]; }
  const GigeDetector& detector(std::size_t i) const { return *detectors_[i]; }
  std::int64_t skewed_pairs() const { return skewed_pairs_; }
  std::int64_t stale_frames() const { return stale_frames_; }
  // Pairs whose frames were all timed by arrival because one could not be timed by its camera's clock.
  std::int64_t pairs_timed_by_arrival() const { return pairs_timed_by_arrival_; }
  std::int64_t reopens() const { return reopens_.load(); }

 private:
  void reopen_loop();
  Status reopen_disconnected_locked();  // with devices_ held

  std::vector<std::unique_ptr<GigeDetector>> detectors_;
  double max_skew_ms_;
  std::int64_t skewed_pairs_ = 0, stale_frames_ = 0, pairs_timed_by_arrival_ = 0;
  std::int64_t exposure_ns_ = 0;  // the exposure asked for (software trigger); 0: any frame
  // The cycle only tries it, shared; the reopen thread holds it alone to reopen, shared to latch
  // the cameras' clocks.
  mutable std::shared_mutex devices_;
  std::atomic<bool> gone_{false}, stop_{false};
  std::atomic<std::int64_t> reopens_{0};
  std::thread reopener_;
};

}  // namespace lftrack::drivers
