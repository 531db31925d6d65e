#pragma once
// A simulated flat panel as a real GigE Vision camera: rows x cols 16-bit grey (Mono16) whose
// frames come from a callback (the simulator renders X-rays into them). The GigE driver
// (drivers/gige_detector.hpp) talks to it exactly as to a panel: GVCP control with heartbeat,
// GenICam registers, GVSP packets over UDP, so the whole protocol path runs without hardware.
//
// The camera is Aravis's fake camera's register model (ArvFakeCamera, Aravis 0.8: its GenICam
// description, registers and frame timing) behind GVCP and GVSP of our own (sim/gvcp.hpp), not
// Aravis's ArvGvFakeCamera: that one trusts every datagram's length fields, and one malformed
// datagram crashed the process holding it. This camera, as a real one, drops what is not a
// well-formed command, answers a well-formed one it cannot carry out with an error status, and
// never reads or writes outside its memory map (malformed() counts both).
// - It answers GVCP on UDP port 3956 of one IPv4 address of this host (`interface`: the address,
//   or an interface's name): an interface's own address, or any 127.x.y.z (the loopback device
//   answers the whole of 127.0.0.0/8, so 127.0.0.2 needs no configuration). The port is fixed,
//   so two cameras need two addresses: 127.0.0.1 and 127.0.0.2. Discovery broadcasts
//   (255.255.255.255:3956, shared with other cameras) are answered too.
// - Its GenICam description offers Mono8, Mono16, RGB8 and four Bayer8 formats; start() selects
//   Mono16 (Mono8 with `mono8_only`) and sets the sensor and image size to cols x rows. A client
//   that selects an 8-bit format gets the high bytes of the same frames. An image window the
//   panel cannot give (outside cols x rows, a format of another size) is not streamed.
// - Free-running, it sends a frame at every multiple of the frame period on CLOCK_REALTIME
//   (`frame_rate_hz` until the client sets AcquisitionFrameRate; at most 1000 Hz). With
//   TriggerMode On and TriggerSource Software it sends one frame per TriggerSoftware, checked
//   `trigger_poll_hz` times a second. Frame ids are 16-bit and start at 65401, so they wrap
//   (65535 -> 1) after 135 frames: a client's wrap handling is exercised early.
// - One controller at a time (the control channel privilege); another client's writes are
//   refused (access denied). A controller silent for the heartbeat timeout (3 s unless it
//   writes another) loses control, and the stream stops.
// - Its clock: the GVSP leader's timestamp is the host's CLOCK_REALTIME in ns (whole us) as the
//   frame is started, before it is rendered: the exposure, in the simulated room (tick frequency
//   1 GHz). The timestamp latch works as GigE Vision's: writing 2 to 0x0944 latches the clock
//   into 0x0948 (high word) and 0x094C, writing 1 sets it to 0 (the leader's timestamps follow).
//   The tick frequency and latched value are read-only. It does not resend packets (GVCP
//   PACKETRESEND is dropped).
// - It has no "off" of its own: stop() closes its sockets (a client hears nothing); start()
//   again is a power cycle: registers back to their defaults, no controller, frame ids from
//   65401. A client's heartbeat then finds it no longer holds control.
//
// The callback runs on the camera's thread, once per frame sent, before the frame's packets
// leave; `pixels` is rows x cols, row-major, host-endian 16-bit counts (the frame buffer itself
// where the client asked for Mono16 and the whole image). `frame_index` counts the frames served
// since start(), from 0.

#include <atomic>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "lftrack/tracking/status.hpp"

namespace lftrack::sim {

using GigeFrameRenderer =
    std::function<void(std::uint64_t frame_index, std::uint16_t* pixels, int rows, int cols)>;

struct GigeFakeDetectorOptions {
  std::string interface =
      "127.0.0.1";  // an IPv4 address of this host (any 127.x.y.z), or an interface's name
  std::string serial = "LFTRACK-GV01";  // at most 15 characters; what discovery reports
  int rows = 0, cols = 0;
  double frame_rate_hz = 25;      // until a client sets AcquisitionFrameRate; 0.1 to 1000
  double trigger_poll_hz = 1000;  // how often a software trigger is looked for
  // A camera without 16-bit output: its GenICam description offers no Mono16 (Aravis's own
  // description with that entry taken out), so it sends Mono8, the high bytes of the frames.
  bool mono8_only = false;
};

class GigeFakeDetector {
 public:
  GigeFakeDetector(GigeFakeDetectorOptions options, GigeFrameRenderer render);
  ~GigeFakeDetector();
  GigeFakeDetector(const GigeFakeDetector&) = delete;
  GigeFakeDetector& operator=(const GigeFakeDetector&) = delete;

  // Binds GVCP port 3956 on the interface's address and starts serving. Refused with the reason
  // (no such interface or address, port taken by another camera or process).
  Status start();
  // Closes the camera's sockets (its thread joins at once).
  void stop();
  bool running() const;

  // What a client opens (GigeDetectorOptions::camera): address(), directly, or device_id(), the
  // name GigE Vision discovery gives it ("<vendor>-<model>-<serial>": Aravis-Fake-<serial>).
  const std::string& address() const { return address_; }
  std::string device_id() const { return "Aravis-Fake-" + options_.serial; }
  const std::string& serial() const { return options_.serial; }
  int rows() const { return options_.rows; }
  int cols() const { return options_.cols; }
  std::uint64_t frames_served() const { return served_.load(std::memory_order_relaxed); }
  // Datagrams dropped or refused (gvcp::check_command) since the camera was made.
  std::uint64_t malformed() const { return malformed_.load(std::memory_order_relaxed); }

 private:
  struct Server;  // sockets, thread and Aravis's register model (arv.h stays out of this header)
  // On the camera's thread: renders frame next_index_ into the client's buffer `data` of `bytes`
  // (width x height at x, y in the `pixel_format` the client selected); nothing where the window
  // does not fit the panel or the buffer.
  void serve(void* data, std::size_t bytes, std::uint32_t width, std::uint32_t height, std::uint32_t x,
             std::uint32_t y, std::uint32_t pixel_format);

  GigeFakeDetectorOptions options_;
  GigeFrameRenderer render_;
  std::unique_ptr<Server> server_;
  std::string address_;
  std::vector<std::uint16_t> scratch_;  // a whole frame, where the client's buffer is not one
  std::uint64_t next_index_ = 0;        // the camera's thread only
  std::atomic<std::uint64_t> served_{0}, malformed_{0};
};

// The IPv4 addresses of this host's interfaces that are up, 127.0.0.1 first: where fake cameras
// can listen besides 127.0.0.2 and the rest of 127.0.0.0/8 (one each).
std::vector<std::string> local_ipv4_addresses();

// Whether UDP port 3956 (GVCP) on `address` is free: no GigE camera (fake or otherwise) and no
// other program listens there.
bool gvcp_port_free(const std::string& address);

}  // namespace lftrack::sim
