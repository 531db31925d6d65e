#pragma once
// A scripted V4L2 capture device behind the driver's system-call seam (v4l2_syscalls.hpp): it
// answers the ioctls a capture driver makes with the kernel's semantics (queued and done
// buffers, mmap'd memory, poll readiness), logs every request, and lets a test expose frames
// and inject faults: an error-flagged buffer, EIO from DQBUF, an unplug (ENODEV, POLLERR).

#include <linux/videodev2.h>
#include <sys/mman.h>

#include <algorithm>
#include <cerrno>
#include <cstdint>
#include <cstring>
#include <deque>
#include <string>
#include <vector>

#include "lftrack/drivers/v4l2_syscalls.hpp"

namespace lftrack::test {

class ScriptedV4l2Device final : public drivers::V4l2Syscalls {
 public:
  // What the device offers.
  std::vector<std::uint32_t> formats = {V4L2_PIX_FMT_Y16, V4L2_PIX_FMT_GREY};
  std::uint32_t capabilities = V4L2_CAP_VIDEO_CAPTURE | V4L2_CAP_STREAMING;
  int width = 64, height = 48;  // what S_FMT grants
  std::uint32_t buffer_count = 4;
  std::uint32_t trigger_control = 0;  // a control it has (0: none)
  std::int32_t trigger_value = 0;     // what was set
  std::uint32_t granted_buffers = 0;  // REQBUFS grants this many when not 0 (else buffer_count)
  bool endless = false;               // DQBUF never says EAGAIN: it hands the last frame again

  // What the driver did.
  std::vector<std::string> log;
  bool streaming = false;
  int open_count = 0, close_count = 0, munmap_count = 0;

  // A frame: the first queued buffer is filled (row r, column c: value + c) and made ready;
  // with no buffer queued the frame is lost, as on a real device.
  // `bytes_used` (when not 0) is what DQBUF reports instead of the whole buffer: a torn transfer.
  // A time stamp may be given raw (`raw_seconds`, `raw_microseconds`), as a faulty device would.
  void expose(std::uint32_t sequence, std::int64_t timestamp_ns, std::uint16_t value,
              std::uint32_t flags = 0, std::uint32_t bytes_used = 0) {
    if (queued_.empty()) return;
    const std::uint32_t i = queued_.front();
    queued_.pop_front();
    const bool grey = format_ == V4L2_PIX_FMT_GREY;
    for (int r = 0; r < height; ++r)
      for (int c = 0; c < width; ++c) {
        const auto v = static_cast<std::uint16_t>(value + c);
        std::uint8_t* p =
            memory_[i].data() + std::size_t(r) * bytes_per_line() + std::size_t(c) * (grey ? 1 : 2);
        p[0] = static_cast<std::uint8_t>(v & 0xFF);
        if (!grey) p[1] = static_cast<std::uint8_t>(v >> 8);
      }
    Done d;
    d.index = i;
    d.sequence = sequence;
    d.flags = flags;
    d.timestamp_ns = timestamp_ns;
    d.bytes_used = bytes_used;
    done_.push_back(d);
  }
  void expose_raw_time(std::uint32_t sequence, std::int64_t raw_seconds, std::int64_t raw_microseconds) {
    const std::size_t ready = done_.size();
    expose(sequence, 0, 1);
    if (done_.size() == ready) return;  // no buffer queued: the frame was lost
    done_.back().raw_time = true;
    done_.back().raw_seconds = raw_seconds;
    done_.back().raw_microseconds = raw_microseconds;
  }
  void fail_next_dqbuf(int error) { dqbuf_errno_ = error; }
  void unplug() { unplugged_ = true; }
  void plug() { unplugged_ = false; }
  std::size_t queued() const { return queued_.size(); }

