#include "core/geometry/camera_model.h"

#include <cmath>

namespace uavm {

Vec2 LensDistortion::Distort(const Vec2& ideal) const {
  const double x = ideal.x(), y = ideal.y();
  const double r2 = x * x + y * y;
  const double radial = 1.0 + k1 * r2 + k2 * r2 * r2;
  return {x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
          y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y};
}

Vec2 LensDistortion::Undistort(const Vec2& distorted) const {
  if (IsZero()) return distorted;
  // x = x + (distorted - Distort(x)): the step moves x by the remaining error, which shrinks by the distortion's
  // Lipschitz factor each time.
  Vec2 x = distorted;
  for (int it = 0; it < 50; ++it) {
    const Vec2 step = distorted - Distort(x);
    x += step;
    if (step.squaredNorm() < 1e-24) break;
  }
  return x;
}

PinholeCamera PinholeCamera::Centred(int width, int height, double focal_px, const LensDistortion& d) {
  PinholeCamera c;
  c.width = width;
  c.height = height;
  c.focal_px = focal_px;
  c.cx = (width - 1.0) / 2.0;
  c.cy = (height - 1.0) / 2.0;
  c.distortion = d;
  return c;
}

Vec2 PinholeCamera::DistortPixel(const Vec2& ideal) const {
  const Vec2 centre(cx, cy);
  return centre + focal_px * distortion.Distort((ideal - centre) / focal_px);
}

Vec2 PinholeCamera::UndistortPixel(const Vec2& distorted) const {
  const Vec2 centre(cx, cy);
  return centre + focal_px * distortion.Undistort((distorted - centre) / focal_px);
}

double PinholeCamera::HalfDiagonalRadius() const {
  return 0.5 * std::hypot(static_cast<double>(width), static_cast<double>(height)) / focal_px;
}

double PinholeCamera::RadialDistortionAtHalfDiagonal() const {
  const double r2 = HalfDiagonalRadius() * HalfDiagonalRadius();
  return distortion.k1 * r2 + distortion.k2 * r2 * r2;
}

RadialFalloff RadialFalloff::FromCorner(double corner) {
  return {1.25 * (corner - 1.0), -0.25 * (corner - 1.0)};
}

}  // namespace uavm
