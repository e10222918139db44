// Bundle adjustment from perturbed poses, points and intrinsics recovers the synthetic truth.
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <random>

#include "core/sfm/bundle_adjuster.h"
#include "sfm_synthetic.h"

namespace uavm::sfm {
namespace {

TEST(SfmBundle, RecoversTruthFromPerturbedStart) {
  const double sigma = 0.3;
  const Reconstruction truth = testing::MakeScene(sigma, 7);
  Reconstruction rec = truth;
  std::mt19937 rng(3);
  std::normal_distribution<double> n01(0.0, 1.0);
  // Image 0 is the gauge (held fixed, so left at the truth); the farthest image keeps its largest centre coordinate.
  for (size_t i = 1; i < rec.images.size(); ++i) {
    auto& p = rec.images[i].pose;
    const Eigen::Vector3d w(n01(rng), n01(rng), n01(rng));
    p.R = Eigen::AngleAxisd(0.01, w.normalized()).toRotationMatrix() * p.R;  // ~0.6 deg
    const Eigen::Vector3d dc(0.5 * n01(rng), 0.5 * n01(rng), 0.5 * n01(rng));
    p.c += dc;
  }
  // Undo the perturbation of the gauge coordinate of the farthest image (x of image 11: 36 m east of image 0).
  rec.images[11].pose.c.x() = truth.images[11].pose.c.x();
  for (auto& p : rec.points) p.X += Eigen::Vector3d(0.3 * n01(rng), 0.3 * n01(rng), 0.5 * n01(rng));
  rec.camera.fx = rec.camera.fy = truth.camera.fx * 1.02;
  rec.camera.cx += 8.0;
  rec.camera.cy -= 6.0;
  rec.camera.k1 = 0.0;
  rec.camera.k2 = 0.0;
  rec.camera.p1 = rec.camera.p2 = 0.0;

  BundleOptions opts;
  opts.loss = BundleOptions::Loss::kHuber;
  opts.loss_scale_px = 1.0;
  opts.fixed_image = 0;
  opts.scale_image = 11;
  BundleSummary s;
  std::string err;
  ASSERT_TRUE(BundleAdjust(&rec, opts, &s, &err)) << err;
  EXPECT_GT(s.rms_before_px, 5.0);
  // After: the noise floor, sqrt(2) sigma * sqrt(1 - free parameters / measurements) (7 gauge dofs held).
  const double params = 6.0 * 12 - 7 + 3.0 * static_cast<double>(rec.points.size()) + 7;
  const double floor =
      std::sqrt(2.0) * sigma * std::sqrt(1.0 - params / (2.0 * static_cast<double>(rec.NumObservations())));
  EXPECT_LT(s.rms_after_px, 1.03 * floor);
  EXPECT_GT(s.rms_after_px, 0.97 * floor);
  EXPECT_NEAR(rec.camera.fx, truth.camera.fx, 0.004 * truth.camera.fx);
  EXPECT_NEAR(rec.camera.cx, truth.camera.cx, 1.5);
  EXPECT_NEAR(rec.camera.cy, truth.camera.cy, 1.5);
  EXPECT_NEAR(rec.camera.k1, truth.camera.k1, 0.004);
  EXPECT_NEAR(rec.camera.k2, truth.camera.k2, 0.006);
  EXPECT_NEAR(rec.camera.p1, truth.camera.p1, 2e-4);
  EXPECT_NEAR(rec.camera.p2, truth.camera.p2, 2e-4);
  for (size_t i = 0; i < rec.images.size(); ++i) {
    EXPECT_LT((rec.images[i].pose.c - truth.images[i].pose.c).norm(), 0.06) << i;
    const double dang = Eigen::AngleAxisd(rec.images[i].pose.R * truth.images[i].pose.R.transpose()).angle();
    EXPECT_LT(dang * 180.0 / M_PI, 0.06) << i;  // 0.3 px noise / 1400 px focal = 0.012 deg per observation
  }
  double sq = 0.0, worst = 0.0;
  for (size_t k = 0; k < rec.points.size(); ++k) {
    const double e = (rec.points[k].X - truth.points[k].X).norm();
    sq += e * e;
    worst = std::max(worst, e);
  }
  EXPECT_LT(std::sqrt(sq / static_cast<double>(rec.points.size())), 0.1);  // started at ~0.6 m
  EXPECT_LT(worst, 0.6);                                                   // two-view points at the border
}

TEST(SfmBundle, RobustLossIgnoresGrossOutliers) {
  Reconstruction rec = testing::MakeScene(0.2, 11);
  const Reconstruction truth = rec;
  // 3 % of the observations moved by 30 px.
  std::mt19937 rng(5);
  std::uniform_int_distribution<size_t> pick(0, rec.points.size() - 1);
  for (int k = 0; k < static_cast<int>(rec.NumObservations() * 3 / 100); ++k) {
    const auto& o = rec.points[pick(rng)].track[0];
    rec.images[static_cast<size_t>(o.image)].keypoints[static_cast<size_t>(o.feature)] += Eigen::Vector2d(30, -20);
  }
  for (size_t i = 1; i < rec.images.size(); ++i) rec.images[i].pose.c += Eigen::Vector3d(0.2, -0.3, 0.2);
  rec.images[11].pose.c.x() = truth.images[11].pose.c.x();
  BundleOptions opts;
  opts.loss = BundleOptions::Loss::kCauchy;
  opts.loss_scale_px = 2.0;
  opts.fixed_image = 0;
  opts.scale_image = 11;
  BundleSummary s;
  std::string err;
  ASSERT_TRUE(BundleAdjust(&rec, opts, &s, &err)) << err;
  for (size_t i = 0; i < rec.images.size(); ++i) {
    EXPECT_LT((rec.images[i].pose.c - truth.images[i].pose.c).norm(), 0.08) << i;
  }
  EXPECT_NEAR(rec.camera.fx, truth.camera.fx, 0.005 * truth.camera.fx);
}

TEST(SfmBundle, RejectsBadOptions) {
  BundleOptions o;
  o.loss_scale_px = 0.0;
  std::string why;
  EXPECT_FALSE(o.Check(&why));
  EXPECT_FALSE(why.empty());
}

}  // namespace
}  // namespace uavm::sfm
