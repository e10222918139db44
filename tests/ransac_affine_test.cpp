#include <gtest/gtest.h>

#include <random>

#include "core/estimators/affine.h"
#include "core/estimators/ransac.h"

namespace uavm {
namespace {

TEST(RansacAffineTest, RecoversKnownAffineWith40PercentOutliers) {
  Mat3 truth;
  truth << 0.93, -0.31, 140.0, 0.28, 1.02, -65.0, 0, 0, 1;
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> coord(0, 1200);
  std::normal_distribution<double> noise(0, 0.5);
  std::vector<Vec2> x;
  std::vector<Vec2> y;
  std::vector<bool> is_outlier;
  for (int i = 0; i < 500; ++i) {
    const Vec2 p(coord(rng), coord(rng));
    const bool outlier = i % 5 < 2;  // 40 %
    x.push_back(p);
    y.push_back(outlier ? Vec2(coord(rng), coord(rng)) : Apply(truth, p) + Vec2(noise(rng), noise(rng)));
    is_outlier.push_back(outlier);
  }
  RansacOptions opt;
  opt.max_error = 2.0;
  const auto report = RANSAC<AffineEstimator>(opt).Estimate(x, y);
  ASSERT_TRUE(report.success);
  // Every true inlier within 3 sigma is found; almost no outlier sneaks in.
  int inliers_found = 0;
  int outliers_accepted = 0;
  for (size_t i = 0; i < x.size(); ++i) {
    if (is_outlier[i])
      outliers_accepted += report.inlier_mask[i];
    else
      inliers_found += report.inlier_mask[i];
  }
  EXPECT_GE(inliers_found, 295);
  EXPECT_LE(outliers_accepted, 3);
  // The model maps the corners of a 1200 px frame within 0.2 px of the truth.
  for (const Vec2& c : ImageCorners(1201, 1201)) EXPECT_LT((Apply(report.model, c) - Apply(truth, c)).norm(), 0.2);
}

TEST(RansacAffineTest, FailsOnPureNoise) {
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> coord(0, 1000);
  std::vector<Vec2> x;
  std::vector<Vec2> y;
  for (int i = 0; i < 200; ++i) {
    x.emplace_back(coord(rng), coord(rng));
    y.emplace_back(coord(rng), coord(rng));
  }
  RansacOptions opt;
  opt.max_error = 1.0;
  const auto report = RANSAC<AffineEstimator>(opt).Estimate(x, y);
  EXPECT_LT(report.num_inliers, 15u);
}

TEST(RansacAffineTest, CollinearSampleIsRejected) {
  std::vector<Vec2> x{Vec2(0, 0), Vec2(1, 1), Vec2(2, 2)};
  std::vector<Vec2> y{Vec2(0, 0), Vec2(1, 1), Vec2(2, 2)};
  Mat3 m;
  EXPECT_FALSE(AffineEstimator::Fit(x, y, &m));
}

// Two structures, as a tilted pair can show: 160 correspondences follow a sheared, shrunk affine (implausible), 130
// the true one. Unconstrained RANSAC returns the larger, implausible set; with the validity check it must return the
// true model, found among the minimal samples, not the best model thrown away afterwards.
TEST(RansacAffineTest, OnlyValidModelsCompete) {
  Mat3 truth;
  truth << 0.85, -0.12, 60.0, 0.10, 0.86, -20.0, 0, 0, 1;
  Mat3 sheared;
  sheared << 0.55, 0.25, 210.0, -0.05, 0.80, 90.0, 0, 0, 1;
  const auto anisotropic = [](const Mat3& m) { return Decompose(m).anisotropy > 0.25; };
  ASSERT_FALSE(anisotropic(truth));
  ASSERT_TRUE(anisotropic(sheared));
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> coord(0, 1000);
  std::normal_distribution<double> noise(0, 0.4);
  std::vector<Vec2> x;
  std::vector<Vec2> y;
  for (int i = 0; i < 400; ++i) {
    const Vec2 p(coord(rng), coord(rng));
    x.push_back(p);
    if (i < 160)
      y.push_back(Apply(sheared, p) + Vec2(noise(rng), noise(rng)));
    else if (i < 290)
      y.push_back(Apply(truth, p) + Vec2(noise(rng), noise(rng)));
    else
      y.emplace_back(coord(rng), coord(rng));
  }
  RansacOptions opt;
  opt.max_error = 2.0;
  const auto unconstrained = RANSAC<AffineEstimator>(opt).Estimate(x, y);
  ASSERT_TRUE(unconstrained.success);
  EXPECT_TRUE(anisotropic(unconstrained.model));  // the larger structure wins without the check
  const auto valid = RANSAC<AffineEstimator>(opt).Estimate(x, y, [&](const Mat3& m) { return !anisotropic(m); });
  ASSERT_TRUE(valid.success);
  EXPECT_GE(valid.num_inliers, 125u);
  EXPECT_LE(valid.num_inliers, 140u);
  for (const Vec2& c : ImageCorners(1001, 1001)) EXPECT_LT((Apply(valid.model, c) - Apply(truth, c)).norm(), 0.3);
  // Nothing valid at all: no success rather than an invalid model.
  const auto none = RANSAC<AffineEstimator>(opt).Estimate(x, y, [](const Mat3&) { return false; });
  EXPECT_FALSE(none.success);
}

}  // namespace
}  // namespace uavm
