#pragma once
#include <Eigen/Core>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "core/sfm/bundle_adjuster.h"
#include "core/sfm/initial_poses.h"
#include "core/sfm/tracks.h"

namespace uavm::sfm {

// 6. The sparse model: tracks triangulated with the initial poses, then bundle adjustment rounds with outlier
// rejection.
// What every BA round shares: the focal-length prior and the GPS centre priors.
struct BundlePriors {
  double focal_sigma = 0.1;
  std::vector<std::optional<Eigen::Vector3d>> centres;
  std::vector<double> focal_ratio;  // InitialModel's
};

// The priors of frames' initial model: the EXIF focal length (1 % with a known sensor, 10 % for a guess) and the GPS
// centres (with a relative altitude; none for a COLMAP import).
[[nodiscard]] BundlePriors MakeBundlePriors(const std::vector<const SessionFrame*>& frames, const InitialModel& init,
                                            const ReconstructionOptions& options, nlohmann::json* js);

// A camera model of another image size seen by too few images to calibrate (BundleOptions::min_images_for_lens) has
// its focal length tied to the main camera's by the onboard maps' ratio (FocalsFromOnboardScale), set before each
// adjustment and held in it: one odd-sized shot cannot tell its focal length from its height (free under a prior, a
// cropped frame went 12 % short started as resized, 10 % long started as cropped).
void TieFocals(const BundlePriors& priors, int min_images, Reconstruction* rec, BundleOptions* bo);

// Every track triangulated with the current poses; observations above max_err leave the track (it stays if two
// remain), points seen under less than min_angle_deg are dropped.
void TriangulateAll(const std::vector<Track>& tracks, const std::vector<FrameFeatures>& feats, double min_angle_deg,
                    double max_err, Reconstruction* rec);

// The first triangulation, the BA rounds and the final adjustment; the cameras and figures in *js.
[[nodiscard]] bool TriangulateAndAdjust(const std::vector<const SessionFrame*>& frames,
                                        const std::vector<FrameFeatures>& feats, const std::vector<Track>& tracks,
                                        const InitialModel& init, const ReconstructionOptions& options,
                                        const ProgressFn& progress, Reconstruction* rec, nlohmann::json* js,
                                        std::string* error);

}  // namespace uavm::sfm
