#pragma once
#include <optional>
#include <string>
#include <vector>

#include "core/sfm/reconstruction.h"

namespace uavm::sfm {

struct BundleOptions {
  enum class Loss { kTrivial, kHuber, kCauchy };
  Loss loss = Loss::kHuber;
  double loss_scale_px = 1.0;
  bool refine_focal = true;
  bool refine_principal_point = true;
  bool refine_radial = true;  // k1 k2 (k3 with refine_k3)
  bool refine_k3 = false;
  bool refine_tangential = true;  // p1 p2
  // A camera model seen by fewer images (e.g. the one odd-sized shot of a flight) keeps its principal point and lens
  // terms as they start and refines its focal length only (under its prior): one image's observations cannot tell
  // them from its pose, and freed they fit the noise (a single 900x505 frame's k1 went to 8).
  int min_images_for_lens = 5;
  // Weak prior that keeps the focal length near its start value (sigma as a fraction of f): a nadir flight over flat
  // ground cannot separate focal length from flying height. 0 = none.
  double focal_prior_sigma = 0.0;
  // Per camera model (index into Reconstruction::cameras): its focal length held as it starts (e.g. tied by the caller
  // to the main camera's: one odd-sized shot cannot tell its focal length from its height).
  std::vector<char> focal_held;
  int max_iterations = 100;
  int threads = 1;
  // Gauge: image `fixed_image` is held fixed, and one coordinate (the largest) of the centre of `scale_image`
  // (relative to the fixed one) fixes the scale. -1 = automatic: image 0 and the image farthest from it.
  int fixed_image = -1;
  int scale_image = -1;
  // Camera-centre priors (GPS east/north, relative altitude), one entry per image or empty. With three or more the
  // priors fix the gauge (no image is held) and keep a nadir flight from bending into a dome, which focal length and
  // radial distortion otherwise allow.
  std::vector<std::optional<Eigen::Vector3d>> centre_priors;
  double prior_sigma_xy_m = 2.0;
  double prior_sigma_z_m = 1.0;
  // Ground control points, in the frame of the centres: each is a 3-D point of the adjustment tied to its surveyed
  // position (sigma control_sigma_m per axis) and to its clicks (sigma control_click_px). Three or more fix the gauge.
  struct Control {
    Eigen::Vector3d world = Eigen::Vector3d::Zero();
    std::vector<std::pair<int, Eigen::Vector2d>> observations;  // image, pixel
  };
  std::vector<Control> control;
  double control_sigma_m = 0.03;
  double control_sigma_z_m =
      0.0;  // the heights' sigma when it differs (horizontal control: loose); 0 = control_sigma_m
  double control_click_px = 1.0;
  [[nodiscard]] bool Check(std::string* why) const;
};

struct BundleSummary {
  double rms_before_px = 0.0;
  double rms_after_px = 0.0;
  int iterations = 0;
  double seconds = 0.0;
  bool converged = false;
  std::string report;                             // Ceres' one-line report
  std::vector<Eigen::Vector3d> control_adjusted;  // per BundleOptions::control, its adjusted 3-D point
};

// Adjusts poses, points and the shared intrinsics in place (Ceres, Schur solver).
[[nodiscard]] bool BundleAdjust(Reconstruction* rec, const BundleOptions& options, BundleSummary* summary,
                                std::string* error);

}  // namespace uavm::sfm
