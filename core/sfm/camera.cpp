#include "core/sfm/camera.h"

#include <algorithm>
#include <array>
#include <cctype>
#include <cmath>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>

namespace uavm::sfm {

Eigen::Vector2d Camera::Distort(const Eigen::Vector2d& xn) const {
  const double x = xn.x(), y = xn.y();
  const double r2 = x * x + y * y;
  const double radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
  const double xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x);
  const double yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y;
  return {fx * xd + cx, fy * yd + cy};
}

Eigen::Vector2d Camera::Undistort(const Eigen::Vector2d& pixel) const {
  const Eigen::Vector2d xd((pixel.x() - cx) / fx, (pixel.y() - cy) / fy);
  Eigen::Vector2d x = xd;
  // Gauss-Newton on Distort(x) = pixel with a numeric Jacobian: converges in a few steps for realistic lenses and
  // stays accurate at the corners of wide lenses where the fixed-point iteration of cv::undistortPoints drifts.
  for (int it = 0; it < 20; ++it) {
    const Eigen::Vector2d f = Distort(x) - pixel;
    if (f.norm() < 1e-10) break;
    constexpr double h = 1e-7;
    Eigen::Matrix2d J;
    J.col(0) = (Distort(x + Eigen::Vector2d(h, 0)) - Distort(x)) / h;
    J.col(1) = (Distort(x + Eigen::Vector2d(0, h)) - Distort(x)) / h;
    x -= J.lu().solve(f);
  }
  return x;
}

std::optional<Eigen::Vector2d> Project(const Camera& cam, const Pose& pose, const Eigen::Vector3d& X) {
  const Eigen::Vector3d p = pose.ToCamera(X);
  if (p.z() <= 1e-12) return std::nullopt;
  return cam.Distort(Eigen::Vector2d(p.x() / p.z(), p.y() / p.z()));
}

cv::Mat UndistortImage(const Camera& cam, const cv::Mat& image) {
  cv::Mat map1, map2, out;
  const cv::Mat K(cam.K()), D(cam.Dist());
  cv::initUndistortRectifyMap(K, D, cv::noArray(), K, image.size(), CV_32FC1, map1, map2);
  cv::remap(image, out, map1, map2, cv::INTER_LINEAR, cv::BORDER_CONSTANT);
  return out;
}

std::optional<SensorSize> LookupSensor(const std::string& model) {
  std::string m;
  for (char ch : model) m += static_cast<char>(std::toupper(static_cast<unsigned char>(ch)));
  // Small table of common drone cameras (EXIF Model -> sensor mm).
  static const std::array<std::pair<const char*, SensorSize>, 10> kTable = {{
      {"FC300S", {6.17, 4.55}},  // DJI Phantom 3 Advanced/Professional
      {"FC300X", {6.17, 4.55}},  // DJI Phantom 3 Professional 4K
      {"FC330", {6.17, 4.55}},   // DJI Phantom 4
      {"FC6310", {13.2, 8.8}},   // DJI Phantom 4 Pro
      {"FC6310S", {13.2, 8.8}},  // DJI Phantom 4 Pro V2
      {"FC220", {6.17, 4.55}},   // DJI Mavic Pro
      {"L1D-20C", {13.2, 8.8}},  // DJI Mavic 2 Pro (Hasselblad)
      {"FC7303", {6.3, 4.7}},    // DJI Mini 2
      {"FC3170", {6.3, 4.7}},    // DJI Mavic Air 2
      {"FC6520", {17.3, 13.0}},  // DJI Zenmuse X5S
  }};
  for (const auto& [name, size] : kTable) {
    if (m == name) return size;
  }
  return std::nullopt;
}

IntrinsicsGuess GuessIntrinsics(int width, int height, double focal_length_mm, const std::string& camera_model,
                                double default_hfov_deg) {
  IntrinsicsGuess g;
  Camera& c = g.camera;
  c.width = width;
  c.height = height;
  c.cx = 0.5 * width - 0.5;
  c.cy = 0.5 * height - 0.5;
  const auto sensor = LookupSensor(camera_model);
  // Without a known model, DJI-like 1/2.3" sensors (6.17 mm) are the common case for small focal lengths.
  const double sensor_w = sensor ? sensor->width_mm : (focal_length_mm > 0.0 && focal_length_mm < 6.0 ? 6.17 : 0.0);
  if (focal_length_mm > 0.0 && sensor_w > 0.0) {
    c.fx = c.fy = focal_length_mm / sensor_w * std::max(width, height);
    g.source = sensor ? "exif+sensor" : "exif+assumed_1/2.3in";
  } else {
    c.fx = c.fy = 0.5 * std::max(width, height) / std::tan(0.5 * default_hfov_deg * CV_PI / 180.0);
    g.source = "default_fov";
  }
  return g;
}

}  // namespace uavm::sfm
