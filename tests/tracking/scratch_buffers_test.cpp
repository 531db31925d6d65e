// The renderer's scratch (tracking/src/scratch_buffers.hpp, private to the tracking library):
// buffers made once, each lent to one call at a time, and a buffer of its own past them.

#include "../../tracking/src/scratch_buffers.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <set>
#include <thread>
#include <vector>

long lftrack_test_allocations();  // tests/tracking/drr_renderer_test.cpp counts every operator new

namespace lftrack::tracking {
namespace {

TEST(ScratchBuffers, LendsEachBufferToOneCallAtATimeWithoutAllocating) {
  const ScratchBuffers scratch(3, 1000);
  std::array<float*, 3> lent{};
  const long before = lftrack_test_allocations();
  {
    ScratchBuffers::Lease a = scratch.borrow(1000);
    ScratchBuffers::Lease b = scratch.borrow(10);
    ScratchBuffers::Lease c = scratch.borrow(0);
    lent = {a.data(), b.data(), c.data()};
    EXPECT_FALSE(a.own() || b.own() || c.own());
  }
  // Returned: the next borrow takes one of the same three.
  ScratchBuffers::Lease again = scratch.borrow(1000);
  const long allocations = lftrack_test_allocations() - before;
  EXPECT_EQ(allocations, 0);
  EXPECT_EQ(std::set<float*>(lent.begin(), lent.end()).size(), 3u);
  EXPECT_NE(std::find(lent.begin(), lent.end(), again.data()), lent.end());
}

TEST(ScratchBuffers, PastItsBuffersOrTheirSizeACallGetsABufferOfItsOwn) {
  const ScratchBuffers scratch(1, 100);
  ScratchBuffers::Lease held = scratch.borrow(100);
  ASSERT_FALSE(held.own());
  const long before = lftrack_test_allocations();
  {
    ScratchBuffers::Lease extra = scratch.borrow(100);  // the only buffer is lent
    EXPECT_TRUE(extra.own());
    EXPECT_NE(extra.data(), held.data());
    extra.data()[99] = 1.0f;  // it holds what was asked for
  }
  EXPECT_GT(lftrack_test_allocations() - before, 0);
  const ScratchBuffers small(2, 100);
  ScratchBuffers::Lease large = small.borrow(101);
  EXPECT_TRUE(large.own());
  large.data()[100] = 1.0f;
  // A set asked for no buffers still keeps one.
  EXPECT_EQ(ScratchBuffers(0, 8).buffers(), 1);
  EXPECT_EQ(ScratchBuffers(-5, 8).buffers(), 1);
}

// Threads that borrow at once never share a buffer: each fills its lease with its own number and
// finds it unchanged before returning it.
TEST(ScratchBuffers, CallsRunningAtOnceNeverShareABuffer) {
  constexpr int kThreads = 4;
  constexpr std::size_t kFloats = 512;
  const ScratchBuffers scratch(2, kFloats);  // fewer buffers than threads: some get their own
  std::atomic<int> overwritten{0};
  std::atomic<int> own{0};
  std::vector<std::thread> threads;
  for (int t = 0; t < kThreads; ++t) {
    threads.emplace_back([&, t] {
      for (int round = 0; round < 2000; ++round) {
        ScratchBuffers::Lease lease = scratch.borrow(kFloats);
        own.fetch_add(lease.own() ? 1 : 0);
        float* values = lease.data();
        for (std::size_t i = 0; i < kFloats; ++i) values[i] = float(t);
        std::this_thread::yield();
        for (std::size_t i = 0; i < kFloats; ++i)
          if (values[i] != float(t)) {
            overwritten.fetch_add(1);
            break;
          }
      }
    });
  }
  for (auto& thread : threads) thread.join();
  EXPECT_EQ(overwritten.load(), 0);
  EXPECT_LT(own.load(), kThreads * 2000);  // the kept buffers were lent too
}

}  // namespace
}  // namespace lftrack::tracking
