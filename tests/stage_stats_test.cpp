#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
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

// Residuals of a solve: most below a pixel, a tail of outliers to hundreds; the median of 10^6 of them (the end's
// solves read up to ~260 000 at a time) from 12 000 bins.
TEST(LogHistogramTest, MedianOfResidualsIsWithinHalfABinOfTheExactFigure) {
  std::mt19937 rng(11);
  std::gamma_distribution<double> inlier(2.0, 0.25);
  std::uniform_real_distribution<double> outlier(5.0, 400.0);
  LogHistogram h(1e-6, 12, 1000);
  std::vector<double> all;
  for (int i = 0; i < 1000000; ++i) {
    const double r = i % 10 == 0 ? outlier(rng) : inlier(rng);
    h.Add(r);
    all.push_back(r);
  }
  EXPECT_EQ(h.count(), all.size());
  EXPECT_EQ(h.max(), *std::max_element(all.begin(), all.end()));
  EXPECT_EQ(h.min(), *std::min_element(all.begin(), all.end()));
  const double half_bin = std::pow(10.0, 0.5 / 1000) - 1;  // 0.115 %
  const double median = ExactRank(all, (all.size() + 1) / 2);
  EXPECT_NEAR(h.Median(), median, half_bin * median);
  const double p90 = ExactRank(all, 900000);
  EXPECT_NEAR(h.AtRank(900000), p90, half_bin * p90);
}

TEST(LogHistogramTest, ValuesOutsideTheRangeAreReportedAsSeenAndNaNIsLeftOut) {
  LogHistogram h(1e-6, 12, 1000);
  EXPECT_EQ(h.Median(), 0.0) << "empty";
  h.Add(0.0);  // an exact fit: below the first decade
  EXPECT_EQ(h.Median(), 0.0);
  h.Add(std::nan(""));
  h.Add(std::numeric_limits<double>::infinity());
  EXPECT_EQ(h.count(), 1u);
  EXPECT_EQ(h.non_finite(), 2u);
  EXPECT_EQ(h.min(), 0.0);
  EXPECT_EQ(h.max(), 0.0) << "min and max of the finite values only";
  h.Add(3e9);  // beyond the last decade: reported as seen
  h.Add(3e9);
  EXPECT_EQ(h.Median(), 3e9);
  EXPECT_EQ(h.AtRank(0), 0.0) << "rank clamped to 1";
  EXPECT_EQ(h.AtRank(99), 3e9) << "rank clamped to the count";
  h.Add(-2.0);  // below the range too: the smallest seen
  EXPECT_EQ(h.AtRank(1), -2.0);
}

// Values at the ends of the range are in its bins, not in the bins beyond: within half a bin like the others.
TEST(LogHistogramTest, ValuesAtTheEndsOfTheRangeKeepTheirPrecision) {
  const double half_bin = std::pow(10.0, 0.5 / 1000) - 1;
  for (const double v : {1.0000001e-6, 0.9999e6}) {
    LogHistogram h(1e-6, 12, 1000);
    h.Add(v / 2);  // out of range below: the smallest
    h.Add(v);
    h.Add(v);
    h.Add(2 * v);  // the largest
    EXPECT_NEAR(h.AtRank(2), v, half_bin * v) << v;
    EXPECT_NE(h.AtRank(2), v / 2) << v;
  }
}

}  // namespace
}  // namespace uavm
