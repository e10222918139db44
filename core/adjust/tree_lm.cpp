#include "core/adjust/tree_lm.h"

#include <Eigen/Cholesky>
#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <utility>

#include "core/util/clock.h"

namespace uavm {

bool TreeLmOptions::Check(std::string* why) const {
  if (max_iterations < 1 || max_linear_iterations < 1 || !(linear_tolerance > 0 && linear_tolerance < 1) ||
      !(function_tolerance >= 0) || !(parameter_tolerance >= 0) || !(gradient_tolerance >= 0) || !(max_seconds >= 0)) {
    if (why != nullptr)
      *why =
          "tree LM: max_iterations >= 1, max_linear_iterations >= 1, linear_tolerance in (0,1), tolerances >= 0, "
          "max_seconds >= 0";
    return false;
  }
  return true;
}

namespace {

using Block = Eigen::Matrix<double, kFrameParams, kFrameParams>;
// An edge's coupling block, rounded to float: the edges' blocks are most of the solver's memory (about five edges a
// frame). The rounding (6e-8 of each entry) only makes each step less exact, as the conjugate gradients already do;
// the gradient and the cost, which decide where the iteration stops, stay in double, and the conjugate gradients stop
// where the rounded system is not positive definite.
using CouplingBlock = Eigen::Matrix<float, kFrameParams, kFrameParams>;
using SharedBlock = Eigen::Matrix<double, kSharedParams, kFrameParams>;
using SharedSquare = Eigen::Matrix<double, kSharedParams, kSharedParams>;
using Vec = Eigen::VectorXd;
using RowMajorJacobian = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
using FrameVector = Eigen::Matrix<double, kFrameParams, 1>;

// A symmetric block kept as its lower triangle, column after column: 36 doubles where the full block took 64. The
// frames' blocks and their tree factors are held for every frame, a third of the solver's memory before.
class PackedLower {
 public:
  void SetZero() { entries_.fill(0.0); }
  double& operator()(int row, int col) { return entries_[Index(row, col)]; }
  [[nodiscard]] double operator()(int row, int col) const { return entries_[Index(row, col)]; }
  // Adds (subtracts) the lower triangle of a symmetric block.
  void AddLower(const Block& b, double sign = 1.0) {
    for (int c = 0; c < kFrameParams; ++c)
      for (int r = c; r < kFrameParams; ++r) entries_[Index(r, c)] += sign * b(r, c);
  }
  // The block with its upper triangle mirrored (symmetric) or zero (a triangular factor).
  [[nodiscard]] Block Symmetric() const { return Unpacked(true); }
  [[nodiscard]] Block Lower() const { return Unpacked(false); }
  void StoreLower(const Block& b) {
    for (int c = 0; c < kFrameParams; ++c)
      for (int r = c; r < kFrameParams; ++r) entries_[Index(r, c)] = b(r, c);
  }
  // y += S v, S the symmetric block, from the packed entries (the conjugate gradients' every step: no unpacking).
  void MultiplyAdd(const FrameVector& v, FrameVector* y) const {
    for (int c = 0; c < kFrameParams; ++c) {
      const double* column = entries_.data() + Index(c, c);
      (*y)(c) += column[0] * v(c);
      for (int r = c + 1; r < kFrameParams; ++r) {
        (*y)(r) += column[r - c] * v(c);
        (*y)(c) += column[r - c] * v(r);
      }
    }
  }
  // (L L^T)^-1 b, L the lower-triangular factor held: forward then backward substitution, column by column.
  [[nodiscard]] FrameVector SolveFactored(FrameVector b) const {
    for (int c = 0; c < kFrameParams; ++c) {
      const double* column = entries_.data() + Index(c, c);
      b(c) /= column[0];
      for (int r = c + 1; r < kFrameParams; ++r) b(r) -= column[r - c] * b(c);
    }
    for (int c = kFrameParams - 1; c >= 0; --c) {
      const double* column = entries_.data() + Index(c, c);
      for (int r = c + 1; r < kFrameParams; ++r) b(c) -= column[r - c] * b(r);
      b(c) /= column[0];
    }
    return b;
  }

