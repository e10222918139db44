// The drop-oldest capture queue and its RAII buffer handles: every buffer goes back to its pool exactly once,
// whether consumed, dropped, cleared or refused by a closed queue.
#include "hal/common/capture_queue.h"

#include <gtest/gtest.h>

#include <atomic>
#include <set>
#include <thread>
#include <vector>

namespace uavm::hal {
namespace {

class CountingPool final : public BufferPool {
 public:
  void Return(uint32_t slot, uint64_t generation) noexcept override {
    std::lock_guard<std::mutex> lock(mutex_);
    returned.push_back(slot);
    last_generation = generation;
  }
  CapturedBuffer Make(uint32_t slot, uint64_t sequence = 0) {
    return CapturedBuffer(this, slot, 7, RawImage{}, static_cast<int64_t>(sequence) * 1000, sequence);
  }
  std::mutex mutex_;
  std::vector<uint32_t> returned;
  uint64_t last_generation = 0;
};

TEST(CapturedBuffer, ReturnsOnceWhenDestroyedOrMoved) {
  CountingPool pool;
  {
    CapturedBuffer a = pool.Make(3);
    CapturedBuffer b = std::move(a);
    EXPECT_FALSE(a.valid());
    EXPECT_TRUE(b.valid());
    CapturedBuffer c = pool.Make(4);
    c = std::move(b);  // c's own buffer (4) goes back now
    ASSERT_EQ(pool.returned.size(), 1u);
    EXPECT_EQ(pool.returned[0], 4u);
    c.Release();
    c.Release();  // idempotent
  }
  ASSERT_EQ(pool.returned.size(), 2u);
  EXPECT_EQ(pool.returned[1], 3u);
  EXPECT_EQ(pool.last_generation, 7u);
}

TEST(CaptureQueue, DropsOldestAndCounts) {
  CountingPool pool;
  CaptureQueue q(2);
  for (uint32_t i = 0; i < 5; ++i) EXPECT_TRUE(q.Push(pool.Make(i, i)));
  EXPECT_EQ(q.size(), 2u);
  EXPECT_EQ(q.dropped(), 3u);
  EXPECT_EQ(q.pushed(), 5u);
  EXPECT_EQ(q.high_water(), 2u);
  // The dropped ones (the oldest) went back to the pool at once.
  EXPECT_EQ(pool.returned, (std::vector<uint32_t>{0, 1, 2}));
  auto a = q.Pop(std::chrono::milliseconds(0));
  ASSERT_TRUE(a);
  EXPECT_EQ(a->sequence(), 3u);
  auto b = q.Pop(std::chrono::milliseconds(0));
  ASSERT_TRUE(b);
  EXPECT_EQ(b->sequence(), 4u);
  EXPECT_FALSE(q.Pop(std::chrono::milliseconds(10)));
}

TEST(CaptureQueue, ClearAndCloseReturnEverything) {
  CountingPool pool;
  {
    CaptureQueue q(4);
    for (uint32_t i = 0; i < 3; ++i) (void)q.Push(pool.Make(i));
    EXPECT_EQ(q.Clear(), 3u);
    EXPECT_EQ(q.dropped(), 3u);
    EXPECT_EQ(pool.returned.size(), 3u);
    (void)q.Push(pool.Make(9));
    q.Close();
    EXPECT_FALSE(q.Push(pool.Make(10)));  // refused, and returned
    EXPECT_EQ(pool.returned.size(), 4u);
    auto left = q.Pop(std::chrono::milliseconds(0));  // a closed queue still drains
    ASSERT_TRUE(left);
    EXPECT_FALSE(q.Pop(std::chrono::milliseconds(0)));
  }
  EXPECT_EQ(pool.returned.size(), 5u);
}

// A fast producer and a slow consumer on two threads: the producer never waits, the queue never exceeds its
// capacity, and produced = consumed + dropped, every buffer returned exactly once.
TEST(CaptureQueue, ProducerNeverBlocksOnSlowConsumer) {
  CountingPool pool;
  CaptureQueue q(3);
  constexpr uint32_t kN = 2000;
  std::atomic<bool> done{false};
  size_t consumed = 0;
  std::thread consumer([&] {
    for (;;) {
      auto b = q.Pop(std::chrono::milliseconds(50));
      if (!b) {
        if (done) break;
        continue;
      }
      ++consumed;
      std::this_thread::sleep_for(std::chrono::microseconds(200));
    }
  });
  for (uint32_t i = 0; i < kN; ++i) ASSERT_TRUE(q.Push(pool.Make(i, i)));
  done = true;
  q.Close();
  consumer.join();
  EXPECT_LE(q.high_water(), 3u);
  EXPECT_GT(q.dropped(), 0u);
  EXPECT_EQ(consumed + q.dropped(), kN);
  std::set<uint32_t> unique(pool.returned.begin(), pool.returned.end());
  EXPECT_EQ(pool.returned.size(), kN);
  EXPECT_EQ(unique.size(), kN);
}

}  // namespace
}  // namespace uavm::hal
