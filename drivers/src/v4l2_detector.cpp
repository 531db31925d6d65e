#include "lftrack/drivers/v4l2_detector.hpp"

#include <fcntl.h>
#include <linux/videodev2.h>
#include <sys/ioctl.h>
#include <sys/mman.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cstring>

namespace lftrack::drivers {

namespace {

class KernelSyscalls final : public V4l2Syscalls {
 public:
  int open(const char* path, int flags) override { return ::open(path, flags); }
  int close(int fd) override { return ::close(fd); }
  int ioctl(int fd, unsigned long request, void* argument) override {
    int r;
    do {
      r = ::ioctl(fd, request, argument);
    } while (r == -1 && errno == EINTR);
    return r;
  }
  void* mmap(std::size_t length, int fd, off_t offset) override {
    return ::mmap(nullptr, length, PROT_READ | PROT_WRITE, MAP_SHARED, fd, offset);
  }
  int munmap(void* address, std::size_t length) override { return ::munmap(address, length); }
  int poll(pollfd* fds, nfds_t count, int timeout_ms) override { return ::poll(fds, count, timeout_ms); }
};

// Preferred formats, best first: 16-bit, 12- and 10-bit in 16-bit containers, then 8-bit.
constexpr std::uint32_t kFormats[] = {V4L2_PIX_FMT_Y16, V4L2_PIX_FMT_Y12, V4L2_PIX_FMT_Y10,
                                      V4L2_PIX_FMT_GREY};
constexpr std::uint32_t kMaxFormats = 256;  // formats enumerated, at most
constexpr std::uint32_t kMaxBuffers = 64;   // buffers a device may give for the ones asked
// A time stamp on CLOCK_MONOTONIC: seconds since boot, far below 2^62 ns.
constexpr std::int64_t kMaxTimestampS = std::int64_t(1) << 32;

std::string fourcc(std::uint32_t f) {
  std::string s(4, ' ');
  for (int i = 0; i < 4; ++i) s[std::size_t(i)] = static_cast<char>((f >> (8 * i)) & 0xFF);
  return s;
}

}  // namespace

V4l2Syscalls& real_v4l2_syscalls() {
  static KernelSyscalls kernel;
  return kernel;
}

V4l2Detector::V4l2Detector(V4l2DetectorOptions options, V4l2Syscalls& sys)
    : options_(std::move(options)), sys_(sys) {}

V4l2Detector::~V4l2Detector() {
  close();
}

Status V4l2Detector::fail(const std::string& what) {
  const std::string message = options_.device + ": " + what;
  close();
  return io_error(message);
}

Status V4l2Detector::open() {
  if (fd_ >= 0) return failed_precondition(options_.device + ": already open");
  if (options_.rows <= 0 || options_.cols <= 0 || options_.buffers < 2 || options_.buffers > 32)
    return invalid_argument(options_.device + ": needs rows, cols and 2..32 buffers");
  fd_ = sys_.open(options_.device.c_str(), O_RDWR | O_NONBLOCK | O_CLOEXEC);
  if (fd_ < 0) return not_found(options_.device + ": cannot open (" + std::strerror(errno) + ")");

  v4l2_capability cap{};
  if (sys_.ioctl(fd_, VIDIOC_QUERYCAP, &cap) != 0)
    return fail(std::string("not a V4L2 device (") + std::strerror(errno) + ")");
  const std::uint32_t caps =
      (cap.capabilities & V4L2_CAP_DEVICE_CAPS) != 0 ? cap.device_caps : cap.capabilities;
  if ((caps & V4L2_CAP_VIDEO_CAPTURE) == 0) return fail("cannot capture video (no V4L2_CAP_VIDEO_CAPTURE)");
  if ((caps & V4L2_CAP_STREAMING) == 0) return fail("cannot stream (no V4L2_CAP_STREAMING)");

  std::vector<std::uint32_t> offered;
  for (std::uint32_t i = 0; i < kMaxFormats; ++i) {  // bounded: a device may never say "no more"
    v4l2_fmtdesc d{};
    d.index = i;
    d.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    if (sys_.ioctl(fd_, VIDIOC_ENUM_FMT, &d) != 0) break;
    offered.push_back(d.pixelformat);
  }
  pixel_format_ = 0;
  for (std::uint32_t f : kFormats)
    if (std::find(offered.begin(), offered.end(), f) != offered.end()) {
      pixel_format_ = f;
      break;
    }
  if (pixel_format_ == 0) {
    std::string list;
    for (std::uint32_t f : offered) list += (list.empty() ? "" : ", ") + fourcc(f);
    return fail("offers no grey format lftrack reads (Y16, Y12, Y10, GREY); it offers " +
                (list.empty() ? std::string("none") : list));
  }
  v4l2_format format{};
  format.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  format.fmt.pix.width = static_cast<std::uint32_t>(options_.cols);
  format.fmt.pix.height = static_cast<std::uint32_t>(options_.rows);
  format.fmt.pix.pixelformat = pixel_format_;
  format.fmt.pix.field = V4L2_FIELD_NONE;
  if (sys_.ioctl(fd_, VIDIOC_S_FMT, &format) != 0)
    return fail(std::string("VIDIOC_S_FMT: ") + std::strerror(errno));
  if (format.fmt.pix.pixelformat != pixel_format_ || int(format.fmt.pix.width) != options_.cols ||
      int(format.fmt.pix.height) != options_.rows)
    return fail("gives " + std::to_string(format.fmt.pix.width) + " x " +
                std::to_string(format.fmt.pix.height) + " " + fourcc(format.fmt.pix.pixelformat) +
                " for the scene's " + std::to_string(options_.cols) + " x " + std::to_string(options_.rows) +
                " " + fourcc(pixel_format_));
  const std::uint32_t bytes_per_pixel = pixel_format_ == V4L2_PIX_FMT_GREY ? 1 : 2;
  bytes_per_line_ = std::max(format.fmt.pix.bytesperline, format.fmt.pix.width * bytes_per_pixel);
  frame_bytes_ = std::size_t(bytes_per_line_) * std::size_t(options_.rows - 1) +
                 std::size_t(options_.cols) * bytes_per_pixel;

  v4l2_requestbuffers request{};
  request.count = static_cast<std::uint32_t>(options_.buffers);
  request.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  request.memory = V4L2_MEMORY_MMAP;
  if (sys_.ioctl(fd_, VIDIOC_REQBUFS, &request) != 0)
    return fail(std::string("no mmap streaming buffers (VIDIOC_REQBUFS: ") + std::strerror(errno) + ")");
  if (request.count < 2) return fail("gives fewer than 2 buffers");
  if (request.count > kMaxBuffers)
    return fail("gives " + std::to_string(request.count) + " buffers for the " +
                std::to_string(options_.buffers) + " asked; at most " + std::to_string(kMaxBuffers) +
                " are mapped");
  buffers_.assign(request.count, {});
  for (std::uint32_t i = 0; i < request.count; ++i) {
    v4l2_buffer b{};
    b.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    b.memory = V4L2_MEMORY_MMAP;
    b.index = i;
    if (sys_.ioctl(fd_, VIDIOC_QUERYBUF, &b) != 0)
      return fail(std::string("VIDIOC_QUERYBUF: ") + std::strerror(errno));
    if (b.length < std::size_t(bytes_per_line_) * std::size_t(options_.rows))
      return fail("buffer smaller than a frame");
    void* p = sys_.mmap(b.length, fd_, static_cast<off_t>(b.m.offset));
    if (p == MAP_FAILED) return fail(std::string("mmap: ") + std::strerror(errno));
    buffers_[i] = {p, b.length};
    if (sys_.ioctl(fd_, VIDIOC_QBUF, &b) != 0)
      return fail(std::string("VIDIOC_QBUF: ") + std::strerror(errno));
  }
  if (options_.trigger_control_id != 0) {
    v4l2_queryctrl query{};
    query.id = options_.trigger_control_id;
    if (sys_.ioctl(fd_, VIDIOC_QUERYCTRL, &query) != 0 || (query.flags & V4L2_CTRL_FLAG_DISABLED) != 0)
      return fail("has no external-trigger control " + std::to_string(options_.trigger_control_id));
    v4l2_control control{};
    control.id = options_.trigger_control_id;
    control.value = options_.trigger_value;
    if (sys_.ioctl(fd_, VIDIOC_S_CTRL, &control) != 0)
      return fail(std::string("cannot switch the external trigger on: ") + std::strerror(errno));
  }
  int type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  if (sys_.ioctl(fd_, VIDIOC_STREAMON, &type) != 0)
    return fail(std::string("VIDIOC_STREAMON: ") + std::strerror(errno));
  have_sequence_ = false;
  return {};
}

void V4l2Detector::close() {
  if (fd_ < 0) return;
  int type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  (void)sys_.ioctl(fd_, VIDIOC_STREAMOFF, &type);
  for (Buffer& b : buffers_)
    if (b.data != nullptr) sys_.munmap(b.data, b.length);
  buffers_.clear();
  sys_.close(fd_);
  fd_ = -1;
}

Status V4l2Detector::reopen() {
  close();
  Status s = open();
  if (s.ok()) ++counters_.reopens;
  return s;
}

DeviceStatus V4l2Detector::disconnected() {
  ++counters_.disconnects;
  close();
  return DeviceStatus::kDisconnected;
}

void V4l2Detector::requeue(std::uint32_t index) {
  v4l2_buffer b{};
  b.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  b.memory = V4L2_MEMORY_MMAP;
  b.index = index;
  (void)sys_.ioctl(fd_, VIDIOC_QBUF, &b);
}

void V4l2Detector::copy_out(const Buffer& buffer, Frame* frame) const {
  const auto* bytes = static_cast<const std::uint8_t*>(buffer.data);
  for (int r = 0; r < options_.rows; ++r) {
    const std::uint8_t* line = bytes + std::size_t(r) * bytes_per_line_;
    std::uint16_t* out = &frame->pixels.at(r, 0);
    if (pixel_format_ == V4L2_PIX_FMT_GREY) {
      for (int c = 0; c < options_.cols; ++c) out[c] = line[c];
    } else {
      std::memcpy(out, line, std::size_t(options_.cols) * 2);  // little-endian counts, as the kernel gives
    }
  }
}

DeviceStatus V4l2Detector::capture(Frame* frame, Deadline deadline) {
  if (fd_ < 0) return DeviceStatus::kDisconnected;
  const auto left =
      std::chrono::duration_cast<std::chrono::milliseconds>(deadline - std::chrono::steady_clock::now());
  pollfd p{fd_, POLLIN, 0};
  const int ready = sys_.poll(&p, 1, static_cast<int>(std::max<long long>(0, left.count())));
  if (ready < 0 && errno != EINTR) return disconnected();
  if (ready > 0 && (p.revents & (POLLERR | POLLHUP | POLLNVAL)) != 0) return disconnected();
  if (ready <= 0) {
    ++counters_.timeouts;
    return DeviceStatus::kTimeout;
  }
  // The newest filled buffer; older ones go back unread. At most one pass over the buffers the
  // device has (plus one): a device that keeps handing buffers over is faulty, not endless.
  v4l2_buffer newest{};
  bool have = false, failed = false;
  for (std::size_t dequeued = 0;; ++dequeued) {
    if (dequeued > buffers_.size()) {
      ++counters_.bad_buffers;
      failed = true;
      break;
    }
    v4l2_buffer b{};
    b.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    b.memory = V4L2_MEMORY_MMAP;
    if (sys_.ioctl(fd_, VIDIOC_DQBUF, &b) != 0) {
      if (errno == EAGAIN) break;
      if (errno == ENODEV) return disconnected();
      ++counters_.io_errors;  // EIO and the like: this buffer is lost to us
      failed = true;
      break;
    }
    if (b.index >= buffers_.size()) {  // not a buffer we mapped: nothing to read, nothing to requeue
      ++counters_.bad_buffers;
      failed = true;
      continue;
    }
    if (have) {
      ++counters_.stale_dropped;
      requeue(newest.index);
    }
    newest = b;
    have = true;
  }
  if (!have) {
    if (failed) return DeviceStatus::kFault;
    ++counters_.timeouts;  // woken without a frame
    return DeviceStatus::kTimeout;
  }
  if ((newest.flags & V4L2_BUF_FLAG_ERROR) != 0 || failed) {
    ++counters_.error_buffers;
    requeue(newest.index);
    return DeviceStatus::kFault;
  }
  // A buffer whose bytes do not cover the frame is a torn transfer: its tail would be an older
  // frame's pixels. So is a time stamp that is not a CLOCK_MONOTONIC time.
  const bool timestamp_valid = newest.timestamp.tv_sec >= 0 && newest.timestamp.tv_sec < kMaxTimestampS &&
                               newest.timestamp.tv_usec >= 0 && newest.timestamp.tv_usec < 1'000'000;
  if (newest.bytesused < frame_bytes_ || !timestamp_valid) {
    ++counters_.bad_buffers;
    requeue(newest.index);
    return DeviceStatus::kFault;
  }
  if (have_sequence_) {
    const std::uint32_t step = newest.sequence - last_sequence_;  // modulo 2^32: a wrap is a step of 1
    if (step == 0 || step > 0x80000000u) {
      ++counters_.backwards;
      last_sequence_ = newest.sequence;
      requeue(newest.index);
      return DeviceStatus::kFault;
    }
    if (step > 1) {
      ++counters_.sequence_gaps;
      counters_.frames_lost += step - 1;
    }
  }
  have_sequence_ = true;
  last_sequence_ = newest.sequence;
  copy_out(buffers_[newest.index], frame);
  frame->sequence = newest.sequence;
  frame->timestamp_ns =
      std::int64_t(newest.timestamp.tv_sec) * 1'000'000'000 + std::int64_t(newest.timestamp.tv_usec) * 1000;
  requeue(newest.index);
  ++counters_.frames;
  return DeviceStatus::kOk;
}

V4l2FrameSource::V4l2FrameSource(std::vector<std::unique_ptr<V4l2Detector>> detectors, double max_skew_ms)
    : detectors_(std::move(detectors)), max_skew_ms_(max_skew_ms) {}

Status V4l2FrameSource::open(FramePair* pair) {
  pair->frames.resize(detectors_.size());
  for (std::size_t i = 0; i < detectors_.size(); ++i) {
    LFTRACK_RETURN_IF_ERROR(detectors_[i]->open());
  }
  return {};
}

DeviceStatus V4l2FrameSource::acquire(FramePair* pair, Deadline deadline) {
  for (std::size_t i = 0; i < detectors_.size(); ++i) {
    const DeviceStatus s = detectors_[i]->capture(&pair->frames[i], deadline);
    if (s != DeviceStatus::kOk) return s;
  }
  std::int64_t first = pair->frames[0].timestamp_ns, last = first;
  for (const Frame& f : pair->frames) {
    first = std::min(first, f.timestamp_ns);
    last = std::max(last, f.timestamp_ns);
  }
  if (double(last - first) > max_skew_ms_ * 1e6) {
    ++skewed_pairs_;
    return DeviceStatus::kFault;
  }
  return DeviceStatus::kOk;
}

void V4l2FrameSource::close() {
  for (auto& d : detectors_) d->close();
}

Status V4l2FrameSource::reopen_disconnected() {
  for (auto& d : detectors_)
    if (!d->is_open()) LFTRACK_RETURN_IF_ERROR(d->reopen());
  return {};
}

}  // namespace lftrack::drivers
