#pragma once
#include <string>
#include <unordered_map>
#include <unordered_set>
#include <vector>

#include "core/geometry/transform.h"
#include "core/graph/match_graph.h"

namespace uavm {

struct AdjustOptions {
  // Similarity prior on each frame's linear part (no shear, equal axis scales), in pixels at the frame's
  // half-diagonal: it stops scale/shear drift along long chains without fixing the scale itself.
  double rigidity_weight = 0.05;
  // Keeps each edge's relative linear part (relative scale and rotation) as the pair measured it, so a real
  // altitude change is followed, not fought.
  double relative_linear_weight = 0.02;
  double huber_px = 2.0;
  int robust_iterations = 2;
  // Up to this many variable frames the normal equations are factored (sparse LDLT); beyond, they are solved by
  // block-preconditioned conjugate gradients, whose memory grows with the frames and edges only (a few hundred bytes
  // each), not with a factor's fill: the end of a long flight stays within its memory plan.
  int direct_max_frames = 1000;
  double iterative_tolerance = 1e-13;  // relative residual |N x - b| / |b| at which the iteration stops
  int max_iterative_steps = 20000;

  [[nodiscard]] bool Check(std::string* why) const;
};

struct AdjustResult {
  bool ok = false;
  std::string failure;
  size_t num_variables = 0;
  size_t num_residuals = 0;
  bool iterative = false;   // solved by conjugate gradients (more frames than direct_max_frames)
  int iterative_steps = 0;  // over every robust pass
  double rms_px = 0.0;      // correspondence residuals, mosaic pixels
  double median_px = 0.0;
};

struct ResidualStats {
  size_t count = 0;
  double rms = 0.0;
  double median = 0.0;  // ResidualHistogram's (within 0.12 %)
  double max = 0.0;
};

// Global affine adjustment: one sparse linear least-squares problem over the 2x3 mosaic_from_frame of every frame in
// `variable`; frames not in `variable` (the reference, or everything else in a local update) stay fixed.
// `mosaic_from_frame` must hold every frame that an edge touches; only variable frames are written.
// `half_diagonal` gives each variable frame's half-diagonal in pixels (weights the rigidity terms). The edges' points
// come from `points` (null: the edges' own).
[[nodiscard]] AdjustResult AdjustAffine(const std::vector<const Edge*>& edges, const std::unordered_set<int>& variable,
                                        const std::unordered_map<int, double>& half_diagonal,
                                        const AdjustOptions& options, std::unordered_map<int, Mat3>* mosaic_from_frame,
                                        EdgePointSource* points = nullptr);

// Residuals |T_src p - T_tgt q| over all edge correspondences whose frames both have transforms. The median is
// ResidualHistogram's.
[[nodiscard]] ResidualStats EdgeResiduals(const std::vector<const Edge*>& edges,
                                          const std::unordered_map<int, Mat3>& mosaic_from_frame,
                                          EdgePointSource* points = nullptr);

}  // namespace uavm
