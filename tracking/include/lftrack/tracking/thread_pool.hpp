#pragma once
// A fixed pool of worker threads for data-parallel loops.
//
// Components below firmware_host never start threads of their own; whoever owns the process
// (the lftrack program, a test, a benchmark) constructs one pool and passes it down.
// parallel_for allocates nothing, so it may be called from the real-time cycle. One
// parallel_for runs at a time per pool (calls from several threads are serialised); a
// parallel_for called from inside a job of the same pool (a renderer given the pool, called from
// a registration's parallel candidates) runs inline on the calling thread.

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

  // Calls body(begin, end) on disjoint chunks that cover [0, count), using every worker and the
  // calling thread; returns when all chunks are done. `grain` is the chunk length.
  template <class Body>
  void parallel_for(int count, int grain, const Body& body) {
    run(count, grain, &invoke<Body>, &body);
  }

 private:
  using Trampoline = void (*)(const void* body, int begin, int end);
  template <class Body>
  static void invoke(const void* body, int begin, int end) {
    (*static_cast<const Body*>(body))(begin, end);
  }
  void run(int count, int grain, Trampoline fn, const void* body);
  void work_on_current_job();
  void worker_loop();

  std::vector<std::thread> workers_;
  std::mutex run_mutex_;  // serialises run()
  std::mutex mutex_;
  std::condition_variable wake_;
  std::condition_variable done_;
  std::uint64_t generation_ = 0;
  bool stopping_ = false;
  int busy_workers_ = 0;
  // The current job.
  Trampoline fn_ = nullptr;
  const void* body_ = nullptr;
  int count_ = 0;
  int grain_ = 1;
  std::atomic<int> next_{0};
};

}  // namespace lftrack::tracking
