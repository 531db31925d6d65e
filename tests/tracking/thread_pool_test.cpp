#include <gtest/gtest.h>

#include <pthread.h>
#include <sched.h>

#include <atomic>
#include <chrono>
#include <thread>
#include <vector>

#include "lftrack/tracking/thread_pool.hpp"

namespace lftrack::tracking {
namespace {

TEST(ThreadPool, CoversEveryIndexExactlyOnce) {
  for (int threads : {1, 2, 4}) {
    ThreadPool pool(threads);
    EXPECT_EQ(pool.size(), threads);
    for (int count : {0, 1, 7, 1000}) {
      std::vector<std::atomic<int>> hits(static_cast<std::size_t>(count));
      pool.parallel_for(count, 3, [&](int b, int e) {
        for (int i = b; i < e; ++i) hits[static_cast<std::size_t>(i)].fetch_add(1);
      });
      for (int i = 0; i < count; ++i)
        ASSERT_EQ(hits[static_cast<std::size_t>(i)].load(), 1) << threads << " " << count;
    }
  }
}

TEST(ThreadPool, ManySuccessiveJobs) {
  ThreadPool pool(3);
  std::atomic<long> sum{0};
  for (int job = 0; job < 2000; ++job) {
    pool.parallel_for(64, 1, [&](int b, int e) { sum.fetch_add(e - b); });
  }
  EXPECT_EQ(sum.load(), 2000L * 64);
}

// A loop inside a loop on the same pool (a pooled renderer inside a registration's parallel
// candidates) runs the inner loop inline: every index once, and no deadlock.
TEST(ThreadPool, NestedLoopsOnTheSamePoolRunInline) {
  ThreadPool pool(3);
  std::vector<std::atomic<int>> hits(64 * 50);
  pool.parallel_for(64, 1, [&](int b, int e) {
    for (int i = b; i < e; ++i)
      pool.parallel_for(50, 4, [&](int ib, int ie) {
        for (int j = ib; j < ie; ++j) hits[static_cast<std::size_t>(i * 50 + j)].fetch_add(1);
      });
  });
  for (const auto& h : hits) ASSERT_EQ(h.load(), 1);
}

// thread_index() picks a registration's per-thread scratch: in range, and never held by two
// threads at once. Each chunk holds its index's flag a while, so that the threads overlap.
TEST(ThreadPool, ThreadIndexIsInRangeAndNeverSharedAtOnce) {
  for (int threads : {2, 3, 5}) {
    ThreadPool pool(threads);
    std::vector<std::atomic<int>> holding(static_cast<std::size_t>(threads));
    std::vector<std::atomic<int>> used(static_cast<std::size_t>(threads));
    std::atomic<int> out_of_range{0}, shared{0};
    for (int job = 0; job < 50; ++job) {
      pool.parallel_for(4 * threads, 1, [&](int, int) {
        const int index = pool.thread_index();
        if (index < 0 || index >= threads) {
          out_of_range.fetch_add(1);
          return;
        }
        if (holding[std::size_t(index)].fetch_add(1) != 0) shared.fetch_add(1);
        used[std::size_t(index)].fetch_add(1);
        std::this_thread::sleep_for(std::chrono::microseconds(200));
        holding[std::size_t(index)].fetch_sub(1);
      });
    }
    EXPECT_EQ(out_of_range.load(), 0) << threads;
    EXPECT_EQ(shared.load(), 0) << threads;
    EXPECT_GT(used[0].load(), 0) << "the calling thread runs chunks too";
  }
}

TEST(ThreadPool, ThreadIndexOutsideAJobAndInsideANestedLoop) {
  ThreadPool pool(3), other(2);
  EXPECT_EQ(pool.thread_index(), 0);
  std::atomic<int> mismatched{0}, other_nonzero{0};
  pool.parallel_for(12, 1, [&](int, int) {
    const int outer = pool.thread_index();
    pool.parallel_for(8, 2, [&](int, int) {  // inline: the same thread, the same index
      if (pool.thread_index() != outer) mismatched.fetch_add(1);
    });
    if (other.thread_index() != 0) other_nonzero.fetch_add(1);  // not in other's job
    std::this_thread::sleep_for(std::chrono::microseconds(100));
  });
  EXPECT_EQ(mismatched.load(), 0);
  EXPECT_EQ(other_nonzero.load(), 0);
  EXPECT_EQ(pool.thread_index(), 0);
}

// The registration's pattern: tens of thousands of tiny jobs back to back, each of two chunks,
// so that workers often arrive after the caller has taken every chunk (and leave the job
// alone) or finish after it (and the caller waits for them). Every result must be in place when
// parallel_for returns, and written once.
TEST(ThreadPool, TinyJobsBackToBackLeaveEveryResultInPlace) {
  for (int threads : {2, 3}) {
    ThreadPool pool(threads);
    int results[2] = {0, 0};
    long wrong = 0;
    for (int job = 1; job <= 20000; ++job) {
      pool.parallel_for(2, 1, [&](int b, int e) {
        for (int i = b; i < e; ++i) results[i] += job;  // a data race if two threads ran one index
      });
      wrong += results[0] != job * (job + 1) / 2 || results[1] != job * (job + 1) / 2;
      if (job % 4096 == 0) std::this_thread::sleep_for(std::chrono::microseconds(200));  // workers asleep
    }
    EXPECT_EQ(wrong, 0) << threads;
  }
}

// A pool with more threads than the CPUs it may run on does not spin (a spinning worker would
// hold up the caller on a shared CPU); it still covers every index once, and a pool made and
// dropped at once (workers still watching for a job) stops without a hang.
TEST(ThreadPool, MoreThreadsThanCpusAndShortLivedPools) {
  cpu_set_t before;
  CPU_ZERO(&before);
  ASSERT_EQ(::pthread_getaffinity_np(::pthread_self(), sizeof before, &before), 0);
  cpu_set_t one;
  CPU_ZERO(&one);
  for (int cpu = 0; cpu < CPU_SETSIZE; ++cpu)
    if (CPU_ISSET(cpu, &before)) {
      CPU_SET(cpu, &one);
      break;
    }
  ASSERT_EQ(::pthread_setaffinity_np(::pthread_self(), sizeof one, &one), 0);
  {
    ThreadPool pool(4);  // its workers inherit the one CPU
    std::atomic<long> sum{0};
    for (int job = 0; job < 500; ++job) pool.parallel_for(8, 1, [&](int b, int e) { sum.fetch_add(e - b); });
    EXPECT_EQ(sum.load(), 500L * 8);
  }
  ASSERT_EQ(::pthread_setaffinity_np(::pthread_self(), sizeof before, &before), 0);
  for (int i = 0; i < 200; ++i) {
    ThreadPool pool(2);
    std::atomic<int> n{0};
    pool.parallel_for(2, 1, [&](int b, int e) { n.fetch_add(e - b); });
    ASSERT_EQ(n.load(), 2);
  }
}

}  // namespace
}  // namespace lftrack::tracking
