// V4L2 buffers through the detector driver's system-call seam (drivers/v4l2_syscalls.hpp): a
// device whose every answer comes from the fuzzer. Capabilities, offered formats, the granted
// size and stride, the buffer count and lengths, poll readiness, and each dequeued buffer's
// index, flags, bytes used, sequence and time stamp. The driver must open or refuse with a
// reason. A capture that returns kOk must come from a buffer the device really handed over,
// error-free, whole (bytes used cover the frame) and with a time stamp in range. Anything else
// is a finding, as is a crash, a sanitizer report or a hang.
#include <fuzzer/FuzzedDataProvider.h>
#include <linux/videodev2.h>
#include <sys/mman.h>

#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <map>
#include <vector>

#include "fuzz_input.hpp"
#include "lftrack/drivers/v4l2_detector.hpp"

namespace {

using lftrack::drivers::V4l2Syscalls;

// Errors a real device gives; the fuzzer picks one where a call fails.
constexpr int kErrors[] = {EINVAL, EIO, ENODEV, EAGAIN, EBUSY, ENOMEM, ENOTTY, EINTR};

class FuzzedV4l2Device final : public V4l2Syscalls {
 public:
  explicit FuzzedV4l2Device(FuzzedDataProvider& in) : in_(in) {}

  // What the last successful DQBUF handed over, for the harness's check.
  struct Handed {
    std::uint32_t index = 0, flags = 0, bytes_used = 0;
    timeval timestamp{};
  };
  std::vector<Handed> handed;  // this capture's dequeues, in order
  std::uint32_t granted_width = 0, granted_height = 0, granted_stride = 0;
  std::size_t mapped_buffers() const { return memory_.size(); }  // by this opening

  int open(const char*, int) override {
    memory_.clear();
    return fails() ? -1 : kFd;
  }
  int close(int) override { return 0; }
  void* mmap(std::size_t length, int, off_t offset) override {
    if (fails() || length == 0 || length > (std::size_t(1) << 22)) return errno = ENOMEM, MAP_FAILED;
    std::vector<std::uint8_t>& m = memory_[offset];
    m.assign(length, in_.ConsumeIntegral<std::uint8_t>());
    return m.data();
  }
  int munmap(void*, std::size_t) override { return 0; }
  int poll(pollfd* fds, nfds_t, int) override {
    const int choice = in_.ConsumeIntegralInRange(0, 5);
    if (choice == 0) return errno = EINTR, -1;
    if (choice == 1) return 0;  // timed out
    fds[0].revents = choice == 2 ? POLLERR : choice == 3 ? POLLHUP : POLLIN;
    return 1;
  }
  int ioctl(int, unsigned long request, void* arg) override {
    if (fails()) return -1;
    switch (request) {
      case VIDIOC_QUERYCAP: {
        auto* cap = static_cast<v4l2_capability*>(arg);
        cap->capabilities = in_.ConsumeIntegral<std::uint32_t>();
        cap->device_caps = in_.ConsumeIntegral<std::uint32_t>();
        return 0;
      }
      case VIDIOC_ENUM_FMT: {
        auto* d = static_cast<v4l2_fmtdesc*>(arg);
        if (in_.remaining_bytes() == 0) return errno = EINVAL, -1;
        constexpr std::uint32_t kOffered[] = {V4L2_PIX_FMT_Y16, V4L2_PIX_FMT_Y12, V4L2_PIX_FMT_Y10,
                                              V4L2_PIX_FMT_GREY, V4L2_PIX_FMT_YUYV};
        d->pixelformat = in_.ConsumeBool() ? in_.PickValueInArray(kOffered) : in_.ConsumeIntegral<std::uint32_t>();
        return 0;
      }
      case VIDIOC_S_FMT: {
        auto& pix = static_cast<v4l2_format*>(arg)->fmt.pix;
        // Mostly what was asked (so the fuzzer gets past open), otherwise anything.
        if (!in_.ConsumeBool()) pix.width = in_.ConsumeIntegral<std::uint32_t>();
        if (!in_.ConsumeBool()) pix.height = in_.ConsumeIntegral<std::uint32_t>();
        if (!in_.ConsumeBool()) pix.pixelformat = in_.ConsumeIntegral<std::uint32_t>();
        pix.bytesperline = in_.ConsumeBool() ? 0 : in_.ConsumeIntegral<std::uint32_t>();
        granted_width = pix.width;
        granted_height = pix.height;
        granted_stride = pix.bytesperline;
        return 0;
      }
      case VIDIOC_REQBUFS: {
        auto* r = static_cast<v4l2_requestbuffers*>(arg);
        if (!in_.ConsumeBool()) r->count = in_.ConsumeIntegral<std::uint32_t>();
        return 0;
      }
      case VIDIOC_QUERYBUF: {
        auto* b = static_cast<v4l2_buffer*>(arg);
        b->length = in_.ConsumeIntegral<std::uint32_t>();
        b->m.offset = b->index * kOffsetStep;
        return 0;
      }
      case VIDIOC_DQBUF: {
        if (in_.remaining_bytes() == 0) return errno = EAGAIN, -1;
        auto* b = static_cast<v4l2_buffer*>(arg);
        b->index = in_.ConsumeIntegral<std::uint32_t>() % 40;  // mostly near the count
        b->flags = in_.ConsumeIntegral<std::uint32_t>();
        b->bytesused = in_.ConsumeIntegral<std::uint32_t>();
        b->sequence = in_.ConsumeIntegral<std::uint32_t>();
        b->timestamp.tv_sec = in_.ConsumeIntegral<std::int64_t>();
        b->timestamp.tv_usec = in_.ConsumeIntegral<std::int64_t>();
        handed.push_back({b->index, b->flags, b->bytesused, b->timestamp});
        return 0;
      }
      default:  // QBUF, QUERYCTRL, S_CTRL, STREAMON, STREAMOFF
        return 0;
    }
  }

