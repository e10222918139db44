#include "core/adjust/global_refiner.h"

#include <ceres/ceres.h>
#include <spdlog/spdlog.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cmath>
#include <map>
#include <optional>

#include "core/adjust/tree_lm.h"
#include "core/util/clock.h"
#include "core/util/stats.h"

namespace uavm {

const char* ToString(MotionModel model) {
  return model == MotionModel::kAffine ? "affine" : "homography";
}

bool ParseMotionModel(const std::string& text, MotionModel* model) {
  if (text == "affine") {
    *model = MotionModel::kAffine;
    return true;
  }
  if (text == "homography") {
    *model = MotionModel::kHomography;
    return true;
  }
  return false;
}

bool RefineOptions::Check(std::string* why) const {
  if (!(huber_px > 0) || !(nadir_weight >= 0) || !(rigidity_weight >= 0) || max_iterations < 1 || !(max_seconds >= 0) ||
      threads < 1 || threads > 64 || !(max_perspective_ratio > 1) || max_correspondences < 100 || !(outlier_px >= 0) ||
      max_frames_per_solve < 2 || max_linear_iterations < 1 || !(homography_min_gain >= 0 && homography_min_gain < 1)) {
    if (why != nullptr)
      *why =
          "refine: huber_px > 0, weights >= 0, max_iterations >= 1, max_seconds >= 0, threads in [1,64], "
          "max_perspective_ratio > 1, max_correspondences >= 100, outlier_px >= 0, max_frames_per_solve >= 2, "
          "max_linear_iterations >= 1, homography_min_gain in [0,1)";
    return false;
  }
  return true;
}

namespace {

// Points an edge needs to join the spanning tree that preconditions the iterative solve: an affine pair is then
// determined (3 points) with one to spare, and the tree's normal equations are positive definite.
constexpr size_t kTreeMinPoints = 4;

// Per frame: the affine rows (h00 h01 h02 h10 h11 h12) and the perspective row (h20 h21), h22 = 1. Two blocks, so
// that the affine model holds the perspective block constant and the anchor holds its affine block constant.
struct FrameParams {
  std::array<double, 6> affine{};
  std::array<double, 2> perspective{};
};

FrameParams ToParams(const Mat3& m_in) {
  const Mat3 m = m_in / m_in(2, 2);
  FrameParams p;
  p.affine = {m(0, 0), m(0, 1), m(0, 2), m(1, 0), m(1, 1), m(1, 2)};
  p.perspective = {m(2, 0), m(2, 1)};
  return p;
}

Mat3 FromParams(const FrameParams& p) {
  Mat3 m;
  m << p.affine[0], p.affine[1], p.affine[2], p.affine[3], p.affine[4], p.affine[5], p.perspective[0], p.perspective[1],
      1.0;
  return m;
}

// The correspondences an edge contributes to the refinement: `count` pairs at `pairs`, each its source point then its
// target point (a view into the RefineProblem's one block of them).
struct KeptPairs {
  const Vec2f* pairs = nullptr;
  size_t count = 0;
  [[nodiscard]] size_t size() const { return count; }
  [[nodiscard]] const Vec2f& src(size_t k) const { return pairs[2 * k]; }
  [[nodiscard]] const Vec2f& tgt(size_t k) const { return pairs[2 * k + 1]; }
};

// Transfer errors of one edge's correspondences (the problem's own copy of those it keeps): each source point through
// mosaic_from_src, then back through the inverse of mosaic_from_tgt (its adjugate: the determinant cancels in the
// projective division), minus the target point. One residual block per edge, not per point: Ceres' per-block
// bookkeeping was most of the solve's memory (1.3 kB per correspondence measured, now ~0.6). Each point keeps its own
// Huber loss: its residual is scaled so that its squared norm is rho(s) (the same cost and gradient as a per-point
// HuberLoss). With a LensRefine, a fifth block holds its (u1, u2, u3): each point is taken to its recorded pixel
// (precomputed) and through the undistortion.
struct EdgeTransferCost {
  EdgeTransferCost(KeptPairs kept, double huber_px, const LensRefine* lens_refine)
      : points(kept), delta(huber_px), lens(lens_refine) {
    if (lens == nullptr) return;
    for (size_t k = 0; k < points.size(); ++k) {
      recorded.push_back(lens->prepared.DistortPixel(points.src(k).cast<double>()));
      recorded.push_back(lens->prepared.DistortPixel(points.tgt(k).cast<double>()));
    }
  }

