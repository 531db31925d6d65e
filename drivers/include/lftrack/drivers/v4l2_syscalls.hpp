#pragma once
// The system calls the V4L2 detector driver makes, behind one small interface, so the same driver
// code runs against the kernel (real_v4l2_syscalls()) and against a scripted device in tests
// (tests/protocol/scripted_v4l2_device.hpp). Each has the system call's contract: -1 and errno
// on failure (MAP_FAILED for mmap).

#include <poll.h>
#include <sys/types.h>

#include <cstddef>

namespace lftrack::drivers {

class V4l2Syscalls {
 public:
  virtual ~V4l2Syscalls() = default;
  virtual int open(const char* path, int flags) = 0;
  virtual int close(int fd) = 0;
  virtual int ioctl(int fd, unsigned long request, void* argument) = 0;
  virtual void* mmap(std::size_t length, int fd, off_t offset) = 0;  // PROT_READ|PROT_WRITE, MAP_SHARED
  virtual int munmap(void* address, std::size_t length) = 0;
  virtual int poll(pollfd* fds, nfds_t count, int timeout_ms) = 0;
};

// The kernel's calls (ioctl retried on EINTR).
V4l2Syscalls& real_v4l2_syscalls();

}  // namespace lftrack::drivers
