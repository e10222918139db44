#pragma once
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "core/stereo/sgm.h"

namespace uavm::stereo {

// A pinhole camera with OpenCV distortion; projection m = K [R | -R c] X (c = camera centre in world coordinates).
struct StereoCamera {
  cv::Matx33d K = cv::Matx33d::eye();
  cv::Vec<double, 5> dist{0, 0, 0, 0, 0};  // OpenCV order k1 k2 p1 p2 k3
  cv::Matx33d R = cv::Matx33d::eye();      // camera_from_world rotation
  cv::Vec3d c{0, 0, 0};
  cv::Size size;
};

struct ColoredPoint {
  cv::Vec3f xyz;  // world coordinates
  cv::Vec3b bgr;
};

struct PairDepthOptions {
  // Depth range (along the optical axis of the first camera, world units) that sets the disparity search range.
  // max_disparity > 0 overrides the range from depths.
  double min_depth = 1.0;
  double max_depth = 1.0e4;
  int max_disparity = 0;
  int max_disparity_cap = 320;  // at matching resolution; a wider range loses its nearest depths
  // Matching resolution: images are scaled by this factor after rectification (0.5 = half size) for speed; it is
  // lowered further when the matcher's buffers would exceed sgm.max_memory_mib.
  double image_scale = 1.0;
  // Keep one point per step x step block of the left rectified image (1 = every pixel).
  int sample_step = 1;
  // Pixels whose disparity was filled (not measured) are never triangulated; this also drops points whose
  // triangulation angle is below this (degrees).
  double min_triangulation_angle_deg = 1.0;
  SgmOptions sgm;

  [[nodiscard]] bool Check(std::string* why = nullptr) const;
};

// The rectification of a pair. Both rectified cameras share the rotation world_to_rect (x axis = baseline c1 -> c2,
// z = mean viewing direction) and the intrinsics K (fx = fy): camera 1 is always the LEFT one, with positive
// disparity d = x1 - x2 = f * baseline / z_rect (a pair whose baseline points the other way in the images is simply
// rotated by 180 degrees, no swap is needed). Rectified image k = remap(image k, map_x[k], map_y[k]).
struct RectifiedPair {
  cv::Mat map_x[2], map_y[2];    // CV_32FC1, size `size`
  cv::Matx33d rect_from_cam[2];  // rotation from original camera k to the rectified frame (initUndistortRectifyMap R)
  cv::Matx33d rect_from_world;
  cv::Matx33d K;
  double baseline = 0.0;  // |c2 - c1|
  cv::Size size;
};

// Rectification of cam1/cam2 from their poses; the rectified frame covers both images' footprints (capped at
// 2x the larger input dimension).
[[nodiscard]] bool RectifyCameras(const StereoCamera& cam1, const StereoCamera& cam2, RectifiedPair* rectified,
                                  std::string* error = nullptr);

// Rectify from the relative pose, dense disparity (SGM + left-right check), triangulate -> world points with colours
// from img1/img2 (the left rectified image). Only measured (not hole-filled) disparities give points.
[[nodiscard]] bool DensePointsFromPair(const cv::Mat& img1, const StereoCamera& cam1, const cv::Mat& img2,
                                       const StereoCamera& cam2, const PairDepthOptions& opts,
                                       std::vector<ColoredPoint>* points, std::string* error);

}  // namespace uavm::stereo