  // Point j's source (which = 0) or target (1) position, ideal under the block's (u1, u2) when there is a lens.
  template <typename T>
  void Point(T const* const* blocks, size_t j, int which, T* x, T* y) const {
    if (lens == nullptr) {
      const Vec2f& p = which == 0 ? points.src(j) : points.tgt(j);
      *x = T(p.x());
      *y = T(p.y());
      return;
    }
    const T* u = blocks[4];
    const Vec2 d = recorded[2 * j + static_cast<size_t>(which)] - Vec2(lens->prepared.cx, lens->prepared.cy);
    const double rho2 = d.squaredNorm() / (lens->prepared.focal_px * lens->prepared.focal_px);
    const T scale = T(1.0) + rho2 * (u[0] + rho2 * (u[1] + rho2 * u[2]));
    *x = T(lens->prepared.cx) + scale * d.x();
    *y = T(lens->prepared.cy) + scale * d.y();
  }

  template <typename T>
  bool operator()(T const* const* blocks, T* residual) const {
    const T* sa = blocks[0];
    const T* sp = blocks[1];
    const T* ta = blocks[2];
    const T* tp = blocks[3];
    // mosaic_from_tgt = [[a b c] [d e f] [g h 1]]; its adjugate rows.
    const T& a = ta[0];
    const T& b = ta[1];
    const T& c = ta[2];
    const T& d = ta[3];
    const T& e = ta[4];
    const T& f = ta[5];
    const T& g = tp[0];
    const T& h = tp[1];
    const T r00 = e - f * h, r01 = c * h - b, r02 = b * f - c * e;
    const T r10 = f * g - d, r11 = a - c * g, r12 = c * d - a * f;
    const T r20 = d * h - e * g, r21 = b * g - a * h, r22 = a * e - b * d;
    const double d2 = delta * delta;
    for (size_t j = 0; j < points.size(); ++j) {
      T px, py, qx, qy;
      Point(blocks, j, 0, &px, &py);
      Point(blocks, j, 1, &qx, &qy);
      const T mx = sa[0] * px + sa[1] * py + sa[2];
      const T my = sa[3] * px + sa[4] * py + sa[5];
      const T mw = sp[0] * px + sp[1] * py + T(1.0);
      const T x = r00 * mx + r01 * my + r02 * mw;
      const T y = r10 * mx + r11 * my + r12 * mw;
      const T w = r20 * mx + r21 * my + r22 * mw;
      T rx = x / w - qx;
      T ry = y / w - qy;
      const T sq = rx * rx + ry * ry;
      if (sq > T(d2)) {  // Huber: rho(s) = 2 delta sqrt(s) - delta^2 beyond delta
        const T root = sqrt(sq);
        const T scale = sqrt(T(2.0 * delta) * root - T(d2)) / root;
        rx *= scale;
        ry *= scale;
      }
      residual[2 * j] = rx;
      residual[2 * j + 1] = ry;
    }
    return true;
  }

  KeptPairs points;  // borrowed: the RefineProblem's
  double delta;
  const LensRefine* lens;
  std::vector<Vec2> recorded;  // with a lens: per kept point, source then target recorded pixel
};

// The lens's undistortion towards its start, in pixels of displacement at the half-diagonal.
struct LensPrior {
  LensPrior(double weight, double hd_rho2, double hd_px, std::array<double, 3> start)
      : w(weight), r2(hd_rho2), px(hd_px), u0(start) {}
  template <typename T>
  bool operator()(const T* u, T* residual) const {
    residual[0] = w * px * r2 * (u[0] - u0[0]);
    residual[1] = w * px * r2 * r2 * (u[1] - u0[1]);
    residual[2] = w * px * r2 * r2 * r2 * (u[2] - u0[2]);
    return true;
  }
  double w, r2, px;
  std::array<double, 3> u0;
};

// Perspective row towards 0, as the denominator's change across the half-diagonal, in pixels at the half-diagonal.
struct NadirPrior {
  explicit NadirPrior(double weight_px) : w(weight_px) {}
  template <typename T>
  bool operator()(const T* perspective, T* residual) const {
    residual[0] = w * perspective[0];
    residual[1] = w * perspective[1];
    return true;
  }
  double w;
};

// The frame's local linear map at its centre c towards a similarity (no shear, equal axis scales), divided by the
// frame's scale so the prior reads in frame pixels at the half-diagonal. For a homography [A t; p 1] the local map is
// (A - m p^T) / w with m the centre's mosaic position and w its denominator: the raw A is not, far from the origin.
struct RigidityPrior {
  RigidityPrior(double weight_px, const Vec2& centre) : w(weight_px), cx(centre.x()), cy(centre.y()) {}
  template <typename T>
  bool operator()(const T* a, const T* p, T* residual) const {
    const T den = p[0] * cx + p[1] * cy + T(1.0);
    const T mx = (a[0] * cx + a[1] * cy + a[2]) / den;
    const T my = (a[3] * cx + a[4] * cy + a[5]) / den;
    const T j00 = (a[0] - mx * p[0]) / den;
    const T j01 = (a[1] - mx * p[1]) / den;
    const T j10 = (a[3] - my * p[0]) / den;
    const T j11 = (a[4] - my * p[1]) / den;
    residual[0] = w * (j00 - j11);
    residual[1] = w * (j01 + j10);
    return true;
  }
  double w, cx, cy;
};

// What stays constant of a frame and its priors (nadir, rigidity), for both solvers.
struct FramePriors {
  bool affine_constant = false;
  bool perspective_constant = false;
  std::optional<NadirPrior> nadir;
  std::optional<RigidityPrior> rigidity;
};

// One edge of the iterative solve: its correspondences and its frames' dense indices.
struct TermEdge {
  KeptPairs points;  // borrowed: the RefineProblem's
  size_t src = 0;
  size_t tgt = 0;
  bool in_tree = false;
};

// The refinement's problem for SolveTreeLm: the same residuals as the Ceres problem's (EdgeTransferCost and the
// priors), differentiated by Ceres' jets.
class RefineTerms final : public FrameGraphTerms {
 public:
  RefineTerms(std::vector<TermEdge> edges, std::vector<FramePriors> frames, double huber_px, const LensRefine* lens,
              std::optional<LensPrior> lens_prior)
      : edges_(std::move(edges)),
        frames_(std::move(frames)),
        huber_px_(huber_px),
        lens_(lens),
        lens_prior_(std::move(lens_prior)) {}

