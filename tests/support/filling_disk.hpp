#pragma once
// A journal disk that fills up (JournalOptions::sink): write(2) takes bytes until a budget is
// spent, the last write partly, then fails with ENOSPC as a real file system does, after
// `slow_to_tell` (a disk slow to say it is full: the writer thread learns of it long after the
// cycle that queued the record).

#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <chrono>
#include <thread>

#include "lftrack/loop/journal.hpp"

namespace lftrack::test {

class FillingDisk final : public loop::JournalSink {
 public:
  explicit FillingDisk(long long bytes_left,
                       std::chrono::milliseconds slow_to_tell = std::chrono::milliseconds(0))
      : left_(bytes_left), slow_to_tell_(slow_to_tell) {}
  ssize_t write(int fd, const void* data, std::size_t bytes) override {
    const long long left = left_.load();
    if (left <= 0) {
      std::this_thread::sleep_for(slow_to_tell_);
      errno = ENOSPC;
      return -1;
    }
    const std::size_t n = std::min<std::size_t>(bytes, static_cast<std::size_t>(left));
    const ssize_t written = ::write(fd, data, n);
    if (written > 0) left_.fetch_sub(written);  // what the file took (one writer per disk)
    return written;
  }

 private:
  std::atomic<long long> left_;
  const std::chrono::milliseconds slow_to_tell_;
};

}  // namespace lftrack::test
