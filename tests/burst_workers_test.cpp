#include "core/util/burst_workers.h"

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <memory>
#include <mutex>
#include <set>
#include <stdexcept>
#include <thread>
#include <vector>

namespace uavm {
namespace {

// Runs a loop of n items that each take `item_us` of work; returns how often each item ran and on which threads.
struct LoopRecord {
  std::vector<int> runs;
  std::set<std::thread::id> threads;
};

LoopRecord RunLoop(BurstWorkers* workers, int n, int item_us) {
  LoopRecord record;
  record.runs.assign(static_cast<size_t>(n), 0);
  std::vector<std::atomic<int>> runs(static_cast<size_t>(n));
  std::mutex mutex;
  workers->ForEach(n, [&](int i) {
    const auto until = std::chrono::steady_clock::now() + std::chrono::microseconds(item_us);
    while (std::chrono::steady_clock::now() < until) {
    }
    runs[static_cast<size_t>(i)].fetch_add(1);
    const std::lock_guard<std::mutex> lock(mutex);
    record.threads.insert(std::this_thread::get_id());
  });
  for (int i = 0; i < n; ++i) record.runs[static_cast<size_t>(i)] = runs[static_cast<size_t>(i)].load();
  return record;
}

// Every item runs once per loop, in a burst and outside one, loop after loop (a worker must neither miss a loop that
// reuses the last one's memory nor run a finished one again), and the workers take part.
TEST(BurstWorkersTest, EveryItemRunsOnceAndTheWorkersShare) {
  BurstWorkers workers(1);
  ASSERT_EQ(workers.threads(), 1);
  std::set<std::thread::id> seen;
  for (int burst = 0; burst < 2; ++burst) {
    const std::unique_ptr<BurstWorkers::Burst> awake =
        burst == 1 ? std::make_unique<BurstWorkers::Burst>(&workers) : nullptr;
    for (int loop = 0; loop < 200; ++loop) {
      const int n = 1 + loop % 17;
      const LoopRecord r = RunLoop(&workers, n, loop % 5 == 0 ? 200 : 5);
      for (int i = 0; i < n; ++i) ASSERT_EQ(r.runs[static_cast<size_t>(i)], 1) << "loop " << loop << " item " << i;
      seen.insert(r.threads.begin(), r.threads.end());
    }
  }
  EXPECT_EQ(seen.size(), 2u) << "the worker never took an item";
}

// Without workers the caller runs every item, in order.
TEST(BurstWorkersTest, NoWorkersRunsOnTheCaller) {
  BurstWorkers workers(0);
  const BurstWorkers::Burst awake(&workers);
  std::vector<int> order;
  workers.ForEach(5, [&](int i) { order.push_back(i); });
  EXPECT_EQ(order, (std::vector<int>{0, 1, 2, 3, 4}));
}

// An item's exception reaches the caller once the other items are done, and the workers go on working.
TEST(BurstWorkersTest, AnItemsExceptionReachesTheCaller) {
  BurstWorkers workers(1);
  const BurstWorkers::Burst awake(&workers);
  std::atomic<int> done{0};
  EXPECT_THROW(workers.ForEach(64,
                               [&](int i) {
                                 if (i == 7) throw std::runtime_error("item 7");
                                 std::this_thread::sleep_for(std::chrono::microseconds(50));
                                 done.fetch_add(1);
                               }),
               std::runtime_error);
  EXPECT_EQ(done.load(), 63);
  const LoopRecord r = RunLoop(&workers, 8, 10);
  for (const int runs : r.runs) EXPECT_EQ(runs, 1);
}

// A loop started inside an item (on the caller or on a worker) runs inline: every inner item once, no wait on itself.
TEST(BurstWorkersTest, ALoopInsideAnItemRunsInline) {
  BurstWorkers workers(1);
  const BurstWorkers::Burst awake(&workers);
  std::vector<std::atomic<int>> runs(8 * 5);
  for (int round = 0; round < 50; ++round) {
    for (auto& r : runs) r.store(0);
    workers.ForEach(8, [&](int outer) {
      workers.ForEach(5, [&](int inner) { runs[static_cast<size_t>(outer * 5 + inner)].fetch_add(1); });
    });
    for (const auto& r : runs) ASSERT_EQ(r.load(), 1) << "round " << round;
  }
}

// The destructor joins workers that sleep and workers that were just kept awake, at once.
TEST(BurstWorkersTest, StopsAsleepOrAwake) {
  const auto start = std::chrono::steady_clock::now();
  { BurstWorkers asleep(2); }
  auto awake = std::make_unique<BurstWorkers>(2);
  {
    const BurstWorkers::Burst burst(awake.get());
    (void)RunLoop(awake.get(), 4, 10);
  }
  awake.reset();
  EXPECT_LT(std::chrono::steady_clock::now() - start, std::chrono::seconds(2));
}

}  // namespace
}  // namespace uavm
