#pragma once
#include <Eigen/Core>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "core/sfm/camera.h"
#include "core/sfm/feature_stage.h"
#include "core/sfm/reconstruction.h"

namespace uavm::sfm {

// 5. Cameras and initial poses: one camera model per image size, poses from the onboard maps placed on GPS (or from a
// COLMAP model).
// GPS -> UTM (origin at the first GPS frame, so the solver works with small numbers).
struct GpsPositions {
  std::vector<std::optional<Eigen::Vector3d>> local;  // per image slot: E, N (relative to origin), altitude
  Eigen::Vector2d origin = Eigen::Vector2d::Zero();
  bool projected = false;  // a UTM zone and at least one position: the products carry the CRS below
  std::string crs_wkt;
  int epsg = 0;
};

// Each frame's GPS position in the UTM zone of the first frame that has one (core/georef, as onboard).
[[nodiscard]] GpsPositions ProjectGps(const std::vector<const SessionFrame*>& frames);

// Images per camera model, and the model most images use (the flight's main camera).
[[nodiscard]] std::vector<int> ImagesPerCamera(const Reconstruction& rec);
[[nodiscard]] size_t MostUsedCamera(const Reconstruction& rec);

// Mosaic -> world similarity (x_world = s Q x_mosaic + t).
struct MosaicToWorld {
  double s = 1.0;
  Eigen::Matrix2d Q = (Eigen::Matrix2d() << 1, 0, 0, -1).finished();  // mosaic rows go south
  Eigen::Vector2d t = Eigen::Vector2d::Zero();
  std::string pose_source;
};

// Mosaic -> world from the frame centres in the mosaic (centre_mosaic) onto GPS; without GPS, metres from the relative
// altitude when known (jac: each frame's local mosaic-from-frame Jacobian, fpx: its focal length in pixels), else
// mosaic pixels.
[[nodiscard]] MosaicToWorld FitMosaicToWorld(const std::vector<const SessionFrame*>& frames, const GpsPositions& gps,
                                             const std::vector<Eigen::Vector2d>& centre_mosaic,
                                             const std::vector<Eigen::Matrix2d>& jac, const std::vector<double>& fpx);

struct InitialModel {
  IntrinsicsGuess guess;
  GpsPositions gps;
  std::string pose_source;
  // Per camera model: its focal length over the main camera's from the onboard maps (0 = its own).
  std::vector<double> focal_ratio;
};

// rec's images (keypoints of feats, no points) with their cameras, and their initial poses: nadir from the onboard maps
// placed by FitMosaicToWorld, or options.colmap_import_dir's model.
[[nodiscard]] bool InitialPoses(const std::vector<const SessionFrame*>& frames, const std::vector<FrameFeatures>& feats,
                                const std::optional<SessionLens>& lens, const ReconstructionOptions& options,
                                Reconstruction* rec, InitialModel* out, nlohmann::json* js, std::string* error);

}  // namespace uavm::sfm
