#pragma once
#include <array>
#include <string>
#include <unordered_map>
#include <unordered_set>
#include <vector>

#include "core/geometry/camera_model.h"
#include "core/geometry/transform.h"
#include "core/graph/match_graph.h"

namespace uavm {

// The per-frame motion model of the mosaic: a 6-dof affine (nadir camera) or an 8-dof homography (tilted camera).
enum class MotionModel { kAffine, kHomography };

[[nodiscard]] const char* ToString(MotionModel model);
[[nodiscard]] bool ParseMotionModel(const std::string& text, MotionModel* model);

struct RefineOptions {
  MotionModel model = MotionModel::kHomography;
  // Robust loss on each correspondence's transfer error, frame pixels.
  double huber_px = 2.0;
  // Nadir prior: each frame's perspective row (h20, h21) is pulled to 0, in pixels of denominator change at the
  // frame's half-diagonal. Weak against real matches; it fixes the mosaic's global projective freedom (a common
  // tilt of all frames cannot be observed from images) at "average tilt = 0".
  double nadir_weight = 0.1;
  // Similarity prior on each frame's 2x2 part (no shear, equal axis scales), frame pixels at the half-diagonal.
  double rigidity_weight = 0.05;
  // Largest ratio of the projective denominator between a frame's corners (2.0: ~20 degrees of tilt for a 70 degree
  // lens); beyond it the refinement is refused and the caller keeps an affine solution.
  double max_perspective_ratio = 2.0;
  // After a first solve, correspondences with a larger transfer error are dropped and the problem is solved again
  // (0 = keep all). The pipeline sets it to the pairwise RANSAC threshold: "inlier" means the same in both.
  double outlier_px = 3.0;
  int max_iterations = 50;
  // Cap on the correspondences handed to the solver (each costs ~1 KiB of solver memory): beyond it every edge
  // contributes an evenly strided subset of its grid-spread points. Set from the memory budget.
  int max_correspondences = 100000;
  double max_seconds = 0.0;  // 0 = no time limit
  int threads = 1;
  // Variable frames up to which the solve factors its normal equations (sparse Cholesky, whose fill-in grows faster
  // than the frames); a larger set is solved by conjugate gradients (memory linear in the correspondences) with at
  // most max_linear_iterations steps per Levenberg-Marquardt iteration.
  int max_frames_per_solve = 600;
  int max_linear_iterations = 150;
  // With the homography model, the end of the flight also refines affine maps and keeps whichever fits the held-out
  // correspondences better: a nadir flight's perspective rows fit noise (easy gate flight: 0.062 px true RMS with
  // homographies, 0.038 with affines), a tilted one needs them (0.17 against 1.42).
  bool choose_model = true;
  // The homographies are kept only when their held-out RMS is lower than the affines' by more than this share: the
  // held-out points barely see what a nadir flight's 2 extra parameters a frame fit (gate flights: 0.2 % lower
  // held-out RMS with affines, 40-57 % lower true RMS), while a tilt costs the affines far more (jitter_tilt: 52 %).
  double homography_min_gain = 0.01;

  [[nodiscard]] bool Check(std::string* why) const;
};

struct RefineResult {
  bool ok = false;
  std::string failure;
  size_t num_variables = 0;  // frames refined
  size_t num_residuals = 0;  // correspondences of the edges
  size_t num_used = 0;       // of which the solver used (max_correspondences)
  int iterations = 0;
  double initial_rms_px = 0.0;  // transfer error, target-frame pixels
  double final_rms_px = 0.0;    // over the final inliers (within outlier_px), or all when outlier_px = 0
  double final_median_px = 0.0;
  size_t final_inliers = 0;
  double final_all_rms_px = 0.0;  // over every correspondence of the edges
  size_t outliers = 0;            // correspondences removed by the outlier pass
  double seconds = 0.0;
  bool iterative = false;  // conjugate gradients (more than max_frames_per_solve variable frames)
};

// Self-calibration of the lens inside the refinement. The edges' points were made ideal with `prepared`'s distortion
// (none: the recorded pixels); each is taken back to its recorded pixel and through a radial undistortion shared by
// every frame, x_ideal = c + (x_rec - c) (1 + u1 rho^2 + u2 rho^4 + u3 rho^6), rho = |x_rec - c| / focal_px, whose
// (u1, u2, u3) the solve estimates with the maps. The undistortion, not the distortion, is the unknown: it is
// closed-form per point (the inverse of a Brown k1 needs the third term: 12 k1^3 rho^7 is pixels at the corners).
struct LensRefine {
  PinholeCamera prepared;                             // work pixels; no tangential terms
  std::array<double, 3> undistortion{0.0, 0.0, 0.0};  // in: start and prior mean; out: the estimate
  // Prior towards the start, as corner pixels (the displacement each term makes at the half-diagonal) per unit
  // weight: weak against thousands of correspondences, it keeps a flight that cannot see the lens near its start.
  double prior_weight = 1.0;

  // The point's position under the current undistortion.
  [[nodiscard]] Vec2 Ideal(const Vec2& prepared_point) const;
};

// Nonlinear refinement of the global solution: minimises each correspondence's transfer error measured in the target
// frame's pixels, |proj(T_tgt^-1 T_src p) - q|, with a robust loss, over the mosaic_from_frame maps of the frames in
// `variable` (8 dof with kHomography, 6 with kAffine). Unlike the linear adjustment's residual in mosaic pixels, this
// error does not change when all maps are scaled together, so the solution has no pull to shrink the mosaic towards
// its anchor. `anchor` (may be -1) keeps its affine part fixed — the gauge — while its perspective row stays free;
// other frames that edges touch but `variable` does not hold stay fixed. `half_diagonal` is per variable frame.
// Memory: at most options.max_correspondences points; beyond max_frames_per_solve variable frames no factorisation and
// no Jacobian (SolveTreeLm: the normal equations as 8x8 blocks per frame and per edge, conjugate gradients
// preconditioned by a spanning tree of the edges, factored without fill-in; one thread), so what the solve holds is
// linear in the frames and edges and does not grow with the points. The edges' points come from `points` (null: the
// edges' own); the solve holds a copy of the ones it uses.
[[nodiscard]] RefineResult RefineGlobal(const std::vector<const Edge*>& edges, const std::unordered_set<int>& variable,
                                        int anchor, const std::unordered_map<int, double>& half_diagonal,
                                        const RefineOptions& options, std::unordered_map<int, Mat3>* mosaic_from_frame,
                                        LensRefine* lens = nullptr, EdgePointSource* points = nullptr);

struct TransferStats {
  size_t count = 0;
  double rms = 0.0;
  double median = 0.0;  // ResidualHistogram's (within 0.12 %)
};
// Transfer errors |proj(T_tgt^-1 T_src p) - q| over all correspondences of `edges` whose frames have maps (with
// `holdout`: over the held-out points instead); with max_px > 0, only errors up to max_px count (inliers). With
// `lens`, the points are first taken through its Ideal(). The points come from `points` (null: the edges' own).
[[nodiscard]] TransferStats TransferErrors(const std::vector<const Edge*>& edges,
                                           const std::unordered_map<int, Mat3>& mosaic_from_frame, bool holdout = false,
                                           double max_px = 0.0, const LensRefine* lens = nullptr,
                                           EdgePointSource* points = nullptr);

}  // namespace uavm
