#include "core/geometry/similarity.h"

#include <Eigen/Geometry>
#include <cmath>

namespace uavm {

namespace {

constexpr double kMinSpread = 1e-12;  // sum of squared distances of the source points to their centroid
constexpr double kMinScale = 1e-12;

// Umeyama on D x n columns; false when the result is not a usable similarity. Dynamic-size matrices: with fixed D,
// GCC 12 warns (-Wstringop-overread) inside Eigen 3.4's umeyama about a vectorised path that never runs.
template <int D>
bool Umeyama(const Eigen::MatrixXd& src, const Eigen::MatrixXd& dst, Similarity<D>* out) {
  const Eigen::MatrixXd m = Eigen::umeyama(src, dst, true);
  // umeyama returns scale * rotation as one block; a rotation's columns have unit length.
  const Eigen::Matrix<double, D, D> sr = m.topLeftCorner(D, D);
  const double scale = sr.col(0).norm();
  if (!m.allFinite() || !(scale >= kMinScale)) return false;
  out->scale = scale;
  out->rotation = sr / scale;
  out->translation = m.topRightCorner(D, 1);
  return true;
}

}  // namespace

template <int D>
bool FitSimilarity(const std::vector<Eigen::Matrix<double, D, 1>>& src,
                   const std::vector<Eigen::Matrix<double, D, 1>>& dst, Similarity<D>* out,
                   const SimilarityFitOptions& options) {
  if (src.size() != dst.size()) return false;
  const size_t n = options.indices != nullptr ? options.indices->size() : src.size();
  if (n < 2) return false;
  Eigen::MatrixXd s(D, static_cast<Eigen::Index>(n));
  Eigen::MatrixXd d(D, static_cast<Eigen::Index>(n));
  for (size_t k = 0; k < n; ++k) {
    const size_t i = options.indices != nullptr ? (*options.indices)[k] : k;
    if (i >= src.size()) return false;
    s.col(static_cast<Eigen::Index>(k)) = src[i];
    d.col(static_cast<Eigen::Index>(k)) = dst[i];
  }
  if (!s.allFinite() || !d.allFinite()) return false;
  // umeyama divides by the source variance: refuse (almost) coincident points instead of returning infinities.
  if ((s.colwise() - s.rowwise().mean()).squaredNorm() <= kMinSpread) return false;
  Similarity<D> proper;
  const bool proper_ok = Umeyama<D>(s, d, &proper);
  if (options.allow_reflection) {
    // umeyama keeps det(rotation) = +1. The best mirrored fit is the proper fit of the mirrored source composed with
    // the mirror; of the two optimal fits the better one has the larger scale (it explains more of the
    // cross-covariance), ties go to the proper one.
    Eigen::Matrix<double, D, D> mirror = Eigen::Matrix<double, D, D>::Identity();
    mirror(D - 1, D - 1) = -1.0;
    const Eigen::MatrixXd mirrored_src = mirror * s;
    Similarity<D> mirrored;
    if (Umeyama<D>(mirrored_src, d, &mirrored) && (!proper_ok || mirrored.scale > proper.scale)) {
      mirrored.rotation = mirrored.rotation * mirror;
      *out = mirrored;
      return true;
    }
  }
  if (!proper_ok) return false;
  *out = proper;
  return true;
}

template bool FitSimilarity<2>(const std::vector<Eigen::Matrix<double, 2, 1>>&,
                               const std::vector<Eigen::Matrix<double, 2, 1>>&, Similarity<2>*,
                               const SimilarityFitOptions&);
template bool FitSimilarity<3>(const std::vector<Eigen::Matrix<double, 3, 1>>&,
                               const std::vector<Eigen::Matrix<double, 3, 1>>&, Similarity<3>*,
                               const SimilarityFitOptions&);

}  // namespace uavm
