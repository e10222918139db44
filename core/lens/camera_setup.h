#pragma once
// Which lens model a flight's frames are undistorted with, and the undistortion itself (points, working images,
// parts of stored frames).
#include <opencv2/core.hpp>
#include <string>

#include "core/frame/frame.h"
#include "core/geometry/camera_model.h"

namespace uavm {

// The `camera` block of the configuration.
struct CameraOptions {
  // A lens known from a calibration (OpenCV's convention, normalised by focal_px): used whenever a term is non-zero.
  double k1 = 0.0, k2 = 0.0, p1 = 0.0, p2 = 0.0;
  // Focal length in original pixels; 0 = from EXIF (35 mm equivalent, or focal length times the database's crop
  // factor), else that of a typical drone camera (84 degrees across the diagonal).
  double focal_px = 0.0;
  bool database = true;  // look the camera EXIF names up in lensfun's database when no lens is configured

  [[nodiscard]] bool Configured() const { return k1 != 0.0 || k2 != 0.0 || p1 != 0.0 || p2 != 0.0; }
  [[nodiscard]] bool Check(std::string* why) const;
};

struct CameraChoice {
  PinholeCamera camera;    // original pixels; principal point at the centre
  std::string source;      // "configuration", "database" or "none"
  std::string detail;      // the database's camera and lens, or why none was found
  std::string focal_from;  // "configuration", "exif_35mm", "exif_crop_factor" or "default"
};

// The flight's lens, from the first frame's size and EXIF.
[[nodiscard]] CameraChoice ChooseCamera(const CameraOptions& options, const FrameMetadata& metadata, cv::Size original);

// Undistortion with one camera on one pixel grid (e.g. the working copy's), its remap tables built once.
class Undistorter {
 public:
  Undistorter() = default;
  explicit Undistorter(const PinholeCamera& camera);
  [[nodiscard]] bool active() const { return active_; }
  [[nodiscard]] const PinholeCamera& camera() const { return camera_; }
  // Recorded pixel positions -> ideal ones, in place.
  void UndistortPoints(std::vector<cv::Point2f>* points) const;
  // The ideal image on the same grid (edge pixels repeated where a pincushion lens would leave none).
  [[nodiscard]] cv::Mat UndistortImage(const cv::Mat& recorded) const;

 private:
  bool active_ = false;
  PinholeCamera camera_;
  cv::Mat map1_, map2_;  // cv::convertMaps' fixed-point tables for the whole grid
};

// The recorded pixels a rectangle of ideal pixels needs (its border mapped through the lens, a 2-pixel margin),
// clipped to the image: what to decode for an ideal part.
[[nodiscard]] cv::Rect RecordedRectFor(const PinholeCamera& camera, const cv::Rect& ideal);

// The ideal part `ideal` (pixels of camera's grid) made from a decoded recorded part whose pixel (0,0) is at
// `recorded_origin` of the same grid.
[[nodiscard]] cv::Mat UndistortPart(const PinholeCamera& camera, const cv::Mat& recorded,
                                    const cv::Point2d& recorded_origin, const cv::Rect& ideal);

}  // namespace uavm