 private:
  static int Index(int row, int col) { return col * kFrameParams - col * (col - 1) / 2 + (row - col); }
  [[nodiscard]] Block Unpacked(bool mirror) const {
    Block b = Block::Zero();
    for (int c = 0; c < kFrameParams; ++c)
      for (int r = c; r < kFrameParams; ++r) {
        b(r, c) = entries_[Index(r, c)];
        if (mirror) b(c, r) = b(r, c);
      }
    return b;
  }
  std::array<double, kFrameParams*(kFrameParams + 1) / 2> entries_{};
};

// The LM scaling's clamp (Ceres' min_lm_diagonal and max_lm_diagonal).
constexpr double kMinDiagonal = 1e-6;
constexpr double kMaxDiagonal = 1e32;
// A step is taken when the cost fell by at least this share of what the linear model promised (Ceres' default).
constexpr double kMinRelativeDecrease = 1e-3;
constexpr double kInitialRadius = 1e4;
constexpr double kMaxRadius = 1e16;
constexpr double kMinRadius = 1e-32;

auto FrameSegment(Vec& v, size_t frame) {
  return v.segment<kFrameParams>(static_cast<Eigen::Index>(kFrameParams * frame));
}
auto FrameSegment(const Vec& v, size_t frame) {
  return v.segment<kFrameParams>(static_cast<Eigen::Index>(kFrameParams * frame));
}

// J^T J as blocks, J^T r and the cost at one point; the columns of constant parameters are zero, their diagonal 1.
struct NormalEquations {
  NormalEquations(size_t frames, size_t edges, bool shared)
      : frame(frames), edge(edges), shared_frame(shared ? frames : 0) {}
  std::vector<PackedLower> frame;   // per frame
  std::vector<CouplingBlock> edge;  // per edge: source rows, target columns
  std::vector<SharedBlock> shared_frame;
  SharedSquare shared = SharedSquare::Zero();
  Vec gradient;
  Vec diagonal;  // diag(J^T J), clamped: the LM scaling
  double cost = 0.0;
};

class Evaluator {
 public:
  explicit Evaluator(const FrameGraphTerms& terms) : terms_(terms), n_(terms.NumFrames()) {
    mask_.resize(n_);
    for (size_t f = 0; f < n_; ++f)
      for (int k = 0; k < kFrameParams; ++k) mask_[f](k) = terms.Free(f, k) ? 1.0 : 0.0;
  }

  size_t Size() const { return kFrameParams * n_ + (terms_.HasShared() ? kSharedParams : 0); }

  // The cost at x; with `normal`, the normal equations too.
  double Evaluate(const Vec& x, NormalEquations* normal) {
    const bool shared = terms_.HasShared();
    const double* s = shared ? x.data() + kFrameParams * n_ : nullptr;
    double cost = 0.0;
    if (normal != nullptr) Clear(normal, x.size());
    std::vector<double>* jacobian = normal != nullptr ? &jacobian_ : nullptr;
    for (size_t e = 0; e < terms_.NumEdges(); ++e) {
      const size_t a = terms_.EdgeSrc(e);
      const size_t b = terms_.EdgeTgt(e);
      residuals_.clear();
      jacobian_.clear();
      terms_.Edge(e, x.data() + kFrameParams * a, x.data() + kFrameParams * b, s, &residuals_, jacobian);
      cost += SumOfSquares();
      if (normal != nullptr) AddEdge(e, a, b, shared, normal);
    }
    for (size_t f = 0; f < n_; ++f) {
      residuals_.clear();
      jacobian_.clear();
      terms_.FramePrior(f, x.data() + kFrameParams * f, &residuals_, jacobian);
      cost += SumOfSquares();
      if (normal != nullptr && !residuals_.empty()) AddFramePrior(f, normal);
    }
    if (shared) {
      residuals_.clear();
      jacobian_.clear();
      terms_.SharedPrior(s, &residuals_, jacobian);
      cost += SumOfSquares();
      if (normal != nullptr && !residuals_.empty()) AddSharedPrior(normal);
    }
    if (normal != nullptr) Finish(normal);
    return 0.5 * cost;
  }