  size_t NumFrames() const override { return frames_.size(); }
  size_t NumEdges() const override { return edges_.size(); }
  size_t EdgeSrc(size_t edge) const override { return edges_[edge].src; }
  size_t EdgeTgt(size_t edge) const override { return edges_[edge].tgt; }
  bool InTree(size_t edge) const override { return edges_[edge].in_tree; }
  bool Free(size_t frame, int k) const override {
    return k < 6 ? !frames_[frame].affine_constant : !frames_[frame].perspective_constant;
  }
  bool HasShared() const override { return lens_ != nullptr; }

  void Edge(size_t edge, const double* src, const double* tgt, const double* shared, std::vector<double>* residuals,
            std::vector<double>* jacobian) const override {
    const TermEdge& t = edges_[edge];
    const EdgeTransferCost cost(t.points, huber_px_, lens_);
    const size_t rows = 2 * t.points.size();
    const size_t at = residuals->size();
    residuals->resize(at + rows);
    if (jacobian == nullptr) {
      const std::array<const double*, 5> blocks{src, src + 6, tgt, tgt + 6, shared};
      cost(blocks.data(), residuals->data() + at);
      return;
    }
    using EdgeJet = ceres::Jet<double, kEdgeColumns>;
    std::array<EdgeJet, kEdgeColumns> x;
    for (int k = 0; k < kFrameParams; ++k) {
      x[k] = EdgeJet(src[k], k);
      x[kFrameParams + k] = EdgeJet(tgt[k], kFrameParams + k);
    }
    for (int k = 0; k < kSharedParams; ++k)
      x[2 * kFrameParams + k] = EdgeJet(shared != nullptr ? shared[k] : 0.0, 2 * kFrameParams + k);
    const std::array<const EdgeJet*, 5> blocks{&x[0], &x[6], &x[kFrameParams], &x[kFrameParams + 6],
                                               &x[2 * kFrameParams]};
    jets_.resize(rows);
    cost(blocks.data(), jets_.data());
    for (size_t i = 0; i < rows; ++i) {
      (*residuals)[at + i] = jets_[i].a;
      jacobian->insert(jacobian->end(), jets_[i].v.data(), jets_[i].v.data() + kEdgeColumns);
    }
  }

  void FramePrior(size_t frame, const double* params, std::vector<double>* residuals,
                  std::vector<double>* jacobian) const override {
    const FramePriors& p = frames_[frame];
    if (p.nadir)
      Append<kFrameParams, 2>(params, residuals, jacobian, [&](const auto* x, auto* r) { (*p.nadir)(x + 6, r); });
    if (p.rigidity)
      Append<kFrameParams, 2>(params, residuals, jacobian, [&](const auto* x, auto* r) { (*p.rigidity)(x, x + 6, r); });
  }

  void SharedPrior(const double* shared, std::vector<double>* residuals, std::vector<double>* jacobian) const override {
    if (lens_prior_)
      Append<kSharedParams, 3>(shared, residuals, jacobian, [&](const auto* x, auto* r) { (*lens_prior_)(x, r); });
  }

 private:
  // A prior of kRows residuals over N parameters: its values, and with `jacobian` its rows.
  template <int N, int kRows, typename F>
  static void Append(const double* params, std::vector<double>* residuals, std::vector<double>* jacobian,
                     const F& prior) {
    if (jacobian == nullptr) {
      std::array<double, kRows> r{};
      prior(params, r.data());
      residuals->insert(residuals->end(), r.begin(), r.end());
      return;
    }
    using PriorJet = ceres::Jet<double, N>;
    std::array<PriorJet, N> x;
    for (int k = 0; k < N; ++k) x[k] = PriorJet(params[k], k);
    std::array<PriorJet, kRows> r;
    prior(x.data(), r.data());
    for (int i = 0; i < kRows; ++i) {
      residuals->push_back(r[i].a);
      jacobian->insert(jacobian->end(), r[i].v.data(), r[i].v.data() + N);
    }
  }

