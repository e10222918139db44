#include "core/adjust/affine_adjuster.h"

#include <Eigen/Cholesky>  // LDLT of the 3x3 blocks D
#include <Eigen/Core>
#include <Eigen/Sparse>
#include <Eigen/SparseCholesky>
#include <algorithm>
#include <cmath>
#include <string>
#include <unordered_map>
#include <utility>
#include <vector>

#include "core/util/stats.h"

namespace uavm {

bool AdjustOptions::Check(std::string* why) const {
  if (!(rigidity_weight >= 0) || !(relative_linear_weight >= 0) || !(huber_px > 0) || robust_iterations < 0 ||
      direct_max_frames < 0 || !(iterative_tolerance > 0 && iterative_tolerance < 1) || max_iterative_steps < 1) {
    if (why != nullptr)
      *why =
          "adjust: weights must be >= 0, huber_px > 0, robust_iterations >= 0, direct_max_frames >= 0, "
          "iterative_tolerance in (0, 1), max_iterative_steps >= 1";
    return false;
  }
  return true;
}

namespace {

// Parameter layout of one frame: a00 a01 a02 a10 a11 a12.
constexpr int kDof = 6;
using Block = Eigen::Matrix<double, kDof, kDof>;
using Vec6 = Eigen::Matrix<double, kDof, 1>;

// The variable frames' ids, ascending: a frame's variable index (column / kDof) is its position. A sorted list, not a
// hash map: at the end of a long flight every frame is variable, and a map's node per frame was the solve's own.
using ColumnOf = std::vector<int>;

// The normal equations in blocks: one on the diagonal per variable frame, one off the diagonal per edge between two
// variable frames (an edge's correspondence and relative-linear terms couple only its two frames). Every term but the
// rigidity acts alike on the two rows of the maps, so an off-diagonal block is I2 (x) B with B 3x3, and a diagonal
// block is I2 (x) D plus the rigidity's coupling of the two rows (one weight, see AddFramePriors): 80 bytes per edge
// (B and its frames) and 128 per frame (D, the weight, the right-hand side), whatever the points. Neither the Jacobian
// (a row per point) nor a 6x6 block is held.
struct BlockSystem {
  std::vector<Eigen::Matrix3d> diagonal;  // D: the diagonal block is I2 (x) D + rigidity_coupling * C
  std::vector<double> rigidity_coupling;  // w = (rigidity_weight * half-diagonal)^2: C couples a00-a11 and a01-a10
  std::vector<Vec6, Eigen::aligned_allocator<Vec6>> rhs;
  std::vector<std::pair<int, int>> pairs;     // (row frame, column frame) of each off-diagonal block: x_row, x_col
  std::vector<Eigen::Matrix3d> off_diagonal;  // B: the block is I2 (x) B

  explicit BlockSystem(size_t frames)
      : diagonal(frames, Eigen::Matrix3d::Zero()), rigidity_coupling(frames, 0.0), rhs(frames, Vec6::Zero()) {}

  // Frame i's 6x6 diagonal block, written out (for the direct solve's matrix).
  [[nodiscard]] Block FullDiagonal(size_t i) const {
    Block d = Block::Zero();
    d.block<3, 3>(0, 0) = diagonal[i];
    d.block<3, 3>(3, 3) = diagonal[i];
    d(0, 4) = d(4, 0) = -rigidity_coupling[i];
    d(1, 3) = d(3, 1) = rigidity_coupling[i];
    return d;
  }