 private:
  double SumOfSquares() const {
    double sum = 0.0;
    for (double r : residuals_) sum += r * r;
    return sum;
  }

  void Clear(NormalEquations* normal, Eigen::Index size) const {
    for (PackedLower& b : normal->frame) b.SetZero();
    for (SharedBlock& b : normal->shared_frame) b.setZero();
    normal->shared.setZero();
    normal->gradient = Vec::Zero(size);
  }

  void AddEdge(size_t e, size_t a, size_t b, bool shared, NormalEquations* normal) const {
    const auto rows = static_cast<Eigen::Index>(residuals_.size());
    const Eigen::Map<const RowMajorJacobian> jac(jacobian_.data(), rows, kEdgeColumns);
    const Eigen::Map<const Vec> r(residuals_.data(), rows);
    const Eigen::Matrix<double, Eigen::Dynamic, kFrameParams> ja = jac.leftCols<kFrameParams>() * mask_[a].asDiagonal();
    const Eigen::Matrix<double, Eigen::Dynamic, kFrameParams> jb =
        jac.middleCols<kFrameParams>(kFrameParams) * mask_[b].asDiagonal();
    normal->frame[a].AddLower(ja.transpose() * ja);
    normal->frame[b].AddLower(jb.transpose() * jb);
    normal->edge[e] = (ja.transpose() * jb).cast<float>();
    FrameSegment(normal->gradient, a).noalias() += ja.transpose() * r;
    FrameSegment(normal->gradient, b).noalias() += jb.transpose() * r;
    if (!shared) return;
    const Eigen::Matrix<double, Eigen::Dynamic, kSharedParams> jl = jac.rightCols<kSharedParams>();
    normal->shared.noalias() += jl.transpose() * jl;
    normal->shared_frame[a].noalias() += jl.transpose() * ja;
    normal->shared_frame[b].noalias() += jl.transpose() * jb;
    normal->gradient.tail<kSharedParams>().noalias() += jl.transpose() * r;
  }

  void AddFramePrior(size_t f, NormalEquations* normal) const {
    const auto rows = static_cast<Eigen::Index>(residuals_.size());
    const Eigen::Map<const RowMajorJacobian> jac(jacobian_.data(), rows, kFrameParams);
    const Eigen::Matrix<double, Eigen::Dynamic, kFrameParams> j = jac * mask_[f].asDiagonal();
    normal->frame[f].AddLower(j.transpose() * j);
    FrameSegment(normal->gradient, f).noalias() += j.transpose() * Eigen::Map<const Vec>(residuals_.data(), rows);
  }

  void AddSharedPrior(NormalEquations* normal) const {
    const auto rows = static_cast<Eigen::Index>(residuals_.size());
    const Eigen::Map<const RowMajorJacobian> jac(jacobian_.data(), rows, kSharedParams);
    normal->shared.noalias() += jac.transpose() * jac;
    normal->gradient.tail<kSharedParams>().noalias() +=
        jac.transpose() * Eigen::Map<const Vec>(residuals_.data(), rows);
  }

  // Constant parameters: a unit diagonal (their rows and columns are zero), so every step leaves them.
  void Finish(NormalEquations* normal) const {
    normal->diagonal.resize(normal->gradient.size());
    for (size_t f = 0; f < n_; ++f)
      for (int k = 0; k < kFrameParams; ++k) {
        if (mask_[f](k) == 0.0) normal->frame[f](k, k) = 1.0;
        normal->diagonal(static_cast<Eigen::Index>(kFrameParams * f) + k) = normal->frame[f](k, k);
      }
    if (terms_.HasShared()) normal->diagonal.tail<kSharedParams>() = normal->shared.diagonal();
    normal->diagonal = normal->diagonal.cwiseMax(kMinDiagonal).cwiseMin(kMaxDiagonal);
  }

