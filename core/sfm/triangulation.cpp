#include "core/sfm/triangulation.h"

#include <Eigen/SVD>
#include <cmath>

namespace uavm::sfm {

std::optional<Eigen::Vector3d> TriangulateDlt(const std::vector<Pose>& poses,
                                              const std::vector<Eigen::Vector2d>& normalized) {
  const size_t n = poses.size();
  if (n < 2 || normalized.size() != n) return std::nullopt;
  // Conditioning: world coordinates centred on the cameras and scaled to unit spread, so that the translation column
  // does not dominate the rows (Hartley's normalisation, applied to the 3-D side).
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (const auto& p : poses) mean += p.c;
  mean /= static_cast<double>(n);
  double spread = 0.0;
  for (const auto& p : poses) spread += (p.c - mean).norm();
  spread = std::max(spread / static_cast<double>(n), 1e-9);
  std::vector<Eigen::Matrix<double, 3, 4>> P(n);
  for (size_t i = 0; i < n; ++i) {
    P[i].leftCols<3>() = poses[i].R * spread;
    P[i].col(3) = -poses[i].R * (poses[i].c - mean);
  }
  std::vector<double> w(n, 1.0);
  Eigen::Vector4d X;
  // Two passes: the second divides each view's rows by its depth, which turns the algebraic error into the image
  // error (the DLT then matches the maximum-likelihood point to first order).
  for (int pass = 0; pass < 2; ++pass) {
    Eigen::MatrixXd A(2 * n, 4);
    for (size_t i = 0; i < n; ++i) {
      A.row(static_cast<Eigen::Index>(2 * i)) = w[i] * (normalized[i].x() * P[i].row(2) - P[i].row(0));
      A.row(static_cast<Eigen::Index>(2 * i + 1)) = w[i] * (normalized[i].y() * P[i].row(2) - P[i].row(1));
    }
    const Eigen::JacobiSVD<Eigen::MatrixXd> svd(A, Eigen::ComputeFullV);
    X = svd.matrixV().col(3);
    if (std::abs(X(3)) < 1e-12) return std::nullopt;
    X /= X(3);
    for (size_t i = 0; i < n; ++i) {
      const double depth = P[i].row(2).dot(X);
      if (std::abs(depth) < 1e-12) return std::nullopt;
      w[i] = 1.0 / std::abs(depth);
    }
  }
  return Eigen::Vector3d(X.head<3>() * spread + mean);
}

double MaxTriangulationAngleDeg(const std::vector<Pose>& poses, const Eigen::Vector3d& X) {
  double best = 0.0;
  for (size_t i = 0; i < poses.size(); ++i) {
    const Eigen::Vector3d a = (poses[i].c - X).normalized();
    for (size_t j = i + 1; j < poses.size(); ++j) {
      const Eigen::Vector3d b = (poses[j].c - X).normalized();
      best = std::max(best, std::acos(std::clamp(a.dot(b), -1.0, 1.0)));
    }
  }
  return best * 180.0 / M_PI;
}

}  // namespace uavm::sfm
