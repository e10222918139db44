#pragma once
#include <array>

#include "core/geometry/transform.h"

namespace uavm {

// Brown-Conrady lens distortion (OpenCV's convention) on normalised coordinates x = (u - cx) / f, y = (v - cy) / f of
// the ideal pinhole image: with r^2 = x^2 + y^2 the lens moves (x, y) to
//   x_d = x (1 + k1 r^2 + k2 r^4) + 2 p1 x y + p2 (r^2 + 2 x^2)
//   y_d = y (1 + k1 r^2 + k2 r^4) + p1 (r^2 + 2 y^2) + 2 p2 x y
// k1 < 0 is barrel distortion (points move towards the centre), the usual case for small drone cameras.
struct LensDistortion {
  double k1 = 0.0, k2 = 0.0, p1 = 0.0, p2 = 0.0;

  [[nodiscard]] bool IsZero() const { return k1 == 0.0 && k2 == 0.0 && p1 == 0.0 && p2 == 0.0; }
  [[nodiscard]] Vec2 Distort(const Vec2& ideal) const;
  // The inverse of Distort by fixed-point iteration (to 1e-12 in normalised units, or 50 steps): it converges while
  // the distortion is a contraction, i.e. for any lens a flight could use (|k1 r^2| well below 1/3 at the corners).
  [[nodiscard]] Vec2 Undistort(const Vec2& distorted) const;
};

// A pinhole camera with one focal length (square pixels) and a principal point, in pixel centres ((0,0) = centre of
// the top-left pixel), plus its lens distortion. "Ideal" pixels are those of the distortion-free pinhole image: the
// ones a homography between image planes acts on; "distorted" pixels are those of the recorded image.
struct PinholeCamera {
  int width = 0, height = 0;
  double focal_px = 1.0;
  double cx = 0.0, cy = 0.0;
  LensDistortion distortion;

  // Principal point at the image centre ((w - 1) / 2, (h - 1) / 2), as the simulator renders.
  [[nodiscard]] static PinholeCamera Centred(int width, int height, double focal_px, const LensDistortion& d);
  [[nodiscard]] Vec2 DistortPixel(const Vec2& ideal) const;
  [[nodiscard]] Vec2 UndistortPixel(const Vec2& distorted) const;
  // Normalised radius of the half-diagonal, sqrt(w^2 + h^2) / 2 / f.
  [[nodiscard]] double HalfDiagonalRadius() const;
  // Radial displacement at the half-diagonal as a fraction of that radius, k1 r^2 + k2 r^4 at r = HalfDiagonalRadius():
  // how strong a lens "is at the image corner" (-0.1 = corners drawn 10 % of their radius towards the centre).
  [[nodiscard]] double RadialDistortionAtHalfDiagonal() const;
  // The same camera on a resized pixel grid of `size` (pixel centres kept: u' = s (u + 0.5) - 0.5); the distortion
  // acts on normalised coordinates and does not change.
  [[nodiscard]] PinholeCamera Resized(int new_width, int new_height) const;
};

// Radial k1, k2 of the Brown model (no tangential terms) that best give the distorted normalised radius
// `distorted_radius(r)` of ideal radius r, least squares over r in (0, max_radius]: how another model's curve (a
// lens database's, a fitted undistortion) becomes this one.
[[nodiscard]] LensDistortion FitRadialDistortion(double (*distorted_radius)(double r, const void* ctx), const void* ctx,
                                                 double max_radius);

// Radial brightness falloff (vignetting) V(r) = 1 + a1 r^2 + a2 r^4, r = distance from the principal point divided by
// the half-diagonal (r = 1 at the image corners): a recorded pixel is V(r) times what an ideal lens would record.
struct RadialFalloff {
  double a1 = 0.0, a2 = 0.0;

  [[nodiscard]] double At(double r) const { return 1.0 + a1 * r * r + a2 * r * r * r * r; }
  // The falloff with V(1) = corner: a1 = 1.25 (corner - 1), a2 = -0.25 (corner - 1). That is the shape of the cos^4
  // law (convex in r, within 0.015 of 1 / (1 + T r^2)^2 with the same corner value at corner 0.6) and decreases
  // monotonically from the centre for any corner < 1.
  [[nodiscard]] static RadialFalloff FromCorner(double corner);
};

}  // namespace uavm
