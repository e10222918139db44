#pragma once
#include <Eigen/Core>
#include <cstddef>
#include <vector>

namespace uavm {

// dst = scale * rotation * src + translation, in D = 2 or 3 dimensions.
template <int D>
struct Similarity {
  using Vec = Eigen::Matrix<double, D, 1>;
  using Mat = Eigen::Matrix<double, D, D>;

  double scale = 1.0;
  Mat rotation = Mat::Identity();  // orthogonal; determinant -1 only when the fit allowed a reflection
  Vec translation = Vec::Zero();

  [[nodiscard]] Vec Apply(const Vec& p) const { return scale * rotation * p + translation; }
};

struct SimilarityFitOptions {
  // Also consider mirror images (an orthogonal map of determinant -1) and keep whichever fits better.
  bool allow_reflection = false;
  // Fit over these indices of src / dst only (e.g. a RANSAC sample or its inliers); null = every point.
  const std::vector<size_t>* indices = nullptr;
};

// Least-squares similarity from point pairs: Umeyama's closed form (Eigen::umeyama). False, with `out` untouched,
// when the pairs cannot fix one: fewer than 2, src and dst of different sizes, an index out of range, non-finite
// input, the source points (almost) coinciding (sum of squared distances to their centroid <= 1e-12), or a
// vanishing scale (< 1e-12: the destination points coincide).
template <int D>
[[nodiscard]] bool FitSimilarity(const std::vector<Eigen::Matrix<double, D, 1>>& src,
                                 const std::vector<Eigen::Matrix<double, D, 1>>& dst, Similarity<D>* out,
                                 const SimilarityFitOptions& options = {});

using Similarity2 = Similarity<2>;
using Similarity3 = Similarity<3>;

extern template bool FitSimilarity<2>(const std::vector<Eigen::Matrix<double, 2, 1>>&,
                                      const std::vector<Eigen::Matrix<double, 2, 1>>&, Similarity<2>*,
                                      const SimilarityFitOptions&);
extern template bool FitSimilarity<3>(const std::vector<Eigen::Matrix<double, 3, 1>>&,
                                      const std::vector<Eigen::Matrix<double, 3, 1>>&, Similarity<3>*,
                                      const SimilarityFitOptions&);

}  // namespace uavm