 private:
  static constexpr std::uint32_t kOffsetStep = 1u << 24;
  // One byte decides whether a call fails, and with which errno (most calls succeed).
  bool fails() {
    const auto b = in_.ConsumeIntegral<std::uint8_t>();
    if (b < 240) return false;
    errno = kErrors[b % std::size(kErrors)];
    return true;
  }
  FuzzedDataProvider& in_;
  std::map<off_t, std::vector<std::uint8_t>> memory_;
  static constexpr int kFd = 7;
};

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace lftrack;
  FuzzedDataProvider in(data, size);
  drivers::V4l2DetectorOptions options;
  options.device = "/dev/fuzz";
  options.rows = in.ConsumeIntegralInRange(1, 48);
  options.cols = in.ConsumeIntegralInRange(1, 64);
  options.buffers = in.ConsumeIntegralInRange(2, 6);
  options.trigger_control_id = in.ConsumeBool() ? V4L2_CID_PRIVATE_BASE : 0;
  FuzzedV4l2Device device(in);
  drivers::V4l2Detector detector(options, device);
  const Status opened = detector.open();
  fuzz::expect_reason(opened);
  if (!opened.ok()) return 0;
  // The driver accepted the device: what it granted must be what the scene asked for.
  if (device.granted_width != std::uint32_t(options.cols) || device.granted_height != std::uint32_t(options.rows))
    std::abort();
  const std::size_t bytes_per_pixel = detector.pixel_format() == V4L2_PIX_FMT_GREY ? 1 : 2;
  const std::size_t stride = std::max<std::size_t>(device.granted_stride, std::size_t(options.cols) * bytes_per_pixel);
  const std::size_t frame_bytes = stride * std::size_t(options.rows - 1) + std::size_t(options.cols) * bytes_per_pixel;

  drivers::Frame frame;
  frame.pixels = tracking::Image<std::uint16_t>(options.rows, options.cols);
  for (int capture = 0; capture < 16 && in.remaining_bytes() > 0; ++capture) {
    device.handed.clear();
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::milliseconds(5);
    const drivers::DeviceStatus s = detector.capture(&frame, deadline);
    if (s == drivers::DeviceStatus::kDisconnected) {
      if (detector.is_open()) std::abort();  // a disconnected device is closed at once
      fuzz::expect_reason(detector.reopen());
      if (!detector.is_open()) return 0;
      continue;
    }
    if (s != drivers::DeviceStatus::kOk) continue;
    // kOk: the frame is the newest buffer handed over, and it was sound.
    if (device.handed.empty()) std::abort();
    const auto& newest = device.handed.back();
    if (newest.index >= device.mapped_buffers()) std::abort();
    if ((newest.flags & V4L2_BUF_FLAG_ERROR) != 0) std::abort();
    if (newest.bytes_used < frame_bytes) std::abort();  // a short (torn) buffer delivered as a frame
    if (newest.timestamp.tv_sec < 0 || newest.timestamp.tv_usec < 0 || newest.timestamp.tv_usec >= 1000000)
      std::abort();
    if (frame.timestamp_ns < 0) std::abort();
  }
  return 0;
}