  int open(const char*, int) override {
    if (unplugged_) return errno = ENOENT, -1;
    ++open_count;
    queued_.clear();
    done_.clear();
    return kFd;
  }
  int close(int) override {
    ++close_count;
    streaming = false;
    return 0;
  }
  void* mmap(std::size_t length, int, off_t offset) override {
    const auto i = static_cast<std::size_t>(offset / kOffsetStep);
    if (i >= memory_.size() || length != memory_[i].size()) return errno = EINVAL, MAP_FAILED;
    return memory_[i].data();
  }
  int munmap(void*, std::size_t) override {
    ++munmap_count;
    return 0;
  }
  int poll(pollfd* fds, nfds_t, int) override {
    if (unplugged_) {
      fds[0].revents = POLLERR;
      return 1;
    }
    fds[0].revents = done_.empty() ? 0 : POLLIN;
    return done_.empty() ? 0 : 1;  // never sleeps: the script decides what is ready
  }
  int ioctl(int, unsigned long request, void* arg) override {
    if (unplugged_) return errno = ENODEV, -1;
    switch (request) {
      case VIDIOC_QUERYCAP: {
        log.push_back("QUERYCAP");
        auto* cap = static_cast<v4l2_capability*>(arg);
        std::memset(cap, 0, sizeof *cap);
        cap->capabilities = capabilities;
        return 0;
      }
      case VIDIOC_ENUM_FMT: {
        auto* d = static_cast<v4l2_fmtdesc*>(arg);
        log.push_back("ENUM_FMT");
        if (d->index >= formats.size()) return errno = EINVAL, -1;
        d->pixelformat = formats[d->index];
        return 0;
      }
      case VIDIOC_S_FMT: {
        log.push_back("S_FMT");
        auto* f = static_cast<v4l2_format*>(arg);
        format_ = f->fmt.pix.pixelformat;
        f->fmt.pix.width = static_cast<std::uint32_t>(width);
        f->fmt.pix.height = static_cast<std::uint32_t>(height);
        f->fmt.pix.bytesperline = static_cast<std::uint32_t>(bytes_per_line());
        return 0;
      }
      case VIDIOC_REQBUFS: {
        log.push_back("REQBUFS");
        auto* r = static_cast<v4l2_requestbuffers*>(arg);
        if (r->memory != V4L2_MEMORY_MMAP) return errno = EINVAL, -1;
        r->count = granted_buffers != 0 ? granted_buffers : buffer_count;
        memory_.assign(std::min<std::uint32_t>(r->count, 256),
                       std::vector<std::uint8_t>(bytes_per_line() * std::size_t(height)));
        return 0;
      }
      case VIDIOC_QUERYBUF: {
        log.push_back("QUERYBUF");
        auto* b = static_cast<v4l2_buffer*>(arg);
        if (b->index >= memory_.size()) return errno = EINVAL, -1;
        b->length = static_cast<std::uint32_t>(memory_[b->index].size());
        b->m.offset = b->index * kOffsetStep;
        return 0;
      }
      case VIDIOC_QBUF: {
        log.push_back("QBUF");
        queued_.push_back(static_cast<v4l2_buffer*>(arg)->index);
        return 0;
      }
      case VIDIOC_DQBUF: {
        if (dqbuf_errno_ != 0) {
          const int e = dqbuf_errno_;
          dqbuf_errno_ = 0;
          if (!done_.empty()) done_.pop_front();  // that buffer is lost
          return errno = e, -1;
        }
        if (done_.empty()) return errno = EAGAIN, -1;
        const Done d = done_.front();
        if (!endless || done_.size() > 1) done_.pop_front();
        auto* b = static_cast<v4l2_buffer*>(arg);
        b->index = d.index;
        b->sequence = d.sequence;
        b->flags = d.flags | V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC;
        b->bytesused = d.bytes_used != 0 ? d.bytes_used : static_cast<std::uint32_t>(memory_[d.index].size());
        b->timestamp.tv_sec = d.raw_time ? d.raw_seconds : d.timestamp_ns / 1'000'000'000;
        b->timestamp.tv_usec = d.raw_time ? d.raw_microseconds : (d.timestamp_ns % 1'000'000'000) / 1000;
        return 0;
      }
      case VIDIOC_QUERYCTRL: {
        log.push_back("QUERYCTRL");
        auto* q = static_cast<v4l2_queryctrl*>(arg);
        return q->id == trigger_control && trigger_control != 0 ? 0 : (errno = EINVAL, -1);
      }
      case VIDIOC_S_CTRL: {
        log.push_back("S_CTRL");
        trigger_value = static_cast<v4l2_control*>(arg)->value;
        return 0;
      }
      case VIDIOC_STREAMON:
        log.push_back("STREAMON");
        streaming = true;
        return 0;
      case VIDIOC_STREAMOFF:
        log.push_back("STREAMOFF");
        streaming = false;
        return 0;
      default:
        return errno = ENOTTY, -1;
    }
  }

 private:
  static constexpr int kFd = 42;
  static constexpr off_t kOffsetStep = 1 << 20;
  struct Done {
    std::uint32_t index = 0, sequence = 0, flags = 0, bytes_used = 0;
    std::int64_t timestamp_ns = 0;
    bool raw_time = false;
    std::int64_t raw_seconds = 0, raw_microseconds = 0;
  };
  std::size_t bytes_per_line() const { return std::size_t(width) * (format_ == V4L2_PIX_FMT_GREY ? 1 : 2); }

  std::uint32_t format_ = V4L2_PIX_FMT_Y16;
  std::vector<std::vector<std::uint8_t>> memory_;
  std::deque<std::uint32_t> queued_;
  std::deque<Done> done_;
  int dqbuf_errno_ = 0;
  bool unplugged_ = false;
};

}  // namespace lftrack::test
