#include <gtest/gtest.h>

#include <opencv2/calib3d.hpp>
#include <random>

#include "core/estimators/homography.h"
#include "core/estimators/ransac.h"

namespace uavm {
namespace {

// A tilted view: a true projective map, not an affine one.
Mat3 TiltedTruth() {
  Mat3 h;
  h << 0.92, -0.28, 130.0, 0.30, 1.05, -70.0, 2.1e-4, -1.3e-4, 1.0;
  return h;
}

TEST(HomographyEstimatorTest, RecoversExactHomographyFromNoiseFreePoints) {
  const Mat3 truth = TiltedTruth();
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> coord(0, 1000);
  std::vector<Vec2> x;
  std::vector<Vec2> y;
  for (int i = 0; i < 50; ++i) {
    x.emplace_back(coord(rng), coord(rng));
    y.push_back(Apply(truth, x.back()));
  }
  Mat3 h;
  ASSERT_TRUE(HomographyEstimator::Fit(x, y, &h));
  for (const Vec2& c : ImageCorners(1001, 1001)) EXPECT_LT((Apply(h, c) - Apply(truth, c)).norm(), 1e-6);
  // The minimal sample fixes it too.
  const std::vector<Vec2> x4(x.begin(), x.begin() + 4);
  const std::vector<Vec2> y4(y.begin(), y.begin() + 4);
  ASSERT_TRUE(HomographyEstimator::Fit(x4, y4, &h));
  for (const Vec2& c : ImageCorners(1001, 1001)) EXPECT_LT((Apply(h, c) - Apply(truth, c)).norm(), 1e-6);
}

// With noise, ours and OpenCV's least-squares fit (an independent implementation) land within a small fraction of the
// noise of each other and of the truth.
TEST(HomographyEstimatorTest, AgreesWithOpenCvLeastSquaresUnderNoise) {
  const Mat3 truth = TiltedTruth();
  std::mt19937 rng(9);
  std::uniform_real_distribution<double> coord(0, 1000);
  std::normal_distribution<double> noise(0, 0.5);
  std::vector<Vec2> x;
  std::vector<Vec2> y;
  std::vector<cv::Point2d> cx;
  std::vector<cv::Point2d> cy;
  for (int i = 0; i < 400; ++i) {
    x.emplace_back(coord(rng), coord(rng));
    y.push_back(Apply(truth, x.back()) + Vec2(noise(rng), noise(rng)));
    cx.emplace_back(x.back().x(), x.back().y());
    cy.emplace_back(y.back().x(), y.back().y());
  }
  Mat3 h;
  ASSERT_TRUE(HomographyEstimator::Fit(x, y, &h));
  const cv::Mat reference = cv::findHomography(cx, cy, 0);
  ASSERT_FALSE(reference.empty());
  Mat3 r;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) r(i, j) = reference.at<double>(i, j);
  for (const Vec2& c : ImageCorners(1001, 1001)) {
    EXPECT_LT((Apply(h, c) - Apply(r, c)).norm(), 0.1);
    EXPECT_LT((Apply(h, c) - Apply(truth, c)).norm(), 0.5);  // corners: extrapolated; 0.30 on aarch64
  }
}

TEST(HomographyEstimatorTest, RefusesDegenerateSamples) {
  std::vector<Vec2> x;
  std::vector<Vec2> y;
  for (int i = 0; i < 20; ++i) {  // all on one line
    x.emplace_back(10.0 * i, 5.0 * i + 3);
    y.emplace_back(10.0 * i + 1, 5.0 * i + 7);
  }
  Mat3 h;
  EXPECT_FALSE(HomographyEstimator::Fit(x, y, &h));
  x.resize(3);
  y.resize(3);
  EXPECT_FALSE(HomographyEstimator::Fit(x, y, &h));
  EXPECT_FALSE(HomographyEstimator::Fit({}, {}, &h));
}

TEST(HomographyEstimatorTest, RansacFindsTheInliers) {
  const Mat3 truth = TiltedTruth();
  std::mt19937 rng(4);
  std::uniform_real_distribution<double> coord(0, 1000);
  std::normal_distribution<double> noise(0, 0.3);
  std::vector<Vec2> x;
  std::vector<Vec2> y;
  for (int i = 0; i < 300; ++i) {
    x.emplace_back(coord(rng), coord(rng));
    y.push_back(i % 3 == 0 ? Vec2(coord(rng), coord(rng)) : Apply(truth, x.back()) + Vec2(noise(rng), noise(rng)));
  }
  RansacOptions opt;
  opt.max_error = 1.5;
  const auto report = RANSAC<HomographyEstimator>(opt).Estimate(x, y);
  ASSERT_TRUE(report.success);
  EXPECT_GE(report.num_inliers, 195u);
  EXPECT_LE(report.num_inliers, 203u);
}

}  // namespace
}  // namespace uavm