  std::vector<TermEdge> edges_;
  std::vector<FramePriors> frames_;
  // One edge's residuals as jets, reused from edge to edge (SolveTreeLm evaluates on one thread).
  mutable std::vector<ceres::Jet<double, kEdgeColumns>> jets_;
  double huber_px_;
  const LensRefine* lens_;
  std::optional<LensPrior> lens_prior_;
};

// The refinement's problem: the edges used, a copy of the correspondences each contributes (`kept`: the edges' own
// points may be read back one edge at a time, see EdgePointSource), the frames' parameters.
class RefineProblem {
 public:
  RefineProblem(const std::vector<const Edge*>& edges, const std::unordered_set<int>& variable, int anchor,
                const std::unordered_map<int, double>& half_diagonal, const RefineOptions& options,
                const std::unordered_map<int, Mat3>& T, LensRefine* lens, EdgePointSource* points)
      : variable_(variable),
        anchor_(anchor),
        half_diagonal_(half_diagonal),
        options_(options),
        lens_(lens),
        points_(points) {
    for (const Edge* e : edges) {
      if (T.count(e->src) == 0 || T.count(e->tgt) == 0) continue;
      const bool touches =
          variable.count(e->src) != 0 || variable.count(e->tgt) != 0 || e->src == anchor || e->tgt == anchor;
      if (!touches) continue;
      const size_t n = PointsOf(*e, points_).size();
      if (n == 0) continue;
      used_.push_back(e);
      full_.push_back(static_cast<uint32_t>(n));
    }
  }

  const std::vector<const Edge*>& used() const { return used_; }
  KeptPairs Kept(size_t i) const {
    return {kept_pairs_.data() + 2 * static_cast<size_t>(kept_begin_[i]), kept_begin_[i + 1] - kept_begin_[i]};
  }
  bool empty() const { return params_.empty(); }
  // The variable frames the edges touch (known before Select: it decides the solve, which decides the selection).
  size_t NumVariables() const {
    std::unordered_set<int> touched;
    for (const Edge* e : used_)
      for (int id : {e->src, e->tgt})
        if (variable_.count(id) != 0) touched.insert(id);
    return touched.size();
  }

  // The correspondences each edge contributes: every `stride`-th (points are grid-spread over the frame in no
  // particular order, so a stride keeps the spread); the parameters of the frames they touch. Returns how many.
  size_t Select(size_t stride, bool iterative, const std::unordered_map<int, Mat3>& T) {
    size_t used_points = 0;
    kept_pairs_.clear();
    kept_begin_.assign(1, 0);
    // The iterative solve's preconditioner is a spanning tree of edges of kTreeMinPoints points at least: where the
    // stride leaves an edge fewer (a flight beyond ~5000 frames at the defaults: 12 points an edge, stride 4), the
    // edges of a tree over the full point counts keep that many, at most a point more per frame than the cap.
    const std::vector<size_t> full(full_.begin(), full_.end());
    const std::vector<bool> tree =
        iterative && stride > 1 ? SpanningTreeBy(full) : std::vector<bool>(used_.size(), false);
    std::vector<size_t> steps(used_.size());
    size_t most = 0;  // the block is reserved once: the solvers point into it
    for (size_t i = 0; i < used_.size(); ++i) {
      steps[i] = stride;
      if (tree[i] && (full[i] + stride - 1) / stride < kTreeMinPoints)
        steps[i] = std::max<size_t>(1, full[i] / kTreeMinPoints);
      most += (full[i] + steps[i] - 1) / steps[i];
    }
    kept_pairs_.reserve(2 * most);
    for (size_t i = 0; i < used_.size(); ++i) {
      const Edge* e = used_[i];
      const EdgePoints& points = PointsOf(*e, points_);
      const size_t n = std::min<size_t>(full[i], points.size());  // a read that failed now keeps nothing
      for (size_t k = 0; k < n; k += steps[i]) {
        kept_pairs_.push_back(points.src(k));
        kept_pairs_.push_back(points.tgt(k));
      }
      kept_begin_.push_back(static_cast<uint32_t>(kept_pairs_.size() / 2));
      used_points += Kept(i).size();
      for (int id : {e->src, e->tgt})
        if (params_.find(id) == params_.end()) params_.emplace(id, ToParams(T.at(id)));
      // A frame's centre, from the extent of its own correspondence points (the frame size is not passed in).
      for (size_t k = 0; k < n; ++k) {
        extent_[e->src].extend(points.src(k).cast<double>());
        extent_[e->tgt].extend(points.tgt(k).cast<double>());
      }
    }
    for (const auto& [id, box] : extent_) frame_centre_[id] = box.center();
    return used_points;
  }

