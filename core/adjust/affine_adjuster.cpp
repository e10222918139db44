#include "core/adjust/affine_adjuster.h"

#include <Eigen/Sparse>
#include <Eigen/SparseCholesky>
#include <algorithm>
#include <cmath>

namespace uavm {

bool AdjustOptions::Check(std::string* why) const {
  if (!(rigidity_weight >= 0) || !(relative_linear_weight >= 0) || !(huber_px > 0) || robust_iterations < 0) {
    if (why != nullptr) *why = "adjust: weights must be >= 0, huber_px > 0, robust_iterations >= 0";
    return false;
  }
  return true;
}

namespace {

// Parameter layout of one frame: a00 a01 a02 a10 a11 a12.
constexpr int kDof = 6;

struct RowBuilder {
  std::vector<Eigen::Triplet<double>> triplets;
  std::vector<double> rhs;
  int rows = 0;

  int NewRow(double b) {
    rhs.push_back(b);
    return rows++;
  }
  void Add(int row, int col, double v) {
    if (v != 0.0) triplets.emplace_back(row, col, v);
  }
};

using ColumnOf = std::unordered_map<int, int>;  // frame id -> first column

// Correspondence rows T_src p - T_tgt q = 0 go straight into the normal equations: per edge, the weighted sums S_pp,
// S_pq, S_qq of the homogeneous points give its 6x6 block (the same for both coordinate rows), so the Jacobian with
// one row per point is never built. `weights` null: all 1 (the first pass).
void AddCorrespondences(const std::vector<const Edge*>& used, const ColumnOf& column,
                        const std::unordered_map<int, Mat3>& T, const std::vector<float>* weights,
                        std::vector<Eigen::Triplet<double>>* normal, Eigen::VectorXd* Atb) {
  size_t corr_index = 0;
  for (const Edge* e : used) {
    Eigen::Matrix3d Spp = Eigen::Matrix3d::Zero();
    Eigen::Matrix3d Spq = Eigen::Matrix3d::Zero();
    Eigen::Matrix3d Sqq = Eigen::Matrix3d::Zero();
    for (size_t k = 0; k < e->src_points.size(); ++k, ++corr_index) {
      const double w = weights == nullptr ? 1.0 : static_cast<double>((*weights)[corr_index]);
      const Eigen::Vector3d p(e->src_points[k].x(), e->src_points[k].y(), 1.0);
      const Eigen::Vector3d q(e->tgt_points[k].x(), e->tgt_points[k].y(), 1.0);
      const double w2 = w * w;
      Spp.noalias() += w2 * p * p.transpose();
      Spq.noalias() += w2 * p * q.transpose();
      Sqq.noalias() += w2 * q * q.transpose();
    }
    const auto cs = column.find(e->src);
    const auto ct = column.find(e->tgt);
    const Mat3& Ts = T.at(e->src);
    const Mat3& Tt = T.at(e->tgt);
    for (int r = 0; r < 2; ++r) {
      const int s0 = cs != column.end() ? cs->second + 3 * r : -1;
      const int t0 = ct != column.end() ? ct->second + 3 * r : -1;
      for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) {
          if (s0 >= 0) normal->emplace_back(s0 + i, s0 + j, Spp(i, j));
          if (t0 >= 0) normal->emplace_back(t0 + i, t0 + j, Sqq(i, j));
          if (s0 >= 0 && t0 >= 0) {
            normal->emplace_back(s0 + i, t0 + j, -Spq(i, j));
            normal->emplace_back(t0 + j, s0 + i, -Spq(i, j));
          }
        }
      // A fixed side moves to the right-hand side.
      if (s0 < 0 && t0 >= 0) {
        const Eigen::Vector3d alpha = Ts.row(r).transpose();
        Atb->segment<3>(t0) += Spq.transpose() * alpha;
      } else if (t0 < 0 && s0 >= 0) {
        const Eigen::Vector3d beta = Tt.row(r).transpose();
        Atb->segment<3>(s0) += Spq * beta;
      }
    }
  }
}

double HalfDiagonal(const std::unordered_map<int, double>& half_diagonal, int id) {
  const auto hd = half_diagonal.find(id);
  return hd != half_diagonal.end() ? hd->second : 1.0;
}

// Rigidity: a00 - a11 = 0 and a01 + a10 = 0, in pixels at the frame's half-diagonal.
void AddRigidityRows(const ColumnOf& column, const std::unordered_map<int, double>& half_diagonal,
                     const AdjustOptions& options, RowBuilder* rb) {
  for (const auto& [id, col] : column) {
    const double scale = options.rigidity_weight * HalfDiagonal(half_diagonal, id);
    if (scale <= 0) continue;
    int row = rb->NewRow(0.0);
    rb->Add(row, col + 0, scale);
    rb->Add(row, col + 4, -scale);
    row = rb->NewRow(0.0);
    rb->Add(row, col + 1, scale);
    rb->Add(row, col + 3, scale);
  }
}

// Relative linear part: L_src - L_tgt * R = 0 with R the edge's measured linear part.
void AddRelativeLinearRows(const std::vector<const Edge*>& used, const ColumnOf& column,
                           const std::unordered_map<int, Mat3>& T, const std::unordered_map<int, double>& half_diagonal,
                           const AdjustOptions& options, RowBuilder* rb) {
  for (const Edge* e : used) {
    const auto cs = column.find(e->src);
    const auto ct = column.find(e->tgt);
    const double scale =
        options.relative_linear_weight * HalfDiagonal(half_diagonal, cs != column.end() ? e->src : e->tgt);
    const Mat3& Ts = T.at(e->src);
    const Mat3& Tt = T.at(e->tgt);
    for (int r = 0; r < 2; ++r) {
      for (int c = 0; c < 2; ++c) {
        double b = 0.0;
        const int row = rb->NewRow(0.0);
        if (cs != column.end())
          rb->Add(row, cs->second + 3 * r + c, scale);
        else
          b -= scale * Ts(r, c);
        for (int k = 0; k < 2; ++k) {
          const double coeff = -scale * e->tgt_from_src(k, c);
          if (ct != column.end())
            rb->Add(row, ct->second + 3 * r + k, coeff);
          else
            b -= coeff * Tt(r, k);
        }
        rb->rhs[static_cast<size_t>(row)] = b;
      }
    }
  }
}

// A faint pull to the current value keeps frames without constraints solvable (gauge of a detached frame).
void AddDampingRows(const ColumnOf& column, const std::unordered_map<int, Mat3>& T, RowBuilder* rb) {
  constexpr double kDamping = 1e-6;
  for (const auto& [id, col] : column) {
    const Mat3& t = T.at(id);
    for (int r = 0; r < 2; ++r)
      for (int c = 0; c < 3; ++c) {
        const int row = rb->NewRow(kDamping * t(r, c));
        rb->Add(row, col + 3 * r + c, kDamping);
      }
  }
}

// One weighted least-squares pass: the correspondence blocks plus the prior rows, solved for every variable frame.
// Empty on success, else why.
std::string SolvePass(const std::vector<const Edge*>& used, const ColumnOf& column, int num_cols,
                      const std::unordered_map<int, double>& half_diagonal, const AdjustOptions& options,
                      const std::vector<float>* weights, std::unordered_map<int, Mat3>* mosaic_from_frame) {
  auto& T = *mosaic_from_frame;
  std::vector<Eigen::Triplet<double>> normal;
  Eigen::VectorXd Atb = Eigen::VectorXd::Zero(num_cols);
  AddCorrespondences(used, column, T, weights, &normal, &Atb);
  RowBuilder rb;
  AddRigidityRows(column, half_diagonal, options, &rb);
  if (options.relative_linear_weight > 0) AddRelativeLinearRows(used, column, T, half_diagonal, options, &rb);
  AddDampingRows(column, T, &rb);
  Eigen::SparseMatrix<double> A(rb.rows, num_cols);
  A.setFromTriplets(rb.triplets.begin(), rb.triplets.end());
  const Eigen::Map<const Eigen::VectorXd> b(rb.rhs.data(), rb.rows);
  Eigen::SparseMatrix<double> AtA(num_cols, num_cols);
  AtA.setFromTriplets(normal.begin(), normal.end());
  normal = {};
  AtA += Eigen::SparseMatrix<double>(A.transpose() * A);
  Atb += A.transpose() * b;
  Eigen::SimplicialLDLT<Eigen::SparseMatrix<double>> solver(AtA);
  if (solver.info() != Eigen::Success) return "normal equations are singular";
  const Eigen::VectorXd x = solver.solve(Atb);
  if (solver.info() != Eigen::Success || !x.allFinite()) return "solve failed";
  for (const auto& [id, col] : column) {
    Mat3& t = T[id];
    for (int r = 0; r < 2; ++r)
      for (int c = 0; c < 3; ++c) t(r, c) = x(col + 3 * r + c);
    t.row(2) << 0, 0, 1;
  }
  return {};
}

// Huber weights per correspondence of `used`, in order, for the next pass (sqrt of the IRLS weight, since rows are
// scaled, not squared). float: the only per-correspondence state, so the solve's memory grows with edges, not points.
void HuberWeights(const std::vector<const Edge*>& used, const std::unordered_map<int, Mat3>& T, double huber_px,
                  std::vector<float>* weights) {
  weights->clear();
  for (const Edge* e : used) {
    const Mat3& Ts = T.at(e->src);
    const Mat3& Tt = T.at(e->tgt);
    for (size_t k = 0; k < e->src_points.size(); ++k) {
      const double r = (Apply(Ts, e->src_points[k]) - Apply(Tt, e->tgt_points[k])).norm();
      weights->push_back(static_cast<float>(r <= huber_px ? 1.0 : std::sqrt(huber_px / r)));
    }
  }
}

}  // namespace

