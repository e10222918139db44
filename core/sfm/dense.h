#pragma once
#include <functional>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "core/sfm/cloud_and_dsm.h"
#include "core/sfm/reconstruction.h"

namespace uavm::sfm {

struct DenseOptions {
  double image_scale = 0.5;  // matching resolution relative to the original frames
  int sample_step = 2;
  int max_pairs = 40;
  double min_baseline_ratio = 0.05, max_baseline_ratio = 0.6, target_baseline_ratio = 0.25;
  double min_overlap = 0.3;
  int pairs_per_image = 2;  // the best partners of each image (two: one along the strip, often one across)
  int threads = 1;
  bool daisy_cost = false;  // the SGM matching cost: census (default) or DAISY (core/stereo/daisy.h)
};

struct StereoPairChoice {
  int image1 = -1, image2 = -1;
  double baseline_ratio = 0.0;  // baseline / median depth
  double overlap = 0.0;         // share of image1's sparse points that image2 sees
  double min_depth = 0.0, max_depth = 0.0;
};

// Pairs for dense matching: per image the pairs_per_image partners whose baseline-to-height ratio is closest to the
// target among those with enough overlap, duplicates removed, best first, at most max_pairs.
[[nodiscard]] std::vector<StereoPairChoice> SelectStereoPairs(const Reconstruction& rec, const DenseOptions& options);

struct DenseReport {
  std::vector<StereoPairChoice> pairs;
  std::vector<size_t> points_per_pair;
  std::vector<double> seconds_per_pair;
  std::vector<std::string> failures;
  std::vector<int> point_pair;  // per raw point: which pair made it
  size_t raw_points = 0;
  [[nodiscard]] nlohmann::json ToJson() const;
};

using DenseProgressFn = std::function<void(const std::string& stage, size_t done, size_t total)>;

// Dense points of the selected pairs (uavm::stereo::DensePointsFromPair), concatenated.
[[nodiscard]] bool DenseFromReconstruction(const Reconstruction& rec, const std::vector<std::string>& image_paths,
                                           const DenseOptions& options, const DenseProgressFn& progress,
                                           std::vector<CloudPoint>* points, DenseReport* report, std::string* error);

struct FusionReport {
  size_t input = 0, cells = 0, cells_consistent = 0, kept_points = 0, output_points = 0;
  [[nodiscard]] nlohmann::json ToJson() const;
};

// Fusion on a cell grid in x,y: per cell the median height of all pairs' points; points within `tolerance` of it are
// kept when at least `min_pairs` different pairs contributed such points (consistency between pairs), then averaged
// per voxel (cell x cell x cell) with their colours.
[[nodiscard]] std::vector<CloudPoint> FuseClouds(const std::vector<CloudPoint>& points, const std::vector<int>& pair_of,
                                                 double cell, double tolerance, int min_pairs, FusionReport* report);

}  // namespace uavm::sfm