  // Solves the problem over the current `keep` lists by a factorisation (Ceres), the parameters staying in `params_`
  // between solves. Empty on success, else why.
  std::string Solve(const ceres::Solver::Options& solver_options, int* iterations, bool log) {
    ceres::Problem problem;
    Build(&problem);
    ceres::Solver::Summary summary;
    ceres::Solve(solver_options, &problem, &summary);
    if (log) spdlog::debug("refinement: {}", summary.BriefReport());
    *iterations += static_cast<int>(summary.iterations.size());
    return summary.IsSolutionUsable() ? std::string() : "refinement failed: " + summary.message;
  }

  // The same by SolveTreeLm: conjugate gradients preconditioned by the spanning tree, no Jacobian held.
  std::string SolveIterative(const TreeLmOptions& lm_options, int* iterations, bool log) {
    std::unordered_map<int, size_t> index;
    std::vector<FrameParamVector> x;
    std::vector<FramePriors> priors;
    for (const auto& [id, p] : params_) {
      index.emplace(id, x.size());
      FrameParamVector v;
      std::copy(p.affine.begin(), p.affine.end(), v.begin());
      std::copy(p.perspective.begin(), p.perspective.end(), v.begin() + 6);
      x.push_back(v);
      priors.push_back(PriorsOf(id, p));
    }
    const std::vector<bool> in_tree = SpanningTree();
    std::vector<TermEdge> edges;
    for (size_t i = 0; i < used_.size(); ++i)
      if (Kept(i).size() != 0) edges.push_back({Kept(i), index.at(used_[i]->src), index.at(used_[i]->tgt), in_tree[i]});
    const LensRefine* lens = edges.empty() ? nullptr : lens_;
    std::optional<LensPrior> lens_prior;
    if (lens != nullptr) lens_prior = MakeLensPrior();
    const RefineTerms terms(std::move(edges), std::move(priors), options_.huber_px, lens, lens_prior);
    SharedParamVector shared{};
    if (lens != nullptr) shared = lens->undistortion;
    const TreeLmSummary summary = SolveTreeLm(terms, lm_options, &x, &shared);
    if (log)
      spdlog::debug("refinement: tree-preconditioned LM, {} steps ({} linear), cost {:.6g} -> {:.6g}, stopped by {}",
                    summary.iterations, summary.linear_iterations, summary.initial_cost, summary.final_cost,
                    summary.message);
    *iterations += summary.iterations;
    if (!summary.usable) return "refinement failed: " + summary.message;
    for (auto& [id, p] : params_) {
      const FrameParamVector& v = x[index.at(id)];
      std::copy(v.begin(), v.begin() + 6, p.affine.begin());
      std::copy(v.begin() + 6, v.end(), p.perspective.begin());
    }
    if (lens_ != nullptr && lens != nullptr) lens_->undistortion = shared;
    return {};
  }

  // Correspondences the refined maps put beyond the pairwise inlier threshold (moving water, parallax on relief, a
  // match that only fitted the pair's affine) are dropped, as a bundle adjustment filters its observations. An edge
  // that would lose more than half of its points keeps them all. Returns how many were dropped.
  size_t DropOutliers() {
    size_t removed = 0;
    size_t write = 0;  // in pairs: the block is compacted in place (a pair only moves towards the front)
    std::vector<char> good;
    for (size_t i = 0; i < used_.size(); ++i) {
      const Edge* e = used_[i];
      const Mat3 tgt_from_src = FromParams(params_.at(e->tgt)).inverse() * FromParams(params_.at(e->src));
      const KeptPairs kept = Kept(i);
      good.assign(kept.size(), 0);
      size_t bad = 0;
      for (size_t k = 0; k < kept.size(); ++k) {
        good[k] = (Apply(tgt_from_src, Ideal(kept.src(k).cast<double>())) - Ideal(kept.tgt(k).cast<double>())).norm() <=
                  options_.outlier_px;
        bad += good[k] != 0 ? 0 : 1;
      }
      const bool drop = bad > 0 && 2 * bad <= kept.size();
      if (drop) removed += bad;
      kept_begin_[i] = static_cast<uint32_t>(write);
      for (size_t k = 0; k < kept.size(); ++k) {
        if (drop && good[k] == 0) continue;
        const Vec2f src = kept.src(k);
        const Vec2f tgt = kept.tgt(k);
        kept_pairs_[2 * write] = src;
        kept_pairs_[2 * write + 1] = tgt;
        ++write;
      }
    }
    kept_begin_.back() = static_cast<uint32_t>(write);
    kept_pairs_.resize(2 * write);
    return removed;
  }

