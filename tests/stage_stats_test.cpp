#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <vector>

#include "core/util/stats.h"

namespace uavm {
namespace {

// The exact nearest-rank value (1-based rank) of the samples.
double ExactRank(std::vector<double> v, size_t rank) {
  std::nth_element(v.begin(), v.begin() + static_cast<long>(rank - 1), v.end());
  return v[rank - 1];
}

TEST(StageStatsTest, MedianAndP95AreWithinTheBinWidthOfTheExactFigures) {
  std::mt19937 rng(7);
  std::lognormal_distribution<double> ms(std::log(40.0), 0.8);  // frame times: tens of ms, a long tail
  StageStats stats;
  std::vector<double> all;
  double total = 0;
  for (int i = 0; i < 20001; ++i) {
    const double x = ms(rng);
    stats.Add("features", x);
    all.push_back(x);
    total += x;
  }
  const Summary s = stats.Get("features");
  EXPECT_EQ(s.count, all.size());
  EXPECT_NEAR(s.total, total, 1e-6 * total);
  EXPECT_EQ(s.max, *std::max_element(all.begin(), all.end()));
  const double median = ExactRank(all, (all.size() + 1) / 2);
  const double p95 = ExactRank(all, static_cast<size_t>(std::ceil(0.95 * static_cast<double>(all.size()))));
  EXPECT_NEAR(s.median, median, 0.006 * median);
  EXPECT_NEAR(s.p95, p95, 0.006 * p95);
}

TEST(StageStatsTest, OneSampleAndValuesOutsideTheBinsAreReportedAsSeen) {
  StageStats stats;
  stats.Add("decode", 12.5);
  EXPECT_DOUBLE_EQ(stats.Get("decode").median, 12.5);  // clamped to the only value seen
  stats.Add("tiny", 0.0);
  stats.Add("tiny", 0.0);
  EXPECT_DOUBLE_EQ(stats.Get("tiny").median, 0.0);
  stats.Add("huge", 5e8);
  EXPECT_DOUBLE_EQ(stats.Get("huge").p95, 5e8);
  EXPECT_EQ(stats.Get("missing").count, 0u);
  const std::vector<std::string> order{"decode", "tiny", "huge"};
  EXPECT_EQ(stats.Stages(), order);
}

}  // namespace
}  // namespace uavm
