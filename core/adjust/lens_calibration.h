#pragma once
// Self-calibration of the lens's radial distortion from the pose-free correspondences of a solved flight.
#include <array>
#include <cmath>
#include <string>
#include <string_view>
#include <unordered_map>
#include <unordered_set>
#include <vector>

#include "core/adjust/global_refiner.h"
#include "core/geometry/camera_model.h"

namespace uavm {

struct LensCalibrationOptions {
  bool enabled = true;
  int min_frames = 6;               // fewer frames rarely see the same ground at enough different radii
  int max_correspondences = 20000;  // a strided subset: the estimate needs spread, not every point
  // A longer flight calibrates its one lens on this many consecutive frames in its middle (and never more than
  // refine.max_frames_per_solve): the points are capped anyway, and the window's edges are resident while it runs, so
  // the phase costs what a flight of this length costs whatever the flight's length.
  int max_frames = 200;
  // The lens is accepted when the held-out points agree better with it, by more than chance: the per-edge mean drop
  // of their squared transfer error, over the edges, must be min_holdout_t standard errors above zero (edges, not
  // points, are the samples: the points of one edge share its errors), and the held-out RMS drop at least
  // min_holdout_gain of it.
  double min_holdout_t = 3.0;
  // 1 %: a lens the held-out points need makes a difference they show (the barrel flights: 58-87 %); a lens-free
  // tilted flight had one accepted at t 3.4 for a 0.17 % gain, and its error against the truth went 0.10 -> 0.24 px
  // (bench/results/issue40-sitting-20261205-vm.md).
  double min_holdout_gain = 0.01;
  double max_distortion = 0.3;  // |k1 r^2 + k2 r^4| at the half-diagonal; beyond it no camera a drone flies
  // A lens must matter: it moves the half-diagonal by at least this many working pixels (a lens of 0.0 % is no lens,
  // however many edges make it "significant").
  double min_effect_px = 0.25;
  // One lens for the whole flight: estimated again on each half of the frames (lower and upper ids: different strips,
  // different times), the two must agree, |d_a - d_b| <= max_halves_disagreement x |d| at the half-diagonal. Model
  // error a lens absorbs (tilts, relief, a rolling shutter) changes along the flight; a lens does not. 0 = off.
  double max_halves_disagreement = 1.0;
  // The halves are asked only when the lens removes less than this share of the held-out RMS: half a flight can be
  // one strip, which sees a lens poorly (caliterra's halves, 20 frames each: -1.5 % and +1.0 %, while the lens
  // took the held-out RMS from 4.46 to 0.82 px); model error has never bought such a gain, a small one it has.
  double halves_below_gain = 0.1;
  double prior_weight = 0.05;  // LensRefine::prior_weight
  // An accepted lens is estimated once more after the pairs it was estimated on are matched again with their
  // keypoints at its ideal pixels. The flight's RANSAC (an affine within 3 px) kept the correspondences a lens-free
  // model explains, the ones the lens displaces least, so a lens fitted to them alone comes out too weak: a -5 %
  // barrel on a jittered flight came out -4.8 % and cost 0.44 px against the truth (0.18 with the true lens).
  bool rematch = true;
  // The rematched points also replace the flight's in the final solve unless they fit the flight's held-out points
  // worse by more than this share (see RegistrationEngine::KeepBetterPoints).
  double rematch_holdout_tolerance = 0.02;

