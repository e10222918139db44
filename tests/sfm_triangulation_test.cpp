// DLT triangulation: exact on exact data, at the noise floor with noise, and the rejection helpers.
#include <gtest/gtest.h>

#include <random>

#include "core/sfm/triangulation.h"
#include "sfm_synthetic.h"

namespace uavm::sfm {
namespace {

std::pair<std::vector<Pose>, std::vector<Eigen::Vector2d>> Views(const Reconstruction& rec, const Point3D& p) {
  std::vector<Pose> poses;
  std::vector<Eigen::Vector2d> xn;
  for (const auto& o : p.track) {
    poses.push_back(rec.images[static_cast<size_t>(o.image)].pose);
    xn.push_back(
        rec.cameras[0].Undistort(rec.images[static_cast<size_t>(o.image)].keypoints[static_cast<size_t>(o.feature)]));
  }
  return {poses, xn};
}

TEST(SfmTriangulation, ExactWithoutNoise) {
  const Reconstruction rec = testing::MakeScene(0.0, 1, 300);
  double worst = 0.0;
  for (const auto& p : rec.points) {
    const auto [poses, xn] = Views(rec, p);
    const auto X = TriangulateDlt(poses, xn);
    ASSERT_TRUE(X.has_value());
    worst = std::max(worst, (*X - p.X).norm());
  }
  EXPECT_LT(worst, 1e-6);
}

TEST(SfmTriangulation, ErrorAtTheNoiseFloor) {
  // 0.5 px noise: the DLT point's reprojection RMS must match the noise left after fitting 3 parameters to 2n
  // measurements, sigma * sqrt((2n - 3) / 2n), and its 3-D error must be of the order of what the geometry allows.
  const double sigma = 0.5;
  const Reconstruction rec = testing::MakeScene(sigma, 2, 2000);
  double sum_sq = 0.0, truth_sq = 0.0, expected_sq = 0.0, err3d_sq = 0.0;
  size_t nobs = 0;
  for (const auto& p : rec.points) {
    const auto [poses, xn] = Views(rec, p);
    const auto X = TriangulateDlt(poses, xn);
    ASSERT_TRUE(X.has_value());
    err3d_sq += (*X - p.X).squaredNorm();
    const double n = static_cast<double>(p.track.size());
    expected_sq += sigma * sigma * (2 * n - 3) / 2;  // per-point sum over its 2n residual components / 2 axes
    for (const auto& o : p.track) {
      const auto& im = rec.images[static_cast<size_t>(o.image)];
      sum_sq += (*Project(rec.cameras[0], im.pose, *X) - im.keypoints[static_cast<size_t>(o.feature)]).squaredNorm();
      truth_sq += (*Project(rec.cameras[0], im.pose, p.X) - im.keypoints[static_cast<size_t>(o.feature)]).squaredNorm();
      ++nobs;
    }
  }
  const double rms = std::sqrt(sum_sq / static_cast<double>(nobs));
  const double floor = std::sqrt(2.0 * expected_sq / static_cast<double>(nobs));
  EXPECT_NEAR(rms, floor, 0.08 * floor) << "rms " << rms << " floor " << floor << " truth "
                                        << std::sqrt(truth_sq / static_cast<double>(nobs)) << " obs/pt "
                                        << static_cast<double>(nobs) / static_cast<double>(rec.points.size());
  // Depth precision ~ sigma * Z^2 / (f * B): 60 m, f 1400, baselines >= 12 m -> ~0.1 m; lateral ~0.02 m.
  const double rms3d = std::sqrt(err3d_sq / static_cast<double>(rec.points.size()));
  EXPECT_LT(rms3d, 0.12);
  EXPECT_GT(rms3d, 0.005);  // the noise is really there
}

TEST(SfmTriangulation, AngleAndDegenerateCases) {
  std::vector<Pose> poses = {testing::NadirPose({0, 0, 50}, 0), testing::NadirPose({10, 0, 50}, 0)};
  const double a = MaxTriangulationAngleDeg(poses, Eigen::Vector3d(5, 0, 0));
  EXPECT_NEAR(a, 2.0 * std::atan(5.0 / 50.0) * 180.0 / M_PI, 1e-9);
  EXPECT_FALSE(TriangulateDlt({poses[0]}, {Eigen::Vector2d(0, 0)}).has_value());
}

}  // namespace
}  // namespace uavm::sfm
