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

PinholeCamera PinholeCamera::Resized(int new_width, int new_height) const {
  const double sx = static_cast<double>(new_width) / width;
  const double sy = static_cast<double>(new_height) / height;
  PinholeCamera c = *this;
  c.width = new_width;
  c.height = new_height;
  c.focal_px = focal_px * 0.5 * (sx + sy);
  c.cx = sx * (cx + 0.5) - 0.5;
  c.cy = sy * (cy + 0.5) - 0.5;
  return c;
}

LensDistortion FitRadialDistortion(double (*distorted_radius)(double r, const void* ctx), const void* ctx,
                                   double max_radius) {
  // r_d / r - 1 = k1 r^2 + k2 r^4: a 2x2 normal system over evenly spaced radii.
  double a11 = 0, a12 = 0, a22 = 0, b1 = 0, b2 = 0;
  constexpr int kSamples = 200;
  for (int i = 1; i <= kSamples; ++i) {
    const double r = max_radius * i / kSamples;
    const double y = distorted_radius(r, ctx) / r - 1.0;
    const double x1 = r * r, x2 = x1 * x1;
    a11 += x1 * x1;
    a12 += x1 * x2;
    a22 += x2 * x2;
    b1 += x1 * y;
    b2 += x2 * y;
  }
  const double det = a11 * a22 - a12 * a12;
  LensDistortion d;
  if (std::abs(det) < 1e-300) return d;
  d.k1 = (a22 * b1 - a12 * b2) / det;
  d.k2 = (a11 * b2 - a12 * b1) / det;
  return d;
}

RadialFalloff RadialFalloff::FromCorner(double corner) {
  return {1.25 * (corner - 1.0), -0.25 * (corner - 1.0)};
}

}  // namespace uavm
