#pragma once
#include <Eigen/Core>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "core/geometry/similarity.h"
#include "core/sfm/camera.h"
#include "core/sfm/tracks.h"

namespace uavm::sfm {

// The aerial-triangulation data model: one shared camera, per image its pose and keypoints, per 3-D point its
// observations (image = index into `images`, feature = index into that image's keypoints).
struct Image {
  int frame_index = -1;  // session frame index
  std::string name;      // file name (COLMAP NAME)
  Pose pose;
  bool posed = true;
  std::vector<Eigen::Vector2d> keypoints;  // original-resolution pixels, pixel-centre convention
};

struct Point3D {
  Eigen::Vector3d X = Eigen::Vector3d::Zero();
  cv::Vec3b bgr{128, 128, 128};
  Track track;
  double error_px = 0.0;  // mean reprojection error, filled by the adjuster / triangulation
};

struct Reconstruction {
  Camera camera;
  std::vector<Image> images;
  std::vector<Point3D> points;

  [[nodiscard]] size_t NumObservations() const;
  // RMS and mean reprojection error over all observations of all points (pixels).
  [[nodiscard]] double ReprojectionRms() const;
  // Ground sampling distance at the median depth of all observations (world units per pixel); 0 without points.
  [[nodiscard]] double MedianGsd() const;
  // Moves the whole model by a similarity (x -> s R x + t): camera centres, orientations and points.
  void Transform(const Similarity3& s);
};

}  // namespace uavm::sfm