  // The refined maps of the variable frames and the anchor; empty on success, else why.
  std::string Refined(std::unordered_map<int, Mat3>* refined) const {
    for (const auto& [id, p] : params_) {
      if (variable_.count(id) == 0 && id != anchor_) continue;
      const Mat3 m = FromParams(p);
      if (!m.allFinite() || std::abs(m.determinant()) < 1e-12) return "refinement produced a degenerate map";
      if (!PlausiblePerspective(id, m)) return "implausible perspective on frame " + std::to_string(id);
      (*refined)[id] = m;
    }
    return {};
  }

 private:
  bool Homography() const { return options_.model == MotionModel::kHomography; }

  void Build(ceres::Problem* problem) {
    for (size_t i = 0; i < used_.size(); ++i) {
      if (Kept(i).size() == 0) continue;
      const Edge* e = used_[i];
      FrameParams& s = params_.at(e->src);
      FrameParams& t = params_.at(e->tgt);
      auto* cost = new ceres::DynamicAutoDiffCostFunction<EdgeTransferCost, 8>(
          new EdgeTransferCost(Kept(i), options_.huber_px, lens_));
      cost->AddParameterBlock(6);
      cost->AddParameterBlock(2);
      cost->AddParameterBlock(6);
      cost->AddParameterBlock(2);
      std::vector<double*> blocks{s.affine.data(), s.perspective.data(), t.affine.data(), t.perspective.data()};
      if (lens_ != nullptr) {
        cost->AddParameterBlock(3);
        blocks.push_back(lens_->undistortion.data());
      }
      cost->SetNumResiduals(static_cast<int>(2 * Kept(i).size()));
      problem->AddResidualBlock(cost, nullptr, blocks);
    }
    for (auto& [id, p] : params_) AddFramePriors(id, &p, problem);
    if (lens_ != nullptr && problem->HasParameterBlock(lens_->undistortion.data())) AddLensPrior(problem);
  }

  LensPrior MakeLensPrior() const {
    const PinholeCamera& c = lens_->prepared;
    const double hd_px = 0.5 * std::hypot(c.width, c.height);
    const double hd_rho = hd_px / c.focal_px;
    return {lens_->prior_weight, hd_rho * hd_rho, hd_px, lens_start_};
  }

  void AddLensPrior(ceres::Problem* problem) {
    problem->AddResidualBlock(new ceres::AutoDiffCostFunction<LensPrior, 3, 3>(new LensPrior(MakeLensPrior())), nullptr,
                              lens_->undistortion.data());
  }

  Vec2 Ideal(const Vec2& p) const { return lens_ != nullptr ? lens_->Ideal(p) : p; }

  // The preconditioner of the iterative solve: a maximum spanning tree of the edges (by their kept points), whose
  // normal equations a sparse Cholesky factors without fill-in (a tree's leaves go first), so its memory is linear in
  // the frames; it carries the mosaic's long, soft modes (a bend across the flight) that a block-diagonal
  // preconditioner leaves to hundreds of steps. Kruskal over the edges, heaviest first.
  std::vector<bool> SpanningTree() const {
    std::vector<size_t> kept(used_.size());
    for (size_t i = 0; i < kept.size(); ++i) kept[i] = Kept(i).size();
    return SpanningTreeBy(kept);
  }
  // The same over `points` per edge.
  std::vector<bool> SpanningTreeBy(const std::vector<size_t>& points) const {
    std::vector<size_t> order(used_.size());
    for (size_t i = 0; i < order.size(); ++i) order[i] = i;
    std::stable_sort(order.begin(), order.end(), [&](size_t a, size_t b) { return points[a] > points[b]; });
    UnionFind sets;  // over the frames, by a dense index of their own
    std::unordered_map<int, int> index;
    const auto element = [&](int id) {
      const auto [it, added] = index.try_emplace(id, 0);
      if (added) it->second = sets.Add();
      return it->second;
    };
    std::vector<bool> in_tree(used_.size(), false);
    for (size_t i : order) {
      if (points[i] < kTreeMinPoints) continue;
      const int a = sets.Find(element(used_[i]->src));
      const int b = sets.Find(element(used_[i]->tgt));
      if (a == b) continue;
      sets.Unite(a, b);
      in_tree[i] = true;
    }
    return in_tree;
  }

  // Which blocks stay constant, and the nadir and rigidity priors of a frame that moves.
  FramePriors PriorsOf(int id, const FrameParams& p) const {
    FramePriors priors;
    const bool is_variable = variable_.count(id) != 0;
    const bool is_anchor = id == anchor_;
    const auto hd_it = half_diagonal_.find(id);
    const double hd = hd_it != half_diagonal_.end() ? hd_it->second : 1.0;
    priors.affine_constant = !is_variable || is_anchor;
    priors.perspective_constant = !Homography() || !(is_variable || is_anchor);
    if (!priors.perspective_constant && options_.nadir_weight > 0)
      priors.nadir.emplace(options_.nadir_weight * hd * hd);
    if (is_variable && !is_anchor && options_.rigidity_weight > 0) {
      const auto c = frame_centre_.find(id);
      const double scale = c != frame_centre_.end() ? LocalScale(FromParams(p), c->second) : 0.0;
      if (scale > 0 && c != frame_centre_.end())
        priors.rigidity.emplace(options_.rigidity_weight * hd / scale, c->second);
    }
    return priors;
  }

