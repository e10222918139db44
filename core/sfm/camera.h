#pragma once
#include <Eigen/Core>
#include <Eigen/LU>
#include <opencv2/core.hpp>
#include <optional>
#include <string>

namespace uavm::sfm {

// Pinhole camera with OpenCV's distortion (radial k1 k2 k3, tangential p1 p2), pixel-centre convention
// ((0,0) = centre of the top-left pixel). One model is shared by all frames of a flight.
struct Camera {
  int width = 0;
  int height = 0;
  double fx = 0.0, fy = 0.0, cx = 0.0, cy = 0.0;
  double k1 = 0.0, k2 = 0.0, p1 = 0.0, p2 = 0.0, k3 = 0.0;

  [[nodiscard]] cv::Matx33d K() const { return {fx, 0, cx, 0, fy, cy, 0, 0, 1}; }
  // OpenCV order k1 k2 p1 p2 k3.
  [[nodiscard]] cv::Vec<double, 5> Dist() const { return {k1, k2, p1, p2, k3}; }
  // Normalised undistorted camera coordinates (x/z, y/z) -> pixel.
  [[nodiscard]] Eigen::Vector2d Distort(const Eigen::Vector2d& xn) const;
  // Pixel -> normalised undistorted coordinates (iterative inverse of Distort).
  [[nodiscard]] Eigen::Vector2d Undistort(const Eigen::Vector2d& pixel) const;
};

// Pose: m = K [R | -R c] X. R is world-to-camera, c the centre in world coordinates.
struct Pose {
  Eigen::Matrix3d R = Eigen::Matrix3d::Identity();
  Eigen::Vector3d c = Eigen::Vector3d::Zero();
  [[nodiscard]] Eigen::Vector3d ToCamera(const Eigen::Vector3d& X) const { return R * (X - c); }
  [[nodiscard]] Eigen::Vector3d t() const { return -R * c; }
};

// Projects a world point; nullopt when it lies behind the camera.
[[nodiscard]] std::optional<Eigen::Vector2d> Project(const Camera& cam, const Pose& pose, const Eigen::Vector3d& X);

// Undistorts a whole image to the same K without distortion (cv::initUndistortRectifyMap + remap).
[[nodiscard]] cv::Mat UndistortImage(const Camera& cam, const cv::Mat& image);

// Sensor width and height in mm of a known camera model (EXIF "Model"), else nullopt.
struct SensorSize {
  double width_mm = 0.0;
  double height_mm = 0.0;
};
[[nodiscard]] std::optional<SensorSize> LookupSensor(const std::string& model);

// Initial intrinsics for a width x height image: focal from the EXIF focal length and the sensor width when both are
// known (the sensor's long side is matched to the image's long side: 16:9 frames crop the 4:3 sensor vertically),
// else from a default horizontal field of view. Principal point at the centre, no distortion.
struct IntrinsicsGuess {
  Camera camera;
  std::string source;  // "exif+sensor" or "default_fov"
};
[[nodiscard]] IntrinsicsGuess GuessIntrinsics(int width, int height, double focal_length_mm,
                                              const std::string& camera_model, double default_hfov_deg = 70.0);

}  // namespace uavm::sfm