  const FrameGraphTerms& terms_;
  const size_t n_;
  std::vector<FrameVector> mask_;
  std::vector<double> residuals_;  // one term's, reused
  std::vector<double> jacobian_;
};

// y = (J^T J + mu D) v.
void Multiply(const FrameGraphTerms& terms, const NormalEquations& h, double mu, const Vec& v, Vec* y) {
  *y = (mu * h.diagonal.array() * v.array()).matrix();
  for (size_t f = 0; f < h.frame.size(); ++f) {
    FrameVector product = FrameVector::Zero();
    h.frame[f].MultiplyAdd(FrameSegment(v, f), &product);
    FrameSegment(*y, f) += product;
  }
  for (size_t e = 0; e < h.edge.size(); ++e) {
    const size_t a = terms.EdgeSrc(e);
    const size_t b = terms.EdgeTgt(e);
    const Block coupling = h.edge[e].cast<double>();
    FrameSegment(*y, a).noalias() += coupling * FrameSegment(v, b);
    FrameSegment(*y, b).noalias() += coupling.transpose() * FrameSegment(v, a);
  }
  if (h.shared_frame.empty()) return;
  y->tail<kSharedParams>().noalias() += h.shared * v.tail<kSharedParams>();
  for (size_t f = 0; f < h.shared_frame.size(); ++f) {
    y->tail<kSharedParams>().noalias() += h.shared_frame[f] * FrameSegment(v, f);
    FrameSegment(*y, f).noalias() += h.shared_frame[f].transpose() * v.tail<kSharedParams>();
  }
}

// The preconditioner: the normal equations of the tree's edges alone (every frame's block, the tree's couplings),
// factored exactly by eliminating leaves first: each frame's Schur complement is 8x8 and nothing fills in. It carries
// the long, soft modes of a mosaic (a bend across the flight) that a block-diagonal preconditioner leaves to hundreds
// of steps. The shared block is preconditioned by its own block.
class TreePreconditioner {
 public:
  explicit TreePreconditioner(const FrameGraphTerms& terms) : terms_(terms) {
    const size_t n = terms.NumFrames();
    std::vector<std::vector<std::pair<size_t, size_t>>> adjacent(n);  // (frame, edge)
    for (size_t e = 0; e < terms.NumEdges(); ++e) {
      if (!terms.InTree(e)) continue;
      adjacent[terms.EdgeSrc(e)].emplace_back(terms.EdgeTgt(e), e);
      adjacent[terms.EdgeTgt(e)].emplace_back(terms.EdgeSrc(e), e);
    }
    parent_.assign(n, kRoot);
    parent_edge_.assign(n, 0);
    std::vector<bool> seen(n, false);
    order_.reserve(n);
    for (size_t root = 0; root < n; ++root) {
      if (seen[root]) continue;
      seen[root] = true;
      order_.push_back(root);
      for (size_t next = order_.size() - 1; next < order_.size(); ++next)
        for (const auto& [other, e] : adjacent[order_[next]])
          if (!seen[other]) {
            seen[other] = true;
            parent_[other] = order_[next];
            parent_edge_[other] = e;
            order_.push_back(other);
          }
    }
    factor_.resize(n);
  }

