#include <gtest/gtest.h>

#include <atomic>
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

}  // namespace
}  // namespace lftrack::tracking