  [[nodiscard]] bool Check(std::string* why) const;
};

struct LensCalibration {
  bool tried = false;
  bool accepted = false;
  bool solve_failed = false;  // a refinement of the subset failed: the prepared lens is not verified either
  bool dropped = false;       // set by the caller: the prepared lens was dropped (distortion zero), see SetCamera()
  std::string why;            // not tried or refused: why
  LensDistortion distortion;  // the estimate (radial only), whether accepted or not
  double distortion_at_half_diagonal = 0.0;
  double holdout_without_px = 0.0;  // held-out RMS of the same subset's refinement with the prepared lens
  double holdout_with_px = 0.0;     // and with the estimated one
  size_t holdout_points = 0;
  size_t holdout_edges = 0;     // edges with held-out points in both solves: the paired test's samples
  double holdout_gain_t = 0.0;  // the paired test's statistic (mean per-edge drop / its standard error)
  // The lens estimated on each half of the frames alone (distortion at the half-diagonal; NaN: not estimated).
  double half_a_at_half_diagonal = std::nan("");
  double half_b_at_half_diagonal = std::nan("");
  size_t used = 0;    // correspondences in the two solves
  size_t frames = 0;  // frames calibrated on (the flight's middle, at most LensCalibrationOptions::max_frames)
  // With options.rematch: the pairs matched again under the first estimate, that estimate (NaN: not rematched), and
  // the held-out RMS of the correction estimated on them after it (without, with; 0: none kept).
  size_t rematched_edges = 0;
  double first_at_half_diagonal = std::nan("");
  double residual_holdout_without_px = 0.0;
  double residual_holdout_with_px = 0.0;
  // Then which points the final solve takes: the held-out RMS on the flight's held-out points of the subset refined on
  // the flight's points and on the rematched ones (0: not compared), and whether the rematched were kept.
  double holdout_flight_points_px = 0.0;
  double holdout_rematched_points_px = 0.0;
  bool rematched_points_kept = false;
  double seconds = 0.0;
};

// Refines the subset twice from `start` (the linear solution): with the points as `prepared` made them ideal, and with
// a shared radial undistortion estimated jointly with the maps (LensRefine); the lens is accepted when the held-out
// correspondences (which neither solve uses) agree better by more than chance (min_holdout_t, min_holdout_gain) and
// its distortion is plausible. The
// distortion returned is Brown's (k1, k2) in `prepared`'s normalised coordinates. Tangential terms are not estimated:
// a prepared lens with them is not calibrated again. `log_name` starts its log line.
[[nodiscard]] LensCalibration CalibrateLens(const std::vector<const Edge*>& edges,
                                            const std::unordered_set<int>& variable, int anchor,
                                            const std::unordered_map<int, double>& half_diagonal,
                                            const RefineOptions& refine, const PinholeCamera& prepared,
                                            const LensCalibrationOptions& options,
                                            const std::unordered_map<int, Mat3>& start,
                                            std::string_view log_name = "lens self-calibration");

// The paired test of the held-out points between two solves: per edge, the mean of e_without^2 - e_with^2 over its
// held-out points; over the edges, that mean divided by its standard error (0 with fewer than 3 edges).
struct PairedGain {
  size_t edges = 0;
  double mean_drop_px2 = 0.0;
  double t = 0.0;
};
[[nodiscard]] PairedGain HoldoutPairedGain(const std::vector<const Edge*>& edges,
                                           const std::unordered_map<int, Mat3>& without,
                                           const std::unordered_map<int, Mat3>& with, const LensRefine& lens);

// Moves an edge's points (kept and held out) from `prepared`'s ideal pixels to those of the same camera with
// `calibrated` as its distortion.
void ReprojectEdgePoints(const PinholeCamera& prepared, const LensDistortion& calibrated, Edge* edge);

// The radial undistortion (u1, u2, u3) of LensRefine closest to `d`'s inverse over (0, max_radius], and back.
[[nodiscard]] std::array<double, 3> UndistortionFromDistortion(const LensDistortion& d, double max_radius);
[[nodiscard]] LensDistortion DistortionFromUndistortion(const std::array<double, 3>& u, double max_radius);

// The radial distortion (k1, k2) closest to `first` after `residual` (recorded = first.Distort(residual.Distort(
// ideal)), both in one camera's normalised coordinates) over the ideal radii of the recorded (0, max_radius].
[[nodiscard]] LensDistortion ComposeRadial(const LensDistortion& first, const LensDistortion& residual,
                                           double max_radius);

}  // namespace uavm