AdjustResult AdjustAffine(const std::vector<const Edge*>& edges, const std::unordered_set<int>& variable,
                          const std::unordered_map<int, double>& half_diagonal, const AdjustOptions& options,
                          std::unordered_map<int, Mat3>* mosaic_from_frame) {
  AdjustResult result;
  auto& T = *mosaic_from_frame;
  ColumnOf column;
  std::vector<int> variable_ids(variable.begin(), variable.end());
  std::sort(variable_ids.begin(), variable_ids.end());
  for (int id : variable_ids) {
    if (T.find(id) == T.end()) {
      result.failure = "variable frame without initial transform";
      return result;
    }
    column.emplace(id, static_cast<int>(column.size()) * kDof);
  }
  result.num_variables = variable_ids.size();
  if (variable_ids.empty()) {
    result.ok = true;
    return result;
  }
  std::vector<const Edge*> used;
  for (const Edge* e : edges) {
    if (T.count(e->src) == 0 || T.count(e->tgt) == 0) continue;
    if (column.count(e->src) == 0 && column.count(e->tgt) == 0) continue;
    used.push_back(e);
  }
  const int num_cols = static_cast<int>(column.size()) * kDof;
  std::vector<float> weights;  // IRLS, from the previous pass
  for (int iteration = 0; iteration <= options.robust_iterations; ++iteration) {
    result.failure = SolvePass(used, column, num_cols, half_diagonal, options, iteration == 0 ? nullptr : &weights, &T);
    if (!result.failure.empty()) return result;
    HuberWeights(used, T, options.huber_px, &weights);
  }
  const ResidualStats stats = EdgeResiduals(used, T);
  result.num_residuals = stats.count;
  result.rms_px = stats.rms;
  result.median_px = stats.median;
  result.ok = true;
  return result;
}

ResidualStats EdgeResiduals(const std::vector<const Edge*>& edges, const std::unordered_map<int, Mat3>& T) {
  ResidualStats s;
  std::vector<double> r;
  for (const Edge* e : edges) {
    const auto ts = T.find(e->src);
    const auto tt = T.find(e->tgt);
    if (ts == T.end() || tt == T.end()) continue;
    for (size_t k = 0; k < e->src_points.size(); ++k)
      r.push_back((Apply(ts->second, e->src_points[k]) - Apply(tt->second, e->tgt_points[k])).norm());
  }
  s.count = r.size();
  if (r.empty()) return s;
  double sq = 0.0;
  for (double v : r) sq += v * v;
  s.rms = std::sqrt(sq / static_cast<double>(r.size()));
  std::nth_element(r.begin(), r.begin() + static_cast<long>(r.size() / 2), r.end());
  s.median = r[r.size() / 2];
  s.max = *std::max_element(r.begin(), r.end());
  return s;
}

}  // namespace uavm