  void Factor(const NormalEquations& h, double mu) {
    // Each frame's Schur complement is built and factored in the one packed block it keeps (no second copy per frame).
    for (size_t f = 0; f < factor_.size(); ++f) {
      factor_[f] = h.frame[f];
      for (int k = 0; k < kFrameParams; ++k) factor_[f](k, k) += mu * FrameSegment(h.diagonal, f)(k);
    }
    for (auto it = order_.rbegin(); it != order_.rend(); ++it) {  // children before their parents
      const size_t f = *it;
      Block schur = factor_[f].Symmetric();
      const FrameVector diagonal = schur.diagonal();
      Eigen::LLT<Eigen::Ref<Block>> in_place(schur);
      if (in_place.info() != Eigen::Success) {  // not positive definite: its diagonal alone
        schur.setZero();
        schur.diagonal() = diagonal.cwiseMax(kMinDiagonal).cwiseSqrt();
      }
      factor_[f].StoreLower(schur);
      if (parent_[f] == kRoot) continue;
      const Block coupling = Coupling(h, f);
      factor_[parent_[f]].AddLower(coupling.transpose() * Solve(f, coupling), -1.0);
    }
    if (!h.shared_frame.empty()) {
      SharedSquare s = h.shared;
      s.diagonal() += mu * h.diagonal.tail<kSharedParams>();
      shared_.compute(s);
    }
  }

  void Apply(const NormalEquations& h, const Vec& r, Vec* z) const {
    Vec& y = forward_;
    y = r;
    for (auto it = order_.rbegin(); it != order_.rend(); ++it) {
      const size_t f = *it;
      if (parent_[f] == kRoot) continue;
      FrameSegment(y, parent_[f]).noalias() -= Coupling(h, f).transpose() * Solve(f, FrameSegment(y, f));
    }
    z->resize(r.size());
    for (const size_t f : order_) {
      if (parent_[f] == kRoot) {
        FrameSegment(*z, f) = Solve(f, FrameSegment(y, f));
      } else {
        const FrameVector rhs = FrameSegment(y, f) - Coupling(h, f) * FrameSegment(*z, parent_[f]);
        FrameSegment(*z, f) = Solve(f, rhs);
      }
    }
    if (!h.shared_frame.empty()) z->tail<kSharedParams>() = shared_.solve(r.tail<kSharedParams>());
  }

 private:
  static constexpr size_t kRoot = SIZE_MAX;

  // The block coupling frame f (rows) to its parent (columns).
  Block Coupling(const NormalEquations& h, size_t f) const {
    const size_t e = parent_edge_[f];
    const Block coupling = h.edge[e].cast<double>();
    return terms_.EdgeSrc(e) == f ? coupling : Block(coupling.transpose());
  }

  // (L L^T)^-1 b with frame f's factor L (the lower triangle of its block).
  template <typename Rhs>
  Eigen::Matrix<double, kFrameParams, Rhs::ColsAtCompileTime> Solve(size_t f, const Rhs& b) const {
    if constexpr (Rhs::ColsAtCompileTime == 1) {
      return factor_[f].SolveFactored(b);  // every conjugate-gradient step: in place
    } else {
      const Block factor = factor_[f].Lower();
      const auto lower = factor.triangularView<Eigen::Lower>();
      return lower.transpose().solve(lower.solve(b));
    }
  }

