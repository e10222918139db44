#pragma once
#include <vector>

#include "core/geometry/transform.h"

namespace uavm {

// 6-dof affine y = A x, fitted by linear least squares (3 points minimal). Model is a Mat3 with last row (0,0,1).
struct AffineEstimator {
  static constexpr int kMinNumSamples = 3;
  using X = Vec2;
  using Y = Vec2;
  using Model = Mat3;

  [[nodiscard]] static bool Fit(const std::vector<X>& x, const std::vector<Y>& y, Model* model);
  [[nodiscard]] static double SquaredError(const X& x, const Y& y, const Model& m) {
    const double u = m(0, 0) * x.x() + m(0, 1) * x.y() + m(0, 2) - y.x();
    const double v = m(1, 0) * x.x() + m(1, 1) * x.y() + m(1, 2) - y.y();
    return u * u + v * v;
  }
};

}  // namespace uavm
