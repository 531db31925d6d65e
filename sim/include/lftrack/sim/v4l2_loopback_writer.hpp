#pragma once
// Frames into a v4l2loopback device (the kernel module `v4l2loopback`, Debian
// v4l2loopback-dkms): `lftrack serve detectors --v4l2loopback /dev/videoN` writes the simulated
// detectors' frames there, and `lftrack run` reads them back through the real V4L2 capture path
// of drivers/v4l2_detector.hpp (the device's capture side). open() sets the output format, 16-bit
// grey (Y16) rows x cols, and checks the device is a loopback one; write() hands one frame over
// (the module keeps it for the reader). Where no such device exists, open() says how to make one.

#include <cstdint>
#include <string>

#include "lftrack/tracking/status.hpp"

namespace lftrack::sim {

class V4l2LoopbackWriter {
 public:
  V4l2LoopbackWriter() = default;
  ~V4l2LoopbackWriter();
  V4l2LoopbackWriter(const V4l2LoopbackWriter&) = delete;
  V4l2LoopbackWriter& operator=(const V4l2LoopbackWriter&) = delete;

  Status open(const std::string& device, int rows, int cols);
  Status write(const std::uint16_t* pixels);  // rows x cols, row-major
  void close();
  std::int64_t frames() const { return frames_; }

 private:
  int fd_ = -1;
  int rows_ = 0, cols_ = 0;
  std::string device_;
  std::int64_t frames_ = 0;
};

}  // namespace lftrack::sim
