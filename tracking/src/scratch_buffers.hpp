#pragma once
// Float buffers made once, lent to calls that may run at once (a const renderer called from a
// registration's pool threads and from another thread): a call borrows one for its duration.
//
// Contract: the buffers are allocated when the set is made, so borrowing allocates nothing as
// long as no more calls hold one at a time than there are buffers and a call asks for no more
// floats than a buffer holds; a call past either gets a buffer of its own, allocated for it and
// freed when it returns, so it is never refused and never shares memory with another call.
// Thread-safe; lock-free (one atomic exchange per buffer tried).
//
// Why not a thread_local buffer, as before: it is sized on each thread's first call, so a
// thread that happened to miss a warm-up (a pool worker preempted while the caller took every
// chunk) allocated in the middle of a registration later.

#include <atomic>
#include <cstddef>
#include <memory>
#include <vector>

namespace lftrack::tracking {

class ScratchBuffers {
 public:
  ScratchBuffers(int buffers, std::size_t floats_each)
      : count_(buffers > 0 ? buffers : 1), floats_each_(floats_each), slots_(new Slot[std::size_t(count_)]) {
    for (int i = 0; i < count_; ++i) slots_[std::size_t(i)].values.resize(floats_each_);
  }

  // A borrowed buffer of at least the floats asked for; returned when the lease ends.
  class Lease {
   public:
    Lease(const Lease&) = delete;
    Lease& operator=(const Lease&) = delete;
    ~Lease() {
      if (busy_ != nullptr) busy_->store(false, std::memory_order_release);
    }
    float* data() { return data_; }
    bool own() const { return busy_ == nullptr; }  // allocated for this lease alone

   private:
    friend class ScratchBuffers;
    Lease(std::atomic<bool>* busy, float* data) : busy_(busy), data_(data) {}
    explicit Lease(std::size_t floats) : own_(floats), data_(own_.data()) {}
    std::atomic<bool>* busy_ = nullptr;
    std::vector<float> own_;
    float* data_ = nullptr;
  };

  Lease borrow(std::size_t floats) const {
    if (floats <= floats_each_) {
      for (int i = 0; i < count_; ++i) {
        Slot& slot = slots_[std::size_t(i)];
        // Acquire: the previous borrower's writes are done before this one writes.
        if (!slot.busy.load(std::memory_order_relaxed) && !slot.busy.exchange(true, std::memory_order_acquire))
          return Lease(&slot.busy, slot.values.data());
      }
    }
    return Lease(floats);
  }

  int buffers() const { return count_; }

 private:
  struct Slot {
    std::atomic<bool> busy{false};
    std::vector<float> values;
  };
  int count_;
  std::size_t floats_each_;
  std::unique_ptr<Slot[]> slots_;
};

}  // namespace lftrack::tracking
