#pragma once
// Throttled, thread-safe progress reporting for long builds (light fields): at most four calls
// a second, plus the final one.

#include <atomic>
#include <chrono>
#include <cstdint>
#include <functional>
#include <mutex>

namespace lftrack::tracking::detail {

class BuildProgress {
 public:
  // `fn` (may be empty) must outlive this; it is called with the fraction of `total` units done,
  // from whichever thread finished a unit.
  BuildProgress(const std::function<void(double)>& fn, std::int64_t total) : fn_(fn), total_(total) {}
  void advance() {
    const std::int64_t done = done_.fetch_add(1) + 1;
    if (!fn_) return;
    const auto now = std::chrono::steady_clock::now();
    std::unique_lock lock(mutex_, std::try_to_lock);
    if (!lock.owns_lock()) return;
    if (done < total_ && now - last_ < std::chrono::milliseconds(250)) return;
    last_ = now;
    fn_(double(done) / double(total_));
  }

 private:
  const std::function<void(double)>& fn_;
  std::int64_t total_;
  std::atomic<std::int64_t> done_{0};
  std::mutex mutex_;
  std::chrono::steady_clock::time_point last_{};
};

}  // namespace lftrack::tracking::detail