  const FrameGraphTerms& terms_;
  std::vector<size_t> order_;  // breadth first over each tree of the forest: parents before children
  std::vector<size_t> parent_;
  std::vector<size_t> parent_edge_;
  // Per frame: its Schur complement's Cholesky factor L.
  std::vector<PackedLower> factor_;
  Eigen::LDLT<SharedSquare> shared_;
  // Apply's forward pass, kept from one conjugate-gradient step to the next: a preconditioner serves one thread.
  mutable Vec forward_;
};

// Preconditioned conjugate gradients on (J^T J + mu D) x = b from x = 0; returns the steps taken.
int ConjugateGradients(const FrameGraphTerms& terms, const NormalEquations& h, double mu,
                       const TreePreconditioner& preconditioner, const TreeLmOptions& options, const Vec& b, Vec* x) {
  *x = Vec::Zero(b.size());
  Vec r = b;
  Vec z;
  Vec q;
  preconditioner.Apply(h, r, &z);
  Vec p = z;
  double rz = r.dot(z);
  const double rz0 = rz;
  int k = 0;
  while (k < options.max_linear_iterations && rz > 0) {
    ++k;
    Multiply(terms, h, mu, p, &q);
    const double pq = p.dot(q);
    if (!(pq > 0)) break;
    const double alpha = rz / pq;
    *x += alpha * p;
    r -= alpha * q;
    preconditioner.Apply(h, r, &z);
    const double rz_next = r.dot(z);
    if (!(rz_next > options.linear_tolerance * options.linear_tolerance * rz0)) break;
    p = z + (rz_next / rz) * p;
    rz = rz_next;
  }
  return k;
}

}  // namespace

TreeLmSummary SolveTreeLm(const FrameGraphTerms& terms, const TreeLmOptions& options,
                          std::vector<FrameParamVector>* frames, SharedParamVector* shared) {
  TreeLmSummary summary;
  if (!options.Check(&summary.message)) return summary;
  const size_t n = terms.NumFrames();
  Evaluator evaluator(terms);
  Vec x(static_cast<Eigen::Index>(evaluator.Size()));
  for (size_t f = 0; f < n; ++f) FrameSegment(x, f) = Eigen::Map<const FrameVector>((*frames)[f].data());
  if (terms.HasShared()) x.tail<kSharedParams>() = Eigen::Map<const Eigen::Vector3d>(shared->data());
  NormalEquations h(n, terms.NumEdges(), terms.HasShared());
  double cost = evaluator.Evaluate(x, &h);
  summary.initial_cost = cost;
  if (!std::isfinite(cost)) {
    summary.message = "the initial cost is not finite";
    return summary;
  }
  TreePreconditioner preconditioner(terms);
  StageTimer timer;
  double radius = kInitialRadius;
  double decrease_factor = 2.0;
  Vec step;
  Vec h_step;
  summary.message = "the iteration limit";
  while (summary.iterations < options.max_iterations) {
    if (h.gradient.lpNorm<Eigen::Infinity>() <= options.gradient_tolerance) {
      summary.message = "the gradient tolerance";
      break;
    }
    if (options.max_seconds > 0 && timer.ElapsedMs() > 1000.0 * options.max_seconds) {
      summary.message = "the time limit";
      break;
    }
    ++summary.iterations;
    const double mu = 1.0 / radius;
    preconditioner.Factor(h, mu);
    summary.linear_iterations += ConjugateGradients(terms, h, mu, preconditioner, options, -h.gradient, &step);
    if (step.norm() <= options.parameter_tolerance * (x.norm() + options.parameter_tolerance)) {
      summary.message = "the parameter tolerance";
      break;
    }
    Multiply(terms, h, 0.0, step, &h_step);
    const double model_decrease = -(h.gradient.dot(step) + 0.5 * step.dot(h_step));
    const Vec trial = x + step;
    const double trial_cost = evaluator.Evaluate(trial, nullptr);
    const double rho = (cost - trial_cost) / model_decrease;
    if (std::isfinite(trial_cost) && model_decrease > 0 && rho > kMinRelativeDecrease) {
      const bool converged = cost - trial_cost <= options.function_tolerance * cost;
      x = trial;
      radius = std::min(kMaxRadius, radius / std::max(1.0 / 3.0, 1.0 - std::pow(2.0 * rho - 1.0, 3)));
      decrease_factor = 2.0;
      cost = evaluator.Evaluate(x, &h);
      if (converged) {
        summary.message = "the function tolerance";
        break;
      }
    } else {
      radius /= decrease_factor;
      decrease_factor *= 2.0;
      if (radius < kMinRadius) {
        summary.message = "the trust region's minimum";
        break;
      }
    }
  }
  for (size_t f = 0; f < n; ++f) Eigen::Map<FrameVector>((*frames)[f].data()) = FrameSegment(x, f);
  if (terms.HasShared()) Eigen::Map<Eigen::Vector3d>(shared->data()) = x.tail<kSharedParams>();
  summary.final_cost = cost;
  summary.usable = std::isfinite(cost);
  return summary;
}

}  // namespace uavm
