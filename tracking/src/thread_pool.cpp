#include "lftrack/tracking/thread_pool.hpp"

#include <sched.h>

#include <algorithm>
#include <chrono>

namespace lftrack::tracking {
namespace {
// The pool whose job this thread is working on, if any: a parallel_for called from inside a job
// of the same pool runs inline (waiting for the pool from one of its own jobs would deadlock).
thread_local const ThreadPool* t_working_for = nullptr;
thread_local int t_thread_index = 0;  // in t_working_for's job

std::int64_t steady_ns() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

inline void cpu_relax() {
#if defined(__x86_64__) || defined(__i386__)
  __builtin_ia32_pause();
#endif
}

// Spins until done() or kSpinNs have passed; true if done().
template <class Done>
bool spin_until(std::int64_t spin_ns, const Done& done) {
  const std::int64_t until = steady_ns() + spin_ns;
  for (int i = 0;; ++i) {
    if (done()) return true;
    cpu_relax();
    if ((i & 63) == 63 && steady_ns() > until) return done();
  }
}

int cpus_allowed() {
  cpu_set_t set;
  CPU_ZERO(&set);
  if (::sched_getaffinity(0, sizeof set, &set) != 0) return 1;
  return CPU_COUNT(&set);
}
}  // namespace

ThreadPool::ThreadPool(int threads) {
  if (threads <= 0) threads = static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
  spin_ = threads <= cpus_allowed();
  workers_.reserve(static_cast<std::size_t>(threads - 1));
  for (int i = 1; i < threads; ++i) workers_.emplace_back([this, i] { worker_loop(i); });
}

ThreadPool::~ThreadPool() {
  {
    std::lock_guard lock(mutex_);
    stopping_ = true;
  }
  wake_.notify_all();
  for (auto& t : workers_) t.join();
}

int ThreadPool::thread_index() const {
  return t_working_for == this ? t_thread_index : 0;
}

void ThreadPool::work_on_current_job(int thread_index) {
  const ThreadPool* outer = t_working_for;
  const int outer_index = t_thread_index;
  t_working_for = this;
  t_thread_index = thread_index;
  for (;;) {
    const int begin = next_.fetch_add(grain_, std::memory_order_relaxed);
    if (begin >= count_) break;
    fn_(body_, begin, std::min(count_, begin + grain_));
  }
  t_working_for = outer;
  t_thread_index = outer_index;
}

ThreadPool::Joined ThreadPool::wait_and_join(std::uint64_t* seen) {
  if (spin_) spin_until(kSpinNs, [&] { return generation_.load(std::memory_order_acquire) != *seen; });
  std::unique_lock lock(mutex_);
  if (generation_.load(std::memory_order_relaxed) == *seen && !stopping_) {
    ++sleeping_workers_;
    wake_.wait(lock, [&] { return stopping_ || generation_.load(std::memory_order_relaxed) != *seen; });
    --sleeping_workers_;
  }
  if (stopping_) return Joined::kStopping;
  *seen = generation_.load(std::memory_order_relaxed);
  if (!job_open_) return Joined::kTooLate;  // its caller took every chunk before this worker came
  joined_workers_.fetch_add(1, std::memory_order_relaxed);
  return Joined::kYes;
}

void ThreadPool::worker_loop(int thread_index) {
  std::uint64_t seen = 0;
  for (;;) {
    const Joined joined = wait_and_join(&seen);
    if (joined == Joined::kStopping) return;
    if (joined == Joined::kTooLate) continue;
    work_on_current_job(thread_index);
    bool last = false;
    {
      std::lock_guard lock(mutex_);
      // Release: the chunks' results are visible to a caller that sees the count reach zero.
      last = joined_workers_.fetch_sub(1, std::memory_order_acq_rel) == 1 && !job_open_;
    }
    if (last) done_.notify_one();
  }
}

void ThreadPool::run(int count, int grain, Trampoline fn, const void* body) {
  if (count <= 0) return;
  grain = std::max(1, grain);
  if (workers_.empty() || count <= grain || t_working_for == this) {
    fn(body, 0, count);
    return;
  }
  std::lock_guard run_lock(run_mutex_);
  bool wake = false;
  {
    std::lock_guard lock(mutex_);
    fn_ = fn;
    body_ = body;
    count_ = count;
    grain_ = grain;
    next_.store(0, std::memory_order_relaxed);
    job_open_ = true;
    generation_.store(generation_.load(std::memory_order_relaxed) + 1, std::memory_order_release);
    wake = sleeping_workers_ > 0;
  }
  if (wake) wake_.notify_all();
  work_on_current_job(0);
  // Every chunk is taken; a worker that has joined may still be running one.
  {
    std::lock_guard lock(mutex_);
    job_open_ = false;
    if (joined_workers_.load(std::memory_order_acquire) == 0) return;
  }
  if (spin_ && spin_until(kSpinNs, [&] { return joined_workers_.load(std::memory_order_acquire) == 0; })) return;
  std::unique_lock lock(mutex_);
  done_.wait(lock, [&] { return joined_workers_.load(std::memory_order_acquire) == 0; });
}

}  // namespace lftrack::tracking
