#include "core/util/bounded_queue.h"

#include <gtest/gtest.h>

#include <thread>

namespace uavm {
namespace {

TEST(BoundedQueueTest, DropOldestCountsWhatItDrops) {
  BoundedQueue<int> q(3, BoundedQueue<int>::Policy::kDropOldest);
  for (int i = 0; i < 10; ++i) EXPECT_TRUE(q.Push(i));
  EXPECT_EQ(q.dropped(), 7u);
  q.Close();
  std::vector<int> got;
  while (auto v = q.Pop()) got.push_back(*v);
  EXPECT_EQ(got, (std::vector<int>{7, 8, 9}));  // the newest survive
}

TEST(BoundedQueueTest, BlockPolicyLosesNothing) {
  BoundedQueue<int> q(2, BoundedQueue<int>::Policy::kBlock);
  std::thread producer([&] {
    for (int i = 0; i < 1000; ++i) q.Push(i);
    q.Close();
  });
  long sum = 0;
  int count = 0;
  while (auto v = q.Pop()) {
    sum += *v;
    ++count;
  }
  producer.join();
  EXPECT_EQ(count, 1000);
  EXPECT_EQ(sum, 999L * 1000 / 2);
  EXPECT_EQ(q.dropped(), 0u);
  EXPECT_LE(q.high_water(), 2u);
}

}  // namespace
}  // namespace uavm
