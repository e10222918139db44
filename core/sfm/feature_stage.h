#pragma once
#include <Eigen/Core>
#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "core/sfm/frame_selection.h"
#include "core/sfm/reconstruction_options.h"

namespace uavm::sfm {

// 2. Features of the selected frames, detected again in the stored frames at the feature scale.
struct FrameFeatures {
  std::vector<Eigen::Vector2d> points;  // original-resolution pixels
  std::vector<cv::Vec3b> colors;
  cv::Mat descriptors;
};

// The scale the frame is read at for features: options.feature_scale, or so that its long side is
// feature_long_side_px (never enlarged).
[[nodiscard]] double FeatureScale(const ReconstructionOptions& options, const SessionFrame& frame);

// (*feats)[i] for sel->frames[i]. A frame whose stored image cannot be read is left out (moved to sel->left_out with
// the reason), not the whole reconstruction; fails when fewer than two frames are left.
[[nodiscard]] bool ExtractFeatures(const std::string& session_dir, SelectedFrames* sel,
                                   const ReconstructionOptions& options, const ProgressFn& progress,
                                   std::vector<FrameFeatures>* feats, nlohmann::json* js, std::string* error);

}  // namespace uavm::sfm
