#pragma once
// A simulated flat panel as a real GigE Vision camera: Aravis's fake GigE Vision camera
// (ArvGvFakeCamera, Aravis 0.8) bound to a local IPv4 address, rows x cols 16-bit grey (Mono16),
// whose frames come from a callback (the simulator renders X-rays into them). The GigE driver
// (drivers/gige_detector.hpp) talks to it exactly as to a panel: GVCP control with heartbeat,
// GenICam registers, GVSP packets over UDP, so the whole protocol path runs without hardware.
//
// What Aravis 0.8.26's fake camera is, and so what this is:
// - It answers GVCP on UDP port 3956 of one IPv4 address that a local interface carries
//   (`interface`: that address, or the interface's name; it refuses an address no interface
//   has, so 127.0.0.2 works only where it was added to lo). The port is fixed, so two fake
//   cameras need two such addresses: 127.0.0.1 and any other address of this host (traffic to a
//   local address goes through the loopback device all the same), or 127.0.0.x added to lo.
// - Its GenICam description offers Mono8, Mono16, RGB8 and four Bayer8 formats; start() selects
//   Mono16 (Mono8 with `mono8_only`) and sets the sensor and image size to cols x rows. A client
//   that selects an 8-bit format gets the high bytes of the same frames.
// - Free-running, it sends a frame at every multiple of the frame period on CLOCK_REALTIME
//   (`frame_rate_hz` until the client sets AcquisitionFrameRate; at most 1000 Hz). With
//   TriggerMode On and TriggerSource Software it sends one frame per TriggerSoftware, checked
//   `trigger_poll_hz` times a second. Frame ids are 16-bit and start at 65401, so they wrap
//   (65535 -> 1) after 135 frames: a client's wrap handling is exercised early.
// - arv_gv_fake_camera_is_running() says only that the interface was found: a GVCP port that
//   another program holds is logged and otherwise ignored (arvgvfakecamera.c). start() therefore
//   checks the port itself, free before and held after.
// - The GVSP timestamp is the host's CLOCK_REALTIME in ns at the start of the frame (tick
//   frequency 1 GHz). It does not resend packets (GVCP PACKETRESEND is not answered).
// - It has no "off" of its own: stop() destroys it (sockets closed, a client hears nothing);
//   start() again is a power cycle: registers back to their defaults, no controller, frame ids
//   from 65401. A client's heartbeat then finds it no longer holds control.
//
// The callback runs on the fake camera's thread (Aravis's), once per frame sent, before the
// frame's packets leave; `pixels` is rows x cols, row-major, host-endian 16-bit counts (the
// frame buffer itself where the client asked for Mono16 and the whole image). `frame_index`
// counts the frames served since start(), from 0.

#include <atomic>
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
  std::string interface = "127.0.0.1";  // an IPv4 address of a local interface, or the interface's name
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
  // Destroys the camera (its thread joins within about 100 ms).
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

 private:
  struct Arv;  // Aravis's fake camera (arv.h stays out of this header)
  // On the fake camera's thread: renders frame next_index_ into the client's buffer `data`
  // (width x height at x, y in the `pixel_format` the client selected).
  void serve(void* data, int width, int height, int x, int y, std::uint32_t pixel_format);

  GigeFakeDetectorOptions options_;
  GigeFrameRenderer render_;
  std::unique_ptr<Arv> arv_;
  std::string address_;
  std::vector<std::uint16_t> scratch_;  // a whole frame, where the client's buffer is not one
  std::uint64_t next_index_ = 0;        // the fake camera's thread only
  std::atomic<std::uint64_t> served_{0};
};

// The IPv4 addresses of this host's interfaces that are up, 127.0.0.1 first: where fake cameras
// can listen (one each).
std::vector<std::string> local_ipv4_addresses();

// Whether UDP port 3956 (GVCP) on `address` is free: no GigE camera (fake or otherwise) and no
// other program listens there.
bool gvcp_port_free(const std::string& address);

}  // namespace lftrack::sim
