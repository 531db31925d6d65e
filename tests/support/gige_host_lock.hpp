#pragma once
// One GigE Vision test at a time on this host, across processes (ctest -j): every fake camera
// needs UDP port 3956 on its own address, so tests that serve cameras hold this file lock.

#include <fcntl.h>
#include <sys/file.h>
#include <unistd.h>

#include <filesystem>

namespace lftrack::test {

class GigeHostLock {
 public:
  GigeHostLock() {
    const auto path = std::filesystem::temp_directory_path() / "lftrack-gige-tests.lock";
    fd_ = ::open(path.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0666);
    if (fd_ >= 0) (void)flock(fd_, LOCK_EX);
  }
  ~GigeHostLock() {
    if (fd_ >= 0) ::close(fd_);  // releases the lock
  }
  GigeHostLock(const GigeHostLock&) = delete;
  GigeHostLock& operator=(const GigeHostLock&) = delete;

 private:
  int fd_ = -1;
};

}  // namespace lftrack::test
