#pragma once
#include <Eigen/Core>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "core/geometry/similarity.h"
#include "core/sfm/camera.h"
#include "core/sfm/tracks.h"

namespace uavm::sfm {

// The aerial-triangulation data model: the cameras (one model per camera and image size, shared by its images), per
// image its camera, pose and keypoints, per 3-D point its observations (image = index into `images`, feature = index
// into that image's keypoints).
struct Image {
  int frame_index = -1;  // session frame index
  std::string name;      // file name (COLMAP NAME)
  int camera = 0;        // index into Reconstruction::cameras
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
  std::vector<Camera> cameras;
  std::vector<Image> images;
  std::vector<Point3D> points;

  [[nodiscard]] const Camera& CameraOf(const Image& image) const { return cameras[static_cast<size_t>(image.camera)]; }
  [[nodiscard]] const Camera& CameraOf(int image) const { return CameraOf(images[static_cast<size_t>(image)]); }

  [[nodiscard]] size_t NumObservations() const;
  // RMS and mean reprojection error over all observations of all points (pixels).
  [[nodiscard]] double ReprojectionRms() const;
  // Per image: RMS reprojection error (pixels) and number of observations.
  struct ImageResidual {
    double rms_px = 0.0;
    size_t observations = 0;
  };
  [[nodiscard]] std::vector<ImageResidual> ResidualsPerImage() const;
  // Ground sampling distance at the median depth of all observations (world units per pixel); 0 without points.
  [[nodiscard]] double MedianGsd() const;
  // Moves the whole model by a similarity (x -> s R x + t): camera centres, orientations and points.
  void Transform(const Similarity3& s);
};

}  // namespace uavm::sfm
