#pragma once
// A fixed pool of worker threads for data-parallel loops.
//
// Components below firmware_host never start threads of their own; whoever owns the process
// (the lftrack program, a test, a benchmark) constructs one pool and passes it down.
// parallel_for allocates nothing, so it may be called from the real-time cycle. One
// parallel_for runs at a time per pool (calls from several threads are serialised); a
// parallel_for called from inside a job of the same pool (a renderer given the pool, called from
// a registration's parallel candidates) runs inline on the calling thread.
//
// Kept by hand rather than taken from a task scheduler (oneTBB manages threads of its own): the
// cycle needs a pool that allocates nothing per job and whose threads are made after the
// real-time set-up, so that they inherit its SCHED_FIFO priority and CPU mask. Two measures keep
// a short job (a registration's one candidate: two views of 10-20 us each) from paying a
// sleeping thread's wake-up (25-40 us on a virtual machine, longer than the job) on every call:
// - a worker that finishes a job watches for the next one for kSpinNs before it sleeps, and the
//   caller watches its joined workers finish for as long before it sleeps; both only when the
//   pool has no more threads than the CPUs it may run on, so a spinning thread never holds up
//   another of its own pool;
// - the caller never waits for a worker that has not started: a worker that wakes after the
//   caller has taken every chunk leaves the job alone.

#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <mutex>
#include <thread>
#include <vector>

namespace lftrack::tracking {

class ThreadPool {
 public:
  // `threads` workers in total, counting the calling thread (so 1 means run inline).
  // 0 picks std::thread::hardware_concurrency().
  explicit ThreadPool(int threads = 0);
  ~ThreadPool();
  ThreadPool(const ThreadPool&) = delete;
  ThreadPool& operator=(const ThreadPool&) = delete;

  int size() const { return static_cast<int>(workers_.size()) + 1; }

  // Calls body(begin, end) on disjoint chunks that cover [0, count), using every worker that
  // joins in time and the calling thread; returns when all chunks are done. `grain` is the chunk
  // length. Which thread runs which chunk depends on timing. The body must not throw: an
  // exception on a worker ends the process, and one on the caller would leave the workers on a
  // body that is gone.
  template <class Body>
  void parallel_for(int count, int grain, const Body& body) {
    run(count, grain, &invoke<Body>, &body);
  }

  // Inside a body: the running thread's index in [0, size()), distinct for threads running
  // chunks of one job at the same time (0: the thread that called parallel_for, or a chunk run
  // inline), so that a body can pick per-thread scratch. Outside this pool's jobs: 0.
  int thread_index() const;

 private:
  using Trampoline = void (*)(const void* body, int begin, int end);
  template <class Body>
  static void invoke(const void* body, int begin, int end) {
    (*static_cast<const Body*>(body))(begin, end);
  }
  void run(int count, int grain, Trampoline fn, const void* body);
  void work_on_current_job(int thread_index);
  void worker_loop(int thread_index);
  // Waits (spinning, then asleep) for a job after generation `seen`, and joins it if it is still
  // open.
  enum class Joined { kYes, kTooLate, kStopping };
  Joined wait_and_join(std::uint64_t* seen);

  static constexpr std::int64_t kSpinNs = 60'000;

  std::vector<std::thread> workers_;
  std::mutex run_mutex_;  // serialises run()
  std::mutex mutex_;
  std::condition_variable wake_;
  std::condition_variable done_;
  bool spin_ = false;  // size() <= the CPUs this process may run on
  // Written under mutex_; read without it by spinning threads.
  std::atomic<std::uint64_t> generation_{0};
  std::atomic<int> joined_workers_{0};
  bool stopping_ = false;
  int sleeping_workers_ = 0;
  // The current job: open while its caller still runs chunks; a worker joins only an open job,
  // and the caller, once it has closed the job, waits for the workers that joined.
  bool job_open_ = false;
  Trampoline fn_ = nullptr;
  const void* body_ = nullptr;
  int count_ = 0;
  int grain_ = 1;
  std::atomic<int> next_{0};
};

}  // namespace lftrack::tracking
