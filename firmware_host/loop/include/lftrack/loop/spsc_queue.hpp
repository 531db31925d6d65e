#pragma once
// A bounded single-producer single-consumer queue of trivially copyable items: the cycle pushes
// journal records, the writer thread pops them. Lock-free (two atomic indices), allocation only
// at construction, push never blocks: when full it returns false and the producer counts the
// loss (the journal records how many were dropped before the next record).

#include <atomic>
#include <cstddef>
#include <type_traits>
#include <vector>

namespace lftrack::loop {

template <class T>
class SpscQueue {
  static_assert(std::is_trivially_copyable_v<T>);

 public:
  // Holds up to `capacity` items (rounded up to a power of two).
  explicit SpscQueue(std::size_t capacity) {
    std::size_t n = 2;
    while (n < capacity) n *= 2;
    slots_.resize(n);
    mask_ = n - 1;
  }
  std::size_t capacity() const { return slots_.size(); }

  // Producer only.
  bool push(const T& item) {
    const std::size_t head = head_.load(std::memory_order_relaxed);
    if (head - tail_.load(std::memory_order_acquire) >= slots_.size()) return false;
    slots_[head & mask_] = item;
    head_.store(head + 1, std::memory_order_release);
    return true;
  }
  // Consumer only.
  bool pop(T* item) {
    const std::size_t tail = tail_.load(std::memory_order_relaxed);
    if (tail == head_.load(std::memory_order_acquire)) return false;
    *item = slots_[tail & mask_];
    tail_.store(tail + 1, std::memory_order_release);
    return true;
  }
  bool empty() const { return tail_.load(std::memory_order_acquire) == head_.load(std::memory_order_acquire); }
  // Any thread: items pushed since construction (not those refused when full).
  std::size_t pushed() const { return head_.load(std::memory_order_acquire); }

 private:
  std::vector<T> slots_;
  std::size_t mask_ = 0;
  alignas(64) std::atomic<std::size_t> head_{0};
  alignas(64) std::atomic<std::size_t> tail_{0};
};

}  // namespace lftrack::loop
