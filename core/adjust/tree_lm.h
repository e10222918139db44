#pragma once
// Levenberg-Marquardt for the refinement of long flights: frames of kFrameParams parameters coupled in pairs by edges,
// with one optional block shared by all (the lens). It keeps the normal equations as 8x8 blocks, one per frame and one
// per edge, never the Jacobian: each edge's Jacobian is evaluated, folded into its blocks and dropped. Each step is
// solved by conjugate gradients preconditioned by a spanning tree of the edges, factored leaves first (no fill-in).
//
// Memory, all of it linear in the frames and edges and none in the correspondences: 64 floats per edge (its coupling
// block), 2 x 36 + 24 doubles per frame (its symmetric block and its tree factor, each as a packed lower triangle; its
// lens coupling) and ten vectors of 8 doubles per frame: ~2.6 KiB a frame at five edges a frame (was ~4.8 with double
// couplings and a second copy of each frame's block while factoring, ~3.1 with full 8x8 frame blocks).
// Ceres' CGNR held the Jacobian (32 doubles per correspondence) and its subset preconditioner a copy of it.
#include <array>
#include <cstddef>
#include <string>
#include <vector>

namespace uavm {

constexpr int kFrameParams = 8;   // the affine rows (6), then the perspective row (2)
constexpr int kSharedParams = 3;  // the lens's undistortion
constexpr int kEdgeColumns = 2 * kFrameParams + kSharedParams;

using FrameParamVector = std::array<double, kFrameParams>;
using SharedParamVector = std::array<double, kSharedParams>;

// What the solver minimises: half the sum of squares of every residual the terms give. Jacobians are row-major, one
// row per residual appended.
class FrameGraphTerms {
 public:
  virtual ~FrameGraphTerms() = default;
  [[nodiscard]] virtual size_t NumFrames() const = 0;
  [[nodiscard]] virtual size_t NumEdges() const = 0;
  [[nodiscard]] virtual size_t EdgeSrc(size_t edge) const = 0;
  [[nodiscard]] virtual size_t EdgeTgt(size_t edge) const = 0;
  // The preconditioner's edges: a forest over the frames (at most one path between two frames).
  [[nodiscard]] virtual bool InTree(size_t edge) const = 0;
  // Whether parameter k of the frame moves (a constant one keeps its value).
  [[nodiscard]] virtual bool Free(size_t frame, int k) const = 0;
  [[nodiscard]] virtual bool HasShared() const = 0;
  // Residuals of an edge; with `jacobian`, kEdgeColumns columns (source frame, target frame, shared block).
  virtual void Edge(size_t edge, const double* src, const double* tgt, const double* shared,
                    std::vector<double>* residuals, std::vector<double>* jacobian) const = 0;
  // Priors on one frame's parameters (kFrameParams columns) and on the shared block (kSharedParams columns).
  virtual void FramePrior(size_t frame, const double* params, std::vector<double>* residuals,
                          std::vector<double>* jacobian) const = 0;
  virtual void SharedPrior(const double* shared, std::vector<double>* residuals,
                           std::vector<double>* jacobian) const = 0;
};

struct TreeLmOptions {
  int max_iterations = 50;          // steps tried, taken or not (as Ceres counts them)
  int max_linear_iterations = 150;  // conjugate-gradient steps per step
  double linear_tolerance = 1e-3;   // of the preconditioned residual, relative to the right-hand side's
  double function_tolerance = 1e-6;
  double parameter_tolerance = 1e-10;
  double gradient_tolerance = 1e-10;
  double max_seconds = 0.0;  // 0 = no limit

  [[nodiscard]] bool Check(std::string* why) const;
};

struct TreeLmSummary {
  bool usable = false;
  int iterations = 0;
  int linear_iterations = 0;
  double initial_cost = 0.0;
  double final_cost = 0.0;
  std::string message;
};

// Minimises the terms over `frames` (NumFrames of them) and `shared` (used only when HasShared), from their values.
[[nodiscard]] TreeLmSummary SolveTreeLm(const FrameGraphTerms& terms, const TreeLmOptions& options,
                                        std::vector<FrameParamVector>* frames, SharedParamVector* shared);

}  // namespace uavm
