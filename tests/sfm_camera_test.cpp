// Camera model: projection against OpenCV's projectPoints, distortion round trip, image undistortion, intrinsics
// from EXIF.
#include <gtest/gtest.h>

#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>

#include "core/sfm/camera.h"
#include "sfm_synthetic.h"

namespace uavm::sfm {
namespace {

TEST(SfmCamera, ProjectionMatchesOpenCv) {
  const Camera cam = testing::TestCamera();
  const Pose pose = testing::NadirPose(Eigen::Vector3d(3, -2, 50), 0.4, 0.05, -0.03);
  std::vector<cv::Point3d> X;
  for (int i = -4; i <= 4; ++i)
    for (int j = -3; j <= 3; ++j) X.emplace_back(6.0 * i + 3, 6.0 * j - 2, 0.3 * i);
  cv::Mat R(3, 3, CV_64F);
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) R.at<double>(r, c) = pose.R(r, c);
  cv::Mat rvec;
  cv::Rodrigues(R, rvec);
  const Eigen::Vector3d t = pose.t();
  const cv::Mat tvec = (cv::Mat_<double>(3, 1) << t.x(), t.y(), t.z());
  std::vector<cv::Point2d> ref;
  cv::projectPoints(X, rvec, tvec, cv::Mat(cam.K()), cv::Mat(cam.Dist()), ref);
  for (size_t i = 0; i < X.size(); ++i) {
    const auto m = Project(cam, pose, Eigen::Vector3d(X[i].x, X[i].y, X[i].z));
    ASSERT_TRUE(m.has_value());
    EXPECT_NEAR(m->x(), ref[i].x, 1e-6);
    EXPECT_NEAR(m->y(), ref[i].y, 1e-6);
  }
}

TEST(SfmCamera, DistortUndistortRoundTrip) {
  Camera cam = testing::TestCamera();
  cam.k3 = 0.01;
  double worst = 0.0;
  for (int y = 0; y < cam.height; y += 37) {
    for (int x = 0; x < cam.width; x += 41) {
      const Eigen::Vector2d px(x, y);
      const Eigen::Vector2d back = cam.Distort(cam.Undistort(px));
      worst = std::max(worst, (back - px).norm());
    }
  }
  EXPECT_LT(worst, 1e-6);
  // Against OpenCV's undistortPoints (iterative) at a mid-field point, where it is accurate.
  std::vector<cv::Point2d> in{{1000.0, 800.0}}, out;
  cv::undistortPoints(in, out, cv::Mat(cam.K()), cv::Mat(cam.Dist()), cv::noArray(), cv::noArray(),
                      cv::TermCriteria(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 100, 1e-12));
  const Eigen::Vector2d ours = cam.Undistort(Eigen::Vector2d(1000.0, 800.0));
  EXPECT_NEAR(ours.x(), out[0].x, 1e-7);
  EXPECT_NEAR(ours.y(), out[0].y, 1e-7);
}

TEST(SfmCamera, UndistortImageMovesDotsToPinholePositions) {
  const Camera cam = testing::TestCamera();
  cv::Mat img(cam.height, cam.width, CV_8UC1, cv::Scalar(0));
  // Dots at the distorted positions of normalised points; after undistortion they must sit at K * x.
  const std::vector<Eigen::Vector2d> xn = {{-0.45, -0.3}, {0.5, 0.35}, {0.1, -0.38}, {-0.5, 0.4}};
  for (const auto& p : xn) {
    const Eigen::Vector2d d = cam.Distort(p);
    cv::circle(img, cv::Point(static_cast<int>(std::lround(d.x() * 16)), static_cast<int>(std::lround(d.y() * 16))),
               6 * 16, cv::Scalar(255), cv::FILLED, cv::LINE_AA, 4);
  }
  const cv::Mat und = UndistortImage(cam, img);
  for (const auto& p : xn) {
    const double ex = cam.fx * p.x() + cam.cx, ey = cam.fy * p.y() + cam.cy;
    const cv::Rect roi(static_cast<int>(ex) - 15, static_cast<int>(ey) - 15, 31, 31);
    const cv::Moments m = cv::moments(und(roi));
    ASSERT_GT(m.m00, 0.0);
    EXPECT_NEAR(roi.x + m.m10 / m.m00, ex, 0.3);
    EXPECT_NEAR(roi.y + m.m01 / m.m00, ey, 0.3);
  }
}

TEST(SfmCamera, IntrinsicsFromExif) {
  // DJI Phantom 3 (FC300S): 3.61 mm on a 6.17 mm wide sensor, 16:9 frames crop the sensor height.
  const auto g = GuessIntrinsics(4000, 2250, 3.61, "FC300S");
  EXPECT_EQ(g.source, "exif+sensor");
  EXPECT_NEAR(g.camera.fx, 3.61 / 6.17 * 4000.0, 1e-9);
  EXPECT_NEAR(g.camera.cx, 1999.5, 1e-12);
  EXPECT_NEAR(g.camera.cy, 1124.5, 1e-12);
  const auto d = GuessIntrinsics(1000, 750, 0.0, "unknown", 90.0);
  EXPECT_EQ(d.source, "default_fov");
  EXPECT_NEAR(d.camera.fx, 500.0, 1e-9);
}

}  // namespace
}  // namespace uavm::sfm
