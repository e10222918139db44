// ParallelFor (core/util/parallel.h): every index exactly once, on the number of workers asked for (the caller
// being one), started in increasing order, with results independent of the thread count.
#include "core/util/parallel.h"

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <mutex>
#include <set>
#include <thread>
#include <tuple>
#include <vector>

namespace uavm {
namespace {

TEST(ParallelForTest, EveryIndexOnce) {
  for (int threads : {1, 2, 3, 8}) {
    for (size_t n : {size_t{0}, size_t{1}, size_t{2}, size_t{7}, size_t{1000}}) {
      std::vector<std::atomic<int>> hits(n);
      ParallelFor(n, threads, [&](size_t i) { ++hits[i]; });
      for (size_t i = 0; i < n; ++i) EXPECT_EQ(hits[i].load(), 1) << "n " << n << " threads " << threads << " i " << i;
    }
  }
}

TEST(ParallelForTest, WorkerCountIsMinOfThreadsAndItems) {
  const auto caller = std::this_thread::get_id();
  const std::vector<std::tuple<int, int, int>> cases = {{1, 50, 1}, {4, 2, 2}, {4, 400, 4}, {0, 10, 1}, {-3, 10, 1}};
  for (const auto& [threads, n, expected] : cases) {
    std::mutex m;
    std::set<std::thread::id> ids;
    std::atomic<int> inside{0};
    std::atomic<int> most{0};
    ParallelFor(static_cast<size_t>(n), threads, [&](size_t) {
      const int now = ++inside;
      for (int seen = most; now > seen && !most.compare_exchange_weak(seen, now);) {
      }
      // Long enough for every worker to take items while the others are busy.
      std::this_thread::sleep_for(std::chrono::milliseconds(2));
      {
        std::lock_guard<std::mutex> lock(m);
        ids.insert(std::this_thread::get_id());
      }
      --inside;
    });
    EXPECT_LE(static_cast<int>(ids.size()), expected) << threads << " threads, " << n << " items";
    EXPECT_LE(most.load(), expected);
    if (expected == 1) {
      EXPECT_EQ(ids, std::set<std::thread::id>{caller}) << "one worker: the calling thread";
    }
    if (expected > 1 && n >= 100) {
      EXPECT_GE(static_cast<int>(ids.size()), 2);
    }
  }
}

// A worker's number is its own: never in use by two threads at once, one thread per number, all in range.
TEST(ParallelForTest, WorkerNumbersBelongToOneThreadEach) {
  for (int threads : {1, 2, 4}) {
    const size_t n = 200;
    std::mutex m;
    std::vector<std::set<std::thread::id>> threads_of(static_cast<size_t>(threads));
    std::vector<std::atomic<int>> busy(static_cast<size_t>(threads));
    std::atomic<bool> overlapped{false};
    std::atomic<bool> out_of_range{false};
    ParallelForOnWorkers(n, threads, [&](size_t, size_t worker) {
      if (worker >= static_cast<size_t>(threads)) {
        out_of_range = true;
        return;
      }
      if (++busy[worker] != 1) overlapped = true;
      std::this_thread::sleep_for(std::chrono::microseconds(200));
      {
        std::lock_guard<std::mutex> lock(m);
        threads_of[worker].insert(std::this_thread::get_id());
      }
      --busy[worker];
    });
    EXPECT_FALSE(out_of_range);
    EXPECT_FALSE(overlapped) << threads << " threads";
    std::set<std::thread::id> all;
    for (const auto& ids : threads_of) {
      EXPECT_LE(ids.size(), 1u);
      for (const auto& id : ids) EXPECT_TRUE(all.insert(id).second) << "a thread under two numbers";
    }
  }
}

TEST(ParallelForTest, IndicesStartInIncreasingOrder) {
  std::mutex m;
  std::vector<size_t> order;
  ParallelFor(500, 3, [&](size_t i) {
    std::lock_guard<std::mutex> lock(m);
    order.push_back(i);
  });
  ASSERT_EQ(order.size(), 500u);
  // Claims are in order; a worker may record its claim after a later one of another worker, never much later.
  for (size_t k = 0; k < order.size(); ++k) EXPECT_LE(order[k], k + 3) << k;
}

TEST(ParallelForTest, SameResultsWhateverTheThreadCount) {
  auto run = [](int threads) {
    std::vector<double> out(257);
    ParallelFor(out.size(), threads, [&](size_t i) {
      double x = 0.0;
      for (int k = 1; k < 200 + static_cast<int>(i % 17) * 50; ++k) x += std::sin(static_cast<double>(i * k)) / k;
      out[i] = x;
    });
    return out;
  };
  const std::vector<double> one = run(1);
  EXPECT_EQ(run(2), one);
  EXPECT_EQ(run(5), one);
}

}  // namespace
}  // namespace uavm
