#include "lftrack/sim/v4l2_loopback_writer.hpp"

#include <fcntl.h>
#include <linux/videodev2.h>
#include <sys/ioctl.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

namespace lftrack::sim {

V4l2LoopbackWriter::~V4l2LoopbackWriter() {
  close();
}

Status V4l2LoopbackWriter::open(const std::string& device, int rows, int cols) {
  close();
  if (rows <= 0 || cols <= 0 || rows > 16384 || cols > 16384)
    return invalid_argument("v4l2loopback " + device + ": rows and cols must be 1 to 16384");
  const std::string how =
      " (load the module: sudo modprobe v4l2loopback devices=2 exclusive_caps=0; see docs/testing.md)";
  fd_ = ::open(device.c_str(), O_RDWR | O_CLOEXEC);
  if (fd_ < 0) return not_found("v4l2loopback " + device + ": " + std::strerror(errno) + how);
  v4l2_capability cap{};
  if (::ioctl(fd_, VIDIOC_QUERYCAP, &cap) != 0 ||
      std::strncmp(reinterpret_cast<const char*>(cap.driver), "v4l2 loopback", 13) != 0) {
    close();
    return failed_precondition("v4l2loopback " + device + ": not a v4l2loopback device" + how);
  }
  v4l2_format format{};
  format.type = V4L2_BUF_TYPE_VIDEO_OUTPUT;
  format.fmt.pix.width = static_cast<std::uint32_t>(cols);
  format.fmt.pix.height = static_cast<std::uint32_t>(rows);
  format.fmt.pix.pixelformat = V4L2_PIX_FMT_Y16;
  format.fmt.pix.field = V4L2_FIELD_NONE;
  format.fmt.pix.bytesperline = static_cast<std::uint32_t>(cols) * 2;
  format.fmt.pix.sizeimage = format.fmt.pix.bytesperline * static_cast<std::uint32_t>(rows);
  if (::ioctl(fd_, VIDIOC_S_FMT, &format) != 0 || format.fmt.pix.pixelformat != V4L2_PIX_FMT_Y16 ||
      format.fmt.pix.width != std::uint32_t(cols) || format.fmt.pix.height != std::uint32_t(rows)) {
    const std::string why = std::strerror(errno);
    close();
    return io_error("v4l2loopback " + device + ": cannot set Y16 " + std::to_string(cols) + " x " +
                    std::to_string(rows) + " (" + why + ")");
  }
  device_ = device;
  rows_ = rows;
  cols_ = cols;
  return {};
}

Status V4l2LoopbackWriter::write(const std::uint16_t* pixels) {
  if (fd_ < 0) return failed_precondition("v4l2loopback: not open");
  const std::size_t bytes = std::size_t(rows_) * std::size_t(cols_) * 2;
  const ssize_t n = ::write(fd_, pixels, bytes);
  if (n != ssize_t(bytes))
    return io_error("v4l2loopback " + device_ + ": write: " + (n < 0 ? std::strerror(errno) : "short write"));
  ++frames_;
  return {};
}

void V4l2LoopbackWriter::close() {
  if (fd_ >= 0) ::close(fd_);
  fd_ = -1;
}

}  // namespace lftrack::sim
