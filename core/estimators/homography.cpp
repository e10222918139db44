#include "core/estimators/homography.h"

#include <Eigen/Eigenvalues>
#include <cmath>

namespace uavm {
namespace {

// The similarity taking `points` to their centroid at a mean distance of sqrt(2) (false when they coincide).
bool Normalization(const std::vector<Vec2>& points, Mat3* norm_from_points) {
  Vec2 mean = Vec2::Zero();
  for (const auto& p : points) mean += p;
  mean /= static_cast<double>(points.size());
  double spread = 0.0;
  for (const auto& p : points) spread += (p - mean).norm();
  spread /= static_cast<double>(points.size());
  if (!(spread > 1e-9)) return false;
  const double s = std::sqrt(2.0) / spread;
  *norm_from_points << s, 0, -s * mean.x(), 0, s, -s * mean.y(), 0, 0, 1;
  return true;
}

}  // namespace

bool HomographyEstimator::Fit(const std::vector<X>& x, const std::vector<Y>& y, Model* model) {
  const size_t n = x.size();
  if (n < static_cast<size_t>(kMinNumSamples) || y.size() != n) return false;
  Mat3 nx;
  Mat3 ny;
  if (!Normalization(x, &nx) || !Normalization(y, &ny)) return false;
  // Two rows of the DLT system per point, accumulated as the normal matrix (no 2n x 9 matrix kept).
  Eigen::Matrix<double, 9, 9> ata = Eigen::Matrix<double, 9, 9>::Zero();
  for (size_t i = 0; i < n; ++i) {
    const Vec2 a = Apply(nx, x[i]);
    const Vec2 b = Apply(ny, y[i]);
    Eigen::Matrix<double, 9, 1> r1;
    Eigen::Matrix<double, 9, 1> r2;
    r1 << a.x(), a.y(), 1, 0, 0, 0, -b.x() * a.x(), -b.x() * a.y(), -b.x();
    r2 << 0, 0, 0, a.x(), a.y(), 1, -b.y() * a.x(), -b.y() * a.y(), -b.y();
    ata += r1 * r1.transpose() + r2 * r2.transpose();
  }
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, 9, 9>> eig(ata);
  if (eig.info() != Eigen::Success) return false;
  // A second null direction: the points do not fix a unique homography (collinear, or fewer than 4 in general
  // position).
  const auto& values = eig.eigenvalues();  // ascending
  if (!(values(1) > 1e-12 * std::max(1.0, values(8)))) return false;
  const Eigen::Matrix<double, 9, 1> h = eig.eigenvectors().col(0);
  Mat3 normalized;
  normalized << h(0), h(1), h(2), h(3), h(4), h(5), h(6), h(7), h(8);
  Mat3 m = ny.inverse() * normalized * nx;
  if (!(std::abs(m(2, 2)) > 1e-12)) return false;
  m /= m(2, 2);
  *model = m;
  return model->allFinite();
}

}  // namespace uavm