  void AddFramePriors(int id, FrameParams* p, ceres::Problem* problem) const {
    const FramePriors priors = PriorsOf(id, *p);
    if (priors.affine_constant) problem->SetParameterBlockConstant(p->affine.data());
    if (priors.perspective_constant) problem->SetParameterBlockConstant(p->perspective.data());
    if (priors.nadir)
      problem->AddResidualBlock(new ceres::AutoDiffCostFunction<NadirPrior, 2, 2>(new NadirPrior(*priors.nadir)),
                                nullptr, p->perspective.data());
    if (priors.rigidity)
      problem->AddResidualBlock(
          new ceres::AutoDiffCostFunction<RigidityPrior, 2, 6, 2>(new RigidityPrior(*priors.rigidity)), nullptr,
          p->affine.data(), p->perspective.data());
  }

  // A drone camera is near nadir: the projective denominator may not vary much over the frame. A frame whose matches
  // allowed a wild perspective (few, clustered points) would be drawn folded or smeared.
  bool PlausiblePerspective(int id, const Mat3& m) const {
    const auto box = extent_.find(id);
    if (!Homography() || box == extent_.end()) return true;
    double lo = 1e300;
    double hi = -1e300;
    for (const auto corner : {Eigen::AlignedBox2d::BottomLeft, Eigen::AlignedBox2d::BottomRight,
                              Eigen::AlignedBox2d::TopLeft, Eigen::AlignedBox2d::TopRight}) {
      const Vec2 c = box->second.corner(corner);
      const double w = m(2, 0) * c.x() + m(2, 1) * c.y() + 1.0;
      lo = std::min(lo, w);
      hi = std::max(hi, w);
    }
    return !(!(lo > 0) || hi / lo > options_.max_perspective_ratio);
  }

