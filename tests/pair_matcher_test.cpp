#include "core/matching/pair_matcher.h"

#include <gtest/gtest.h>

#include <opencv2/calib3d.hpp>
#include <opencv2/core/persistence.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <random>

#include "tests/test_image.h"

namespace uavm {
namespace {

const std::string kGraf = std::string(UAVM_TEST_DATA) + "/opencv_samples/";

// OpenCV's graf pair with its exact homography: our RootSIFT + ratio-test matches must agree with it.
TEST(PairMatcherTest, GrafMatchesAgreeWithGroundTruthHomography) {
  const cv::Mat img1 = cv::imread(kGraf + "graf1.png", cv::IMREAD_GRAYSCALE);
  const cv::Mat img3 = cv::imread(kGraf + "graf3.png", cv::IMREAD_GRAYSCALE);
  ASSERT_FALSE(img1.empty());
  ASSERT_FALSE(img3.empty());
  cv::FileStorage fs(kGraf + "H1to3p.xml", cv::FileStorage::READ);
  cv::Mat H;
  fs["H13"] >> H;
  ASSERT_EQ(H.rows, 3);
  FeatureOptions fo;
  const SiftExtractor sift(fo);
  const Features f1 = sift.Extract(img1);
  const Features f3 = sift.Extract(img3);
  ASSERT_GT(f1.size(), 1000u);
  MatchOptions mo;
  const DescriptorIndex index3(f3, mo);
  const auto matches = index3.Match(f1.descriptors);
  ASSERT_GT(matches.size(), 200u);
  std::vector<cv::Point2f> p1;
  std::vector<cv::Point2f> p3;
  int consistent = 0;
  for (const auto& m : matches) {
    const cv::Point2f a = f1.points[static_cast<size_t>(m.queryIdx)];
    const cv::Point2f b = f3.points[static_cast<size_t>(m.trainIdx)];
    const cv::Mat x = H * (cv::Mat_<double>(3, 1) << a.x, a.y, 1.0);
    const double ex = x.at<double>(0) / x.at<double>(2) - b.x;
    const double ey = x.at<double>(1) / x.at<double>(2) - b.y;
    consistent += std::hypot(ex, ey) < 3.0 ? 1 : 0;
    p1.push_back(a);
    p3.push_back(b);
  }
  // graf 1->3 is a 40 degree viewpoint change: most ratio-test matches must still be right.
  EXPECT_GT(consistent, 0.6 * static_cast<double>(matches.size())) << consistent << "/" << matches.size();
  // RANSAC on our matches keeps almost only true matches, and they sit on the ground truth with sub-pixel error.
  cv::Mat inlier_mask;
  const cv::Mat Hest = cv::findHomography(p1, p3, cv::RANSAC, 2.0, inlier_mask);
  ASSERT_FALSE(Hest.empty());
  std::vector<double> errors;
  for (size_t i = 0; i < p1.size(); ++i) {
    if (inlier_mask.at<uchar>(static_cast<int>(i)) == 0) continue;
    const cv::Mat a = H * (cv::Mat_<double>(3, 1) << p1[i].x, p1[i].y, 1.0);
    errors.push_back(
        std::hypot(a.at<double>(0) / a.at<double>(2) - p3[i].x, a.at<double>(1) / a.at<double>(2) - p3[i].y));
  }
  std::sort(errors.begin(), errors.end());
  ASSERT_GT(errors.size(), 200u);
  EXPECT_LT(errors[errors.size() / 2], 1.0);
  // Two in three within 3 px. (Most of the rest sit in graf1's bottom-left corner, x < 30, y > 530, where the
  // homography fitted to these matches departs from H1to3p by 6-8 px while the matches agree with each other.)
  EXPECT_LT(errors[errors.size() * 2 / 3], 3.0);
}

// A real aerial frame against a known affine warp of itself: the verified pair recovers the warp.
TEST(PairMatcherTest, RecoversKnownAffineOnAerialFrame) {
  const cv::Mat img = test::ScaledForEmulation(
      cv::imread(std::string(UAVM_TEST_DATA) + "/caliterra_small/images/IMG_9360.jpg", cv::IMREAD_GRAYSCALE));
  ASSERT_FALSE(img.empty());
  const double scale = test::EmulationImageScale();  // half size under emulation, the shift with it
  Mat3 truth;
  truth << 0.9 * std::cos(0.5), -0.9 * std::sin(0.5), 250 * scale, 0.9 * std::sin(0.5), 0.9 * std::cos(0.5),
      -120 * scale, 0, 0, 1;
  cv::Mat warped;
  cv::warpAffine(img, warped, cv::Mat(ToCvAffine(truth)), img.size(), cv::INTER_LINEAR);
  const SiftExtractor sift{FeatureOptions{}};
  const Features src = sift.Extract(img);
  const Features tgt = sift.Extract(warped);
  MatchOptions mo;
  const DescriptorIndex index(tgt, mo);
  const PairResult r = MatchPair(index, tgt, src, mo);
  ASSERT_TRUE(r.ok) << r.failure;
  EXPECT_GT(r.num_inliers, 200);
  EXPECT_LE(r.src_points.size(), static_cast<size_t>(mo.max_edge_correspondences));
  EXPECT_GE(r.src_points.size(), 48u);  // cell means over (nearly) the whole 8 x 8 grid
  EXPECT_EQ(r.holdout_src_points.size(), static_cast<size_t>(mo.holdout_correspondences));
  // Every kept correspondence sits on the truth (the cells' means: well under a pixel), every held-out one within
  // RANSAC's threshold.
  ASSERT_EQ(r.src_points.size(), r.tgt_points.size());
  for (size_t i = 0; i < r.src_points.size(); ++i)
    EXPECT_LT((Apply(truth, r.src_points[i]) - r.tgt_points[i]).norm(), 0.5) << i;
  for (size_t i = 0; i < r.holdout_src_points.size(); ++i)
    EXPECT_LT((Apply(truth, r.holdout_src_points[i]) - r.holdout_tgt_points[i]).norm(), mo.ransac.max_error) << i;
  // One inlier per cell: the same held-out sample, max_edge_correspondences inliers kept.
  MatchOptions picks = mo;
  picks.average_cells = false;
  const PairResult p = MatchPair(index, tgt, src, picks);
  ASSERT_TRUE(p.ok);
  EXPECT_EQ(p.src_points.size(), static_cast<size_t>(mo.max_edge_correspondences));
  EXPECT_EQ(p.holdout_src_points, r.holdout_src_points);
  // A cap below the grid's 64 cells shrinks the grid: 10 allow 3 x 3 cells.
  MatchOptions ten = mo;
  ten.max_edge_correspondences = 10;
  const PairResult t = MatchPair(index, tgt, src, ten);
  ASSERT_TRUE(t.ok);
  EXPECT_LE(t.src_points.size(), 9u);
  EXPECT_GE(t.src_points.size(), 8u);
  for (const Vec2& c : ImageCorners(img.cols, img.rows))
    EXPECT_LT((Apply(r.tgt_from_src, c) - Apply(truth, c)).norm(), 1.0);
  // Guided by the truth, the same pair still verifies, from fewer queries.
  MatchGuide guide{truth, warped.size(), 0.1};
  const PairResult g = MatchPair(index, tgt, src, mo, &guide);
  ASSERT_TRUE(g.ok);
  for (const Vec2& c : ImageCorners(img.cols, img.rows))
    EXPECT_LT((Apply(g.tgt_from_src, c) - Apply(truth, c)).norm(), 1.0);
  // A tight query cap (a quarter of what the overlap offers) asks at most that many points, yet keeps a full edge
  // and the same warp; without a cap the guided query asks every predicted-inside point.
  MatchOptions all = mo;
  all.max_guided_queries = 0;
  const PairResult u = MatchPair(index, tgt, src, all, &guide);
  ASSERT_TRUE(u.ok);
  MatchOptions capped = mo;
  capped.max_guided_queries = std::max(mo.min_inliers, u.num_matches / 4);
  ASSERT_GT(u.num_matches, capped.max_guided_queries) << "the cap must bind for this test to mean anything";
  const PairResult c = MatchPair(index, tgt, src, capped, &guide);
  ASSERT_TRUE(c.ok) << c.failure;
  EXPECT_LE(c.num_matches, capped.max_guided_queries);
  // A full edge: a cell mean over (nearly) every cell of the overlap either way.
  EXPECT_GE(c.src_points.size(), 48u);
  EXPECT_NEAR(static_cast<double>(c.src_points.size()), static_cast<double>(u.src_points.size()), 3.0);
  for (const Vec2& corner : ImageCorners(img.cols, img.rows))
    EXPECT_LT((Apply(c.tgt_from_src, corner) - Apply(truth, corner)).norm(), 1.0);
}

TEST(PairMatcherTest, GridSubsampleSpreadsPoints) {
  std::vector<Vec2> src;
  std::vector<Vec2> tgt;
  for (int i = 0; i < 1000; ++i) {  // 90 % of the points crowd one corner
    const double x = i < 900 ? (i % 30) : 100.0 * (i % 10);
    const double y = i < 900 ? (i / 30) : 100.0 * ((i / 10) % 10);
    src.emplace_back(x, y);
    tgt.emplace_back(x + 1, y + 1);
  }
  GridSubsample(&src, &tgt, 8, 64);
  ASSERT_EQ(src.size(), 64u);
  int far = 0;
  for (size_t i = 0; i < src.size(); ++i) {
    far += (src[i].x() > 200 || src[i].y() > 200) ? 1 : 0;
    EXPECT_EQ(tgt[i], src[i] + Vec2(1, 1));
  }
  EXPECT_GT(far, 30);  // the sparse part is represented, not drowned by the crowd
}

// Cell means referred to an affine approximation of a tilted view: each comes within a small fraction of the
// keypoints' noise of the true map at the cell's centroid (the noise averaged, the map's curvature across a cell
// negligible), where one inlier per cell carries the full noise; a lone point comes out unchanged.
TEST(PairMatcherTest, CellMeansAverageTheNoiseAndFollowTheTrueMap) {
  Mat3 truth;
  truth << 0.95, -0.2, 40.0, 0.18, 1.01, -25.0, 1.5e-4, -1.0e-4, 1.0;
  std::mt19937 rng(21);
  std::uniform_real_distribution<double> coord(0, 640);
  std::normal_distribution<double> noise(0, 0.5);
  std::vector<Vec2> src;
  std::vector<Vec2> tgt;
  for (int i = 0; i < 1280; ++i) {
    src.emplace_back(coord(rng), coord(rng) * 0.75);
    tgt.push_back(Apply(truth, src.back()) + Vec2(noise(rng), noise(rng)));
  }
  Mat3 affine;  // what RANSAC's affine would be: the truth's tangent map at the frame's centre
  const Vec2 c(320, 240);
  const double eps = 1e-3;
  const Vec2 dx = (Apply(truth, c + Vec2(eps, 0)) - Apply(truth, c - Vec2(eps, 0))) / (2 * eps);
  const Vec2 dy = (Apply(truth, c + Vec2(0, eps)) - Apply(truth, c - Vec2(0, eps))) / (2 * eps);
  const Vec2 t = Apply(truth, c) - dx * c.x() - dy * c.y();
  affine << dx.x(), dy.x(), t.x(), dx.y(), dy.y(), t.y(), 0, 0, 1;
  std::vector<Vec2> cell_src;
  std::vector<Vec2> cell_tgt;
  CellMeanCorrespondences(src, tgt, affine, 8, &cell_src, &cell_tgt);
  ASSERT_EQ(cell_src.size(), 64u);
  ASSERT_EQ(cell_tgt.size(), 64u);
  double sq = 0.0;
  for (size_t i = 0; i < cell_src.size(); ++i) sq += (cell_tgt[i] - Apply(truth, cell_src[i])).squaredNorm();
  const double rms = std::sqrt(sq / 64.0);
  EXPECT_LT(rms, 0.2) << "one inlier per cell: ~0.71 px";
  // Grid subsampling keeps single noisy inliers: about the noise's RMS (0.5 px per axis).
  std::vector<Vec2> gs = src;
  std::vector<Vec2> gt = tgt;
  GridSubsample(&gs, &gt, 8, 64);
  sq = 0.0;
  for (size_t i = 0; i < gs.size(); ++i) sq += (gt[i] - Apply(truth, gs[i])).squaredNorm();
  EXPECT_GT(std::sqrt(sq / static_cast<double>(gs.size())), 2 * rms);
  // A lone point is its own mean.
  cell_src.clear();
  cell_tgt.clear();
  CellMeanCorrespondences({src[0]}, {tgt[0]}, affine, 8, &cell_src, &cell_tgt);
  ASSERT_EQ(cell_src.size(), 1u);
  EXPECT_LT((cell_src[0] - src[0]).norm(), 1e-12);
  EXPECT_LT((cell_tgt[0] - tgt[0]).norm(), 1e-9);
}

// Inliers along a narrow band: their cell means still sit on the truth (the reference exact, the noise 0.2 px).
TEST(PairMatcherTest, CellMeansOfABandSitOnTheTruth) {
  Mat3 truth;
  truth << 0.98, -0.1, 35.0, 0.1, 0.98, -12.0, 0, 0, 1;
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> along(0, 600);
  std::uniform_real_distribution<double> across(200, 203);
  std::normal_distribution<double> noise(0, 0.2);
  std::vector<Vec2> src;
  std::vector<Vec2> tgt;
  for (int i = 0; i < 40; ++i) {
    src.emplace_back(along(rng), across(rng));
    tgt.push_back(Apply(truth, src.back()) + Vec2(noise(rng), noise(rng)));
  }
  MatchOptions mo;
  std::vector<Vec2> cell_src;
  std::vector<Vec2> cell_tgt;
  CellMeanCorrespondences(src, tgt, truth, mo.correspondence_grid, &cell_src, &cell_tgt);
  ASSERT_GE(cell_src.size(), 1u);
  for (size_t i = 0; i < cell_src.size(); ++i) EXPECT_LT((Apply(truth, cell_src[i]) - cell_tgt[i]).norm(), 1.0);
  // Mismatched inputs give nothing rather than reading past the end.
  cell_src.clear();
  cell_tgt.clear();
  CellMeanCorrespondences(src, {tgt[0]}, truth, 8, &cell_src, &cell_tgt);
  EXPECT_TRUE(cell_src.empty());
}

}  // namespace
}  // namespace uavm
