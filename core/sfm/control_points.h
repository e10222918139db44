#pragma once
#include <Eigen/Core>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "core/geometry/similarity.h"
#include "core/sfm/bundle_adjuster.h"
#include "core/sfm/gcp.h"
#include "core/sfm/reconstruction.h"

namespace uavm::sfm {

// A reconstruction tied to ground control points: moved onto them by a similarity, adjusted with them as weighted
// 3-D constraints, then every point (control and checkpoint) triangulated again from its clicks alone and compared with
// its survey. Checkpoints never enter the alignment or the adjustment, so their error is an independent check.
struct ControlOptions {
  double sigma_m = 0.03;  // survey accuracy per axis (RTK-surveyed targets: a few centimetres)
  double click_px = 1.0;  // click accuracy
  // A control point farther than this from its survey after the alignment is reported as suspicious (a misclick, a
  // wrong coordinate, or the wrong CRS): metres, and multiples of the ground sampling distance, whichever is larger.
  double suspicious_m = 1.0;
  double suspicious_gsd = 20.0;
  // Horizontal control only (a GCP file without heights: every Z the same, often 0, as a handheld GPS gives): the
  // points tie x and y; their heights stay where the flight's GPS put them, held there loosely (free_height_sigma_m)
  // so that a flight without GPS heights cannot drift, and the report says no height was checked.
  bool horizontal_only = false;
  double free_height_sigma_m = 10.0;
  [[nodiscard]] bool Check(std::string* why) const;
};

struct ControlPointError {
  std::string name;
  bool checkpoint = false;
  int clicks = 0;
  bool triangulated = false;
  Eigen::Vector3d surveyed = Eigen::Vector3d::Zero();  // the survey's position (the GCP CRS minus the offset)
  Eigen::Vector3d error_m = Eigen::Vector3d::Zero();   // triangulated - surveyed
  double reprojection_px = 0.0;                        // RMS of its clicks against the triangulated point
};

struct ControlReport {
  Similarity3 alignment;  // frame before -> GCP frame
  double alignment_rms_m = 0.0;
  std::vector<std::string> warnings;
  std::vector<ControlPointError> points;  // after the adjustment
  double gsd_m = 0.0;
  bool horizontal_only = false;  // the surveys have no height: errors and RMS are horizontal
  [[nodiscard]] nlohmann::json ToJson() const;
};

// Point from its clicks with the reconstruction's poses and camera (DLT, then image-error weights); nullopt when fewer
// than two clicks or behind a camera.
[[nodiscard]] std::optional<Eigen::Vector3d> TriangulateClicks(const Reconstruction& rec, const ControlPoint& cp);

// Moves `rec` (and the centre priors, which live in its frame) onto the control points' surveyed positions; with
// options.horizontal_only by a similarity about the vertical (x, y fitted; heights scaled about their mean).
[[nodiscard]] bool AlignToControl(const std::vector<ControlPoint>& cps, const ControlOptions& options,
                                  Reconstruction* rec, std::vector<std::optional<Eigen::Vector3d>>* centre_priors,
                                  ControlReport* report, std::string* error);

// The BundleOptions::control entries of the control points (checkpoints left out). With options.horizontal_only each
// point's height is where `rec` (aligned) triangulates it from its clicks: the surveys have none.
[[nodiscard]] std::vector<BundleOptions::Control> ControlConstraints(const std::vector<ControlPoint>& cps,
                                                                     const Reconstruction& rec,
                                                                     const ControlOptions& options);

// Every point's error after the adjustment, from its clicks alone.
void MeasureControl(const Reconstruction& rec, const std::vector<ControlPoint>& cps, ControlReport* report);

}  // namespace uavm::sfm