  // y = N x, with N the symmetric matrix of the blocks.
  void Multiply(const Eigen::VectorXd& x, Eigen::VectorXd* y) const {
    y->setZero(x.size());
    for (size_t i = 0; i < diagonal.size(); ++i) {
      const long a = static_cast<long>(i) * kDof;
      y->segment<3>(a).noalias() += diagonal[i] * x.segment<3>(a);
      y->segment<3>(a + 3).noalias() += diagonal[i] * x.segment<3>(a + 3);
      const double w = rigidity_coupling[i];
      (*y)(a) -= w * x(a + 4);
      (*y)(a + 4) -= w * x(a);
      (*y)(a + 1) += w * x(a + 3);
      (*y)(a + 3) += w * x(a + 1);
    }
    for (size_t k = 0; k < pairs.size(); ++k) {
      const long a = static_cast<long>(pairs[k].first) * kDof;
      const long b = static_cast<long>(pairs[k].second) * kDof;
      for (long r = 0; r < kDof; r += 3) {
        y->segment<3>(a + r).noalias() += off_diagonal[k] * x.segment<3>(b + r);
        y->segment<3>(b + r).noalias() += off_diagonal[k].transpose() * x.segment<3>(a + r);
      }
    }
  }
};

double HalfDiagonal(const std::unordered_map<int, double>& half_diagonal, int id) {
  const auto hd = half_diagonal.find(id);
  return hd != half_diagonal.end() ? hd->second : 1.0;
}

int VariableIndex(const ColumnOf& column, int id) {
  const auto it = std::lower_bound(column.begin(), column.end(), id);
  return it != column.end() && *it == id ? static_cast<int>(it - column.begin()) : -1;
}

// One edge's share of the normal equations: its frames' diagonal blocks I2 (x) ss and I2 (x) tt, their right-hand
// sides, and their coupling I2 (x) st.
struct EdgeBlocks {
  Eigen::Matrix3d ss = Eigen::Matrix3d::Zero(), tt = Eigen::Matrix3d::Zero();
  Eigen::Matrix3d st = Eigen::Matrix3d::Zero();
  Vec6 bs = Vec6::Zero(), bt = Vec6::Zero();
};

// Relative linear part: L_src - L_tgt * R = 0 with R the edge's measured linear part, as rows of the same edge. Row
// (r, c): scale * (a_s(r, c) - sum_k R(k, c) a_t(r, k)) = 0; a fixed side (src_fixed, tgt_fixed) moves to the right.
void AddRelativeLinear(const Edge& e, const Mat3& Ts, const Mat3& Tt, bool src_fixed, bool tgt_fixed, double scale,
                       EdgeBlocks* blocks) {
  for (int r = 0; r < 2; ++r)
    for (int c = 0; c < 2; ++c) {
      Vec6 js = Vec6::Zero(), jt = Vec6::Zero();
      js(3 * r + c) = scale;
      for (int k = 0; k < 2; ++k) jt(3 * r + k) = -scale * e.tgt_from_src(k, c);
      // The fixed side's value moves to the right-hand side: b = -(J_fixed x_fixed).
      double b = 0.0;
      if (src_fixed) b -= scale * Ts(r, c);
      if (tgt_fixed)
        for (int k = 0; k < 2; ++k) b -= jt(3 * r + k) * Tt(r, k);
      // js * js^T, jt * jt^T and js * jt^T: rows 3r + c, columns 3r + k, the same for both r.
      if (r == 0) {
        blocks->ss += js.head<3>() * js.head<3>().transpose();
        blocks->tt += jt.head<3>() * jt.head<3>().transpose();
        for (int k = 0; k < 2; ++k) blocks->st(c, k) += js(c) * jt(k);
      }
      blocks->bs += js * b;
      blocks->bt += jt * b;
    }
}

// A correspondence's Huber weight at the maps the previous pass solved (the square root of the IRLS weight, since rows
// are scaled, not squared). Computed as each pass adds the edge, not kept between passes: it was the only state per
// correspondence, and an edge read back from edges.bin gets the weights of the very points it is read with.
double HuberWeight(const Mat3& Ts, const Mat3& Tt, const Vec2f& p, const Vec2f& q, double huber_px) {
  const double r = (Apply(Ts, p.cast<double>()) - Apply(Tt, q.cast<double>())).norm();
  return static_cast<double>(static_cast<float>(r <= huber_px ? 1.0 : std::sqrt(huber_px / r)));
}

// Correspondence rows T_src p - T_tgt q = 0: per edge, the weighted sums S_pp, S_pq, S_qq of the homogeneous points
// give its blocks (the same for both coordinate rows). A fixed side moves to the right-hand side. `huber_px` 0: the
// first pass, unweighted.
void AddEdge(const Edge& e, const EdgePoints& points, const ColumnOf& column, const std::unordered_map<int, Mat3>& T,
             const std::unordered_map<int, double>& half_diagonal, const AdjustOptions& options, double huber_px,
             BlockSystem* sys) {
  const Mat3& Ts = T.at(e.src);
  const Mat3& Tt = T.at(e.tgt);
  Eigen::Matrix3d Spp = Eigen::Matrix3d::Zero();
  Eigen::Matrix3d Spq = Eigen::Matrix3d::Zero();
  Eigen::Matrix3d Sqq = Eigen::Matrix3d::Zero();
  for (size_t k = 0; k < points.size(); ++k) {
    const double w = huber_px > 0 ? HuberWeight(Ts, Tt, points.src(k), points.tgt(k), huber_px) : 1.0;
    const Eigen::Vector3d p(points.src(k).x(), points.src(k).y(), 1.0);
    const Eigen::Vector3d q(points.tgt(k).x(), points.tgt(k).y(), 1.0);
    const double w2 = w * w;
    Spp.noalias() += w2 * p * p.transpose();
    Spq.noalias() += w2 * p * q.transpose();
    Sqq.noalias() += w2 * q * q.transpose();
  }
  const int s = VariableIndex(column, e.src);
  const int t = VariableIndex(column, e.tgt);
  EdgeBlocks blocks;
  blocks.st = -Spq;
  blocks.ss = Spp;
  blocks.tt = Sqq;
  for (int r = 0; r < 2; ++r) {
    if (s < 0) blocks.bt.segment<3>(3 * r) += Spq.transpose() * Ts.row(r).transpose();
    if (t < 0) blocks.bs.segment<3>(3 * r) += Spq * Tt.row(r).transpose();
  }
  if (options.relative_linear_weight > 0)
    AddRelativeLinear(e, Ts, Tt, s < 0, t < 0,
                      options.relative_linear_weight * HalfDiagonal(half_diagonal, s >= 0 ? e.src : e.tgt), &blocks);
  if (s >= 0) {
    sys->diagonal[static_cast<size_t>(s)] += blocks.ss;
    sys->rhs[static_cast<size_t>(s)] += blocks.bs;
  }
  if (t >= 0) {
    sys->diagonal[static_cast<size_t>(t)] += blocks.tt;
    sys->rhs[static_cast<size_t>(t)] += blocks.bt;
  }
  if (s >= 0 && t >= 0) {
    sys->pairs.emplace_back(s, t);
    sys->off_diagonal.push_back(blocks.st);
  }
}

// Rigidity (a00 - a11 = 0 and a01 + a10 = 0, in pixels at the frame's half-diagonal) and a faint pull to the current
// value, which keeps frames without constraints solvable (the gauge of a detached frame). The rigidity rows' squares
// put w = scale^2 on the diagonal of a00, a01, a10 and a11 (D's (0,0) and (1,1), for both rows of the map), -w
// between a00 and a11 and +w between a01 and a10 (BlockSystem::rigidity_coupling).
void AddFramePriors(const ColumnOf& column, const std::unordered_map<int, Mat3>& T,
                    const std::unordered_map<int, double>& half_diagonal, const AdjustOptions& options,
                    BlockSystem* sys) {
  constexpr double kDamping = 1e-6;
  for (size_t index = 0; index < column.size(); ++index) {
    const int id = column[index];
    Eigen::Matrix3d& d = sys->diagonal[index];
    Vec6& b = sys->rhs[index];
    const double scale = options.rigidity_weight * HalfDiagonal(half_diagonal, id);
    const double w = scale > 0 ? scale * scale : 0.0;
    d(0, 0) += w;
    d(1, 1) += w;
    sys->rigidity_coupling[index] = w;
    for (int c = 0; c < 3; ++c) d(c, c) += kDamping * kDamping;
    const Mat3& t = T.at(id);
    for (int r = 0; r < 2; ++r)
      for (int c = 0; c < 3; ++c) b(3 * r + c) += kDamping * kDamping * t(r, c);
  }
}

// Direct: the blocks as one sparse matrix, factored (sparse LDLT). Its fill grows faster than the frames.
std::string SolveDirect(const BlockSystem& sys, Eigen::VectorXd* x) {
  const long n = static_cast<long>(sys.diagonal.size()) * kDof;
  std::vector<Eigen::Triplet<double>> triplets;
  triplets.reserve((sys.diagonal.size() + sys.pairs.size()) * kDof * kDof);  // an edge: 2 x (2 x 9)
  const auto add = [&](long r0, long c0, const auto& b, bool transpose) {
    for (int i = 0; i < b.rows(); ++i)
      for (int j = 0; j < b.cols(); ++j)
        if (const double v = transpose ? b(j, i) : b(i, j); v != 0.0) triplets.emplace_back(r0 + i, c0 + j, v);
  };
  for (size_t i = 0; i < sys.diagonal.size(); ++i)
    add(static_cast<long>(i) * kDof, static_cast<long>(i) * kDof, sys.FullDiagonal(i), false);
  for (size_t k = 0; k < sys.pairs.size(); ++k) {
    const long a = static_cast<long>(sys.pairs[k].first) * kDof;
    const long b = static_cast<long>(sys.pairs[k].second) * kDof;
    for (long r = 0; r < kDof; r += 3) {
      add(a + r, b + r, sys.off_diagonal[k], false);
      add(b + r, a + r, sys.off_diagonal[k], true);
    }
  }
  Eigen::SparseMatrix<double> N(n, n);
  N.setFromTriplets(triplets.begin(), triplets.end());
  triplets = {};
  Eigen::VectorXd rhs(n);
  for (size_t i = 0; i < sys.rhs.size(); ++i) rhs.segment<kDof>(static_cast<long>(i) * kDof) = sys.rhs[i];
  Eigen::SimplicialLDLT<Eigen::SparseMatrix<double>> solver(N);
  if (solver.info() != Eigen::Success) return "normal equations are singular";
  *x = solver.solve(rhs);
  if (solver.info() != Eigen::Success || !x->allFinite()) return "solve failed";
  return {};
}

// Iterative: conjugate gradients from `x` (the current maps, already close), preconditioned by I2 (x) D^-1 per frame
// (the diagonal block without the rigidity's coupling of the two rows, small beside D's linear entries wherever a frame
// has points). Memory is the blocks, a 3x3 inverse per frame and four vectors (q holds N p, then the preconditioned
// residual once r is updated): ~200 bytes a frame beyond the blocks, never a factor's fill.
std::string SolveIterative(const BlockSystem& sys, const AdjustOptions& options, Eigen::VectorXd* x, int* iterations) {
  const size_t frames = sys.diagonal.size();
  const long n = static_cast<long>(frames) * kDof;
  std::vector<Eigen::Matrix3d> inverse(frames);
  for (size_t i = 0; i < frames; ++i) {
    const Eigen::LDLT<Eigen::Matrix3d> ldlt(sys.diagonal[i]);
    if (ldlt.info() != Eigen::Success || !(ldlt.vectorD().minCoeff() > 0)) return "normal equations are singular";
    inverse[i] = ldlt.solve(Eigen::Matrix3d::Identity());
  }
  const auto precondition = [&](const Eigen::VectorXd& r, Eigen::VectorXd* z) {
    z->resize(n);
    for (long a = 0; a < n; a += 3)
      z->segment<3>(a).noalias() = inverse[static_cast<size_t>(a / kDof)] * r.segment<3>(a);
  };
  // The residual starts as the right-hand side (no copy of it is kept: its norm is all the stop needs).
  Eigen::VectorXd r(n), p, q;
  for (size_t i = 0; i < frames; ++i) r.segment<kDof>(static_cast<long>(i) * kDof) = sys.rhs[i];
  const double stop = options.iterative_tolerance * options.iterative_tolerance * r.squaredNorm();
  sys.Multiply(*x, &q);
  r -= q;
  precondition(r, &p);
  double rz = r.dot(p);
  *iterations = 0;
  while (r.squaredNorm() > stop && *iterations < options.max_iterative_steps) {
    sys.Multiply(p, &q);
    const double pq = p.dot(q);
    if (!(pq > 0)) return "normal equations are not positive definite";
    const double alpha = rz / pq;
    *x += alpha * p;
    r -= alpha * q;
    precondition(r, &q);  // z, in q's room: N p is spent
    const double rz_next = r.dot(q);
    p = q + (rz_next / rz) * p;
    rz = rz_next;
    ++*iterations;
  }
  if (!x->allFinite()) return "solve failed";
  if (r.squaredNorm() > stop)
    return "conjugate gradients did not converge in " + std::to_string(options.max_iterative_steps) + " steps";
  return {};
}

// One least-squares pass over every variable frame, weighted by `huber_px` at the current maps (0: unweighted). Empty
// on success, else why.
std::string SolvePass(const std::vector<const Edge*>& used, EdgePointSource* points, const ColumnOf& column,
                      const std::unordered_map<int, double>& half_diagonal, const AdjustOptions& options,
                      double huber_px, std::unordered_map<int, Mat3>* mosaic_from_frame, AdjustResult* result) {
  auto& T = *mosaic_from_frame;
  BlockSystem sys(column.size());
  sys.pairs.reserve(used.size());
  sys.off_diagonal.reserve(used.size());
  for (const Edge* e : used) AddEdge(*e, PointsOf(*e, points), column, T, half_diagonal, options, huber_px, &sys);
  AddFramePriors(column, T, half_diagonal, options, &sys);
  Eigen::VectorXd x(static_cast<long>(column.size()) * kDof);
  for (size_t index = 0; index < column.size(); ++index)
    for (int r = 0; r < 2; ++r)
      for (int c = 0; c < 3; ++c) x(static_cast<long>(index) * kDof + 3 * r + c) = T.at(column[index])(r, c);
  const bool direct = static_cast<int>(column.size()) <= options.direct_max_frames;
  int steps = 0;
  const std::string failure = direct ? SolveDirect(sys, &x) : SolveIterative(sys, options, &x, &steps);
  if (!failure.empty()) return failure;
  result->iterative = !direct;
  result->iterative_steps += steps;
  for (size_t index = 0; index < column.size(); ++index) {
    Mat3& t = T[column[index]];
    for (int r = 0; r < 2; ++r)
      for (int c = 0; c < 3; ++c) t(r, c) = x(static_cast<long>(index) * kDof + 3 * r + c);
    t.row(2) << 0, 0, 1;
  }
  return {};
}

}  // namespace

AdjustResult AdjustAffine(const std::vector<const Edge*>& edges, const std::unordered_set<int>& variable,
                          const std::unordered_map<int, double>& half_diagonal, const AdjustOptions& options,
                          std::unordered_map<int, Mat3>* mosaic_from_frame, EdgePointSource* points) {
  AdjustResult result;
  auto& T = *mosaic_from_frame;
  ColumnOf column(variable.begin(), variable.end());
  std::sort(column.begin(), column.end());
  for (int id : column) {
    if (T.find(id) == T.end()) {
      result.failure = "variable frame without initial transform";
      return result;
    }
  }
  result.num_variables = column.size();
  if (column.empty()) {
    result.ok = true;
    return result;
  }
  std::vector<const Edge*> used;
  for (const Edge* e : edges) {
    if (T.count(e->src) == 0 || T.count(e->tgt) == 0) continue;
    if (VariableIndex(column, e->src) < 0 && VariableIndex(column, e->tgt) < 0) continue;
    used.push_back(e);
  }
  for (int iteration = 0; iteration <= options.robust_iterations; ++iteration) {
    result.failure =
        SolvePass(used, points, column, half_diagonal, options, iteration == 0 ? 0.0 : options.huber_px, &T, &result);
    if (!result.failure.empty()) return result;
  }
  const ResidualStats stats = EdgeResiduals(used, T, points);
  result.num_residuals = stats.count;
  result.rms_px = stats.rms;
  result.median_px = stats.median;
  result.ok = true;
  return result;
}

ResidualStats EdgeResiduals(const std::vector<const Edge*>& edges, const std::unordered_map<int, Mat3>& T,
                            EdgePointSource* points) {
  ResidualStats s;
  // The median from a fixed histogram, the sums in double as the residuals come: nothing here grows with the points.
  LogHistogram histogram = ResidualHistogram();
  double sq = 0.0;
  for (const Edge* e : edges) {
    const auto ts = T.find(e->src);
    const auto tt = T.find(e->tgt);
    if (ts == T.end() || tt == T.end()) continue;
    const EdgePoints& p = PointsOf(*e, points);
    for (size_t k = 0; k < p.size(); ++k) {
      const double v = (Apply(ts->second, p.src(k).cast<double>()) - Apply(tt->second, p.tgt(k).cast<double>())).norm();
      sq += v * v;
      histogram.Add(v);
    }
  }
  s.count = histogram.count();
  if (s.count == 0) return s;
  s.max = histogram.max();
  s.rms = std::sqrt(sq / static_cast<double>(s.count));
  s.median = histogram.Median();
  return s;
}

}  // namespace uavm
