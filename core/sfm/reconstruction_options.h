#pragma once
#include <functional>
#include <string>
#include <vector>

#include "core/sfm/control_points.h"

namespace uavm::sfm {

// The ground reconstruction's options (the onboard program's are core/pipeline/options.h's PipelineOptions).
struct ReconstructionOptions {
  int threads = 2;
  // Features are re-detected in the stored frames at this fraction of the original resolution (1 = full); 0 = so that
  // the long side is feature_long_side_px (never enlarged). Measured against COLMAP (bench/results/ground-vs-colmap-*):
  // on 4000 px frames, 2000 px gives 4.6x the sparse points of full resolution on brighton_beach (8011 vs 1739) and
  // camera centres 3x closer to GPS, in 60 % of the time; SIFT at full size finds grass-scale blobs that do not repeat.
  double feature_scale = 0.0;
  int feature_long_side_px = 2000;
  int max_features = 12000;
  double contrast_threshold = 0.02;  // SIFT start threshold (lowered only when fewer than max_features/4 are found)
  double ratio = 0.8;
  // Matching is guided by the onboard maps: candidates within this fraction of the long image side of the predicted
  // position.
  double guided_radius = 0.04;
  double fundamental_threshold_px = 3.0;  // RANSAC on F, original-resolution pixels (F ignores the lens distortion)
  int min_pair_inliers = 15;
  std::string camera_model;  // EXIF Model for the sensor table
  double default_hfov_deg = 70.0;
  std::string colmap_import_dir;  // non-empty: initial poses and intrinsics from a COLMAP text model
  // Rejection after each BA round: reprojection thresholds per round (pixels); the first triangulation with the
  // initial poses uses initial_reprojection_px.
  double initial_reprojection_px = 60.0;
  std::vector<double> round_reprojection_px = {8.0, 3.0, 2.0};
  double min_triangulation_angle_deg = 1.0;
  bool refine_k3 = false;
  // Dense.
  bool dense = true;
  double dense_image_scale = 0.5;
  bool dense_daisy = false;  // --dense-cost daisy
  int dense_sample_step = 2;
  int max_dense_pairs = 40;
  int dense_pairs_per_image = 2;
  double min_baseline_ratio = 0.05, max_baseline_ratio = 0.6, target_baseline_ratio = 0.25;
  double min_pair_overlap = 0.3;        // share of the sparse points of one image seen by the other
  int fusion_min_pairs = 2;             // a DSM cell's points are kept when at least this many pairs agree there
  double dsm_cell_m = 0.0;              // 0 = automatic from the dense sampling
  double fusion_tolerance_cells = 2.0;  // agreement with the cell median, in cell sizes
  int dsm_fill_cells = 64;              // DSM holes are filled up to this many cells from a measured one
  // Ground control points (core/sfm/gcp.h): non-empty = gcp_list.txt; the outputs are then in its CRS.
  std::string gcp_file;
  std::vector<std::string> checkpoints;  // GCP names kept out of the adjustment, reported as checks
  ControlOptions control;
  double gcp_max_distance_km = 5.0;  // GCPs farther than this beyond the flight's GPS positions: wrong CRS
  [[nodiscard]] bool Check(std::string* why) const;
};

// A stage's progress: its name, items done, items in all.
using ProgressFn = std::function<void(const std::string& stage, size_t done, size_t total)>;

}  // namespace uavm::sfm