  const std::unordered_set<int>& variable_;
  const int anchor_;
  const std::unordered_map<int, double>& half_diagonal_;
  const RefineOptions& options_;
  LensRefine* lens_;
  std::array<double, 3> lens_start_ = lens_ != nullptr ? lens_->undistortion : std::array<double, 3>{};
  EdgePointSource* points_;  // borrowed; null: the edges' own
  std::vector<const Edge*> used_;
  std::vector<uint32_t> full_;  // each used edge's correspondences
  // The correspondences each used edge contributes, copied into one block: edge i's are pairs kept_begin_[i] to
  // kept_begin_[i + 1] (16 bytes a pair and 4 an edge; the solvers point into it).
  std::vector<Vec2f> kept_pairs_;
  std::vector<uint32_t> kept_begin_;
  // Ordered map: the parameter blocks' addresses must stay put while the problem holds them.
  std::map<int, FrameParams> params_;
  std::unordered_map<int, Vec2> frame_centre_;
  std::unordered_map<int, Eigen::AlignedBox2d> extent_;
};

// A factorisation (Ceres) up to max_frames_per_solve variable frames; beyond, SolveTreeLm: conjugate gradients on the
// normal equations preconditioned by a spanning tree of the edges, no Jacobian held, no fill-in, memory linear in the
// frames and edges.
ceres::Solver::Options SolverOptions(const RefineOptions& options) {
  ceres::Solver::Options solver_options;
  solver_options.linear_solver_type = ceres::SPARSE_NORMAL_CHOLESKY;
  solver_options.function_tolerance = 1e-9;
  solver_options.parameter_tolerance = 1e-10;
  solver_options.max_num_iterations = options.max_iterations;
  solver_options.num_threads = options.threads;
  if (options.max_seconds > 0) solver_options.max_solver_time_in_seconds = options.max_seconds;
  solver_options.logging_type = ceres::SILENT;
  return solver_options;
}

TreeLmOptions IterativeOptions(const RefineOptions& options) {
  TreeLmOptions lm;
  lm.max_iterations = options.max_iterations;
  lm.max_linear_iterations = options.max_linear_iterations;
  // Truncated steps lower the cost a little on every iteration: a 1e-9 tolerance would run them to the cap
  // (sim_long, 567 frames: 64 iterations at 1e-9, 22 at 1e-6, the same error against the truth).
  lm.function_tolerance = 1e-6;
  lm.parameter_tolerance = 1e-10;
  lm.max_seconds = options.max_seconds;
  return lm;
}

}  // namespace

Vec2 LensRefine::Ideal(const Vec2& prepared_point) const {
  const Vec2 c(prepared.cx, prepared.cy);
  const Vec2 d = prepared.DistortPixel(prepared_point) - c;
  const double rho2 = d.squaredNorm() / (prepared.focal_px * prepared.focal_px);
  return c + (1.0 + rho2 * (undistortion[0] + rho2 * (undistortion[1] + rho2 * undistortion[2]))) * d;
}

TransferStats TransferErrors(const std::vector<const Edge*>& edges,
                             const std::unordered_map<int, Mat3>& mosaic_from_frame, bool holdout, double max_px,
                             const LensRefine* lens, EdgePointSource* source) {
  TransferStats s;
  LogHistogram histogram = ResidualHistogram();  // the median in fixed memory, the sum in double as the errors come
  double sq = 0.0;
  for (const Edge* e : edges) {
    const auto ts = mosaic_from_frame.find(e->src);
    const auto tt = mosaic_from_frame.find(e->tgt);
    if (ts == mosaic_from_frame.end() || tt == mosaic_from_frame.end()) continue;
    const Mat3 tgt_from_src = tt->second.inverse() * ts->second;
    const EdgePoints& points = PointsOf(*e, source);
    const size_t n = holdout ? points.holdout_size() : points.size();
    for (size_t k = 0; k < n; ++k) {
      const Vec2 p = (holdout ? points.holdout_src(k) : points.src(k)).cast<double>();
      const Vec2 q = (holdout ? points.holdout_tgt(k) : points.tgt(k)).cast<double>();
      const double d = lens != nullptr ? (Apply(tgt_from_src, lens->Ideal(p)) - lens->Ideal(q)).norm()
                                       : (Apply(tgt_from_src, p) - q).norm();
      if (max_px > 0 && !(d <= max_px)) continue;  // a NaN is no inlier
      histogram.Add(d);
      sq += d * d;
    }
  }
  s.count = histogram.count();
  if (s.count == 0) return s;
  s.rms = std::sqrt(sq / static_cast<double>(s.count));
  s.median = histogram.Median();
  return s;
}

RefineResult RefineGlobal(const std::vector<const Edge*>& edges, const std::unordered_set<int>& variable, int anchor,
                          const std::unordered_map<int, double>& half_diagonal, const RefineOptions& options,
                          std::unordered_map<int, Mat3>* mosaic_from_frame, LensRefine* lens, EdgePointSource* points) {
  RefineResult result;
  StageTimer timer;
  auto& T = *mosaic_from_frame;
  RefineProblem refine(edges, variable, anchor, half_diagonal, options, T, lens, points);
  const TransferStats before = TransferErrors(refine.used(), T, false, 0.0, lens, points);
  result.initial_rms_px = before.rms;
  result.num_residuals = before.count;
  const auto max_correspondences = static_cast<size_t>(options.max_correspondences);
  const size_t stride =
      before.count > max_correspondences ? (before.count + max_correspondences - 1) / max_correspondences : 1;
  const size_t num_variables = refine.NumVariables();
  const bool iterative = num_variables > static_cast<size_t>(options.max_frames_per_solve);
  result.num_used = refine.Select(stride, iterative, T);
  if (refine.empty()) {
    result.ok = true;
    return result;
  }
  result.num_variables = num_variables;
  result.iterative = iterative;
  const ceres::Solver::Options solver_options = SolverOptions(options);
  const TreeLmOptions lm_options = IterativeOptions(options);
  const auto solve = [&](bool log) {
    return result.iterative ? refine.SolveIterative(lm_options, &result.iterations, log)
                            : refine.Solve(solver_options, &result.iterations, log);
  };
  result.failure = solve(/*log=*/true);
  if (!result.failure.empty()) return result;
  if (options.outlier_px > 0) {
    result.outliers = refine.DropOutliers();
    if (result.outliers > 0) {
      result.failure = solve(/*log=*/false);
      if (!result.failure.empty()) return result;
    }
  }
  std::unordered_map<int, Mat3> refined;
  result.failure = refine.Refined(&refined);
  if (!result.failure.empty()) return result;
  // Ceres only returns a step that lowered the robust cost; the plain statistics are for the report.
  std::unordered_map<int, Mat3> trial = T;
  for (const auto& [id, m] : refined) trial[id] = m;
  const TransferStats after = TransferErrors(refine.used(), trial, false, 0.0, lens, points);
  const TransferStats inliers = TransferErrors(refine.used(), trial, false, options.outlier_px, lens, points);
  for (const auto& [id, m] : refined) T[id] = m;
  result.final_all_rms_px = after.rms;
  result.final_rms_px = options.outlier_px > 0 ? inliers.rms : after.rms;
  result.final_median_px = options.outlier_px > 0 ? inliers.median : after.median;
  result.final_inliers = options.outlier_px > 0 ? inliers.count : after.count;
  result.seconds = timer.ElapsedMs() / 1000.0;
  result.ok = true;
  return result;
}

}  // namespace uavm
