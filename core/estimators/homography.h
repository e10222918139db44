#pragma once
#include <vector>

#include "core/geometry/transform.h"

namespace uavm {

// 8-dof homography y ~ H x, fitted by the normalised direct linear transform (4 points minimal): each point set is
// moved to its centroid and scaled to a mean distance of sqrt(2), and H is the eigenvector of the smallest eigenvalue
// of the 9 x 9 normal matrix (algebraic least squares; Hartley & Zisserman, algorithm 4.2). Model is a Mat3 with H(2,
// 2) = 1.
struct HomographyEstimator {
  static constexpr int kMinNumSamples = 4;
  using X = Vec2;
  using Y = Vec2;
  using Model = Mat3;

  [[nodiscard]] static bool Fit(const std::vector<X>& x, const std::vector<Y>& y, Model* model);
  [[nodiscard]] static double SquaredError(const X& x, const Y& y, const Model& m) {
    return (Apply(m, x) - y).squaredNorm();
  }
};

}  // namespace uavm
