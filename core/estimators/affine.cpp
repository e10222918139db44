#include "core/estimators/affine.h"

#include <Eigen/Dense>
#include <cmath>

namespace uavm {

bool AffineEstimator::Fit(const std::vector<X>& x, const std::vector<Y>& y, Model* model) {
  const size_t n = x.size();
  if (n < 3 || y.size() != n) return false;
  // Centre and scale the source points so the normal equations are well conditioned at any pixel scale.
  Vec2 mean = Vec2::Zero();
  for (const auto& p : x) mean += p;
  mean /= static_cast<double>(n);
  double spread = 0.0;
  for (const auto& p : x) spread += (p - mean).norm();
  spread /= static_cast<double>(n);
  if (!(spread > 1e-9)) return false;
  const double s = 1.0 / spread;
  Eigen::Matrix3d ata = Eigen::Matrix3d::Zero();
  Eigen::Matrix<double, 3, 2> atb = Eigen::Matrix<double, 3, 2>::Zero();
  for (size_t i = 0; i < n; ++i) {
    const Eigen::Vector3d a((x[i].x() - mean.x()) * s, (x[i].y() - mean.y()) * s, 1.0);
    ata += a * a.transpose();
    atb += a * y[i].transpose();
  }
  Eigen::LDLT<Eigen::Matrix3d> ldlt(ata);
  // Collinear samples make the system singular: reject instead of returning garbage.
  const Eigen::Vector3d diag = ldlt.vectorD().cwiseAbs();
  if (ldlt.info() != Eigen::Success || diag.minCoeff() < 1e-9 * std::max(1.0, diag.maxCoeff())) return false;
  const Eigen::Matrix<double, 3, 2> sol = ldlt.solve(atb);  // rows: coefficient of xn, yn, 1
  Mat3 normalized = Mat3::Identity();
  normalized.row(0) << sol(0, 0), sol(1, 0), sol(2, 0);
  normalized.row(1) << sol(0, 1), sol(1, 1), sol(2, 1);
  Mat3 norm_from_src = Mat3::Identity();
  norm_from_src(0, 0) = norm_from_src(1, 1) = s;
  norm_from_src(0, 2) = -mean.x() * s;
  norm_from_src(1, 2) = -mean.y() * s;
  *model = normalized * norm_from_src;
  return model->allFinite();
}

}  // namespace uavm
