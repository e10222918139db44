#pragma once
#include <cstddef>
#include <nlohmann/json.hpp>
#include <vector>

#include "core/sfm/feature_stage.h"
#include "core/sfm/tracks.h"

namespace uavm::sfm {

// 3. Matching of graph.csv's used pairs, verified by RANSAC on F.
struct PairMatch {
  int candidates = 0;                 // guided, ratio-tested, mutual
  int inliers = 0;                    // of F
  std::vector<FeatureMatch> matches;  // the inliers when at least min_pair_inliers, else none
};

// Frames a and b (image slots) matched within options.guided_radius of where the onboard maps put each feature of a
// in b (core/matching's radius matcher, shared with the onboard registration), ratio-tested, mutual, then verified by
// RANSAC on F.
[[nodiscard]] PairMatch MatchPair(size_t a, size_t b, const FrameFeatures& fa, const FrameFeatures& fb,
                                  const SessionFrame& frame_a, const SessionFrame& frame_b,
                                  const ReconstructionOptions& options);

// The verified matches of graph.csv's used pairs among the selected frames, in pair order (image slots, ascending).
[[nodiscard]] std::vector<FeatureMatch> MatchGraphPairs(const SelectedFrames& sel,
                                                        const std::vector<FrameFeatures>& feats,
                                                        const ReconstructionOptions& options,
                                                        const ProgressFn& progress, nlohmann::json* js);

}  // namespace uavm::sfm
