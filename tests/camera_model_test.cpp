#include "core/geometry/camera_model.h"

#include <gtest/gtest.h>

#include <cmath>

namespace uavm {
namespace {

TEST(LensDistortionTest, UndistortInvertsDistortOverTheFrame) {
  const PinholeCamera cam = PinholeCamera::Centred(400, 300, 400.0, {-0.1, 0.02, 0.001, -0.0005});
  double worst = 0.0;
  for (int y = 0; y < 300; y += 23)
    for (int x = 0; x < 400; x += 29) {
      const Vec2 p(x, y);
      worst = std::max(worst, (cam.DistortPixel(cam.UndistortPixel(p)) - p).norm());
      worst = std::max(worst, (cam.UndistortPixel(cam.DistortPixel(p)) - p).norm());
    }
  EXPECT_LT(worst, 1e-9);
  // Barrel distortion (k1 < 0) draws a corner towards the centre, by k1 R^2 + k2 R^4 of its radius.
  const PinholeCamera barrel = PinholeCamera::Centred(400, 300, 400.0, {-0.1, 0, 0, 0});
  EXPECT_NEAR(barrel.HalfDiagonalRadius(), 0.625, 1e-12);
  EXPECT_NEAR(barrel.RadialDistortionAtHalfDiagonal(), -0.1 * 0.390625, 1e-12);
  const Vec2 corner(barrel.cx + 200.0, barrel.cy + 150.0);  // the half-diagonal from the principal point
  const Vec2 moved = barrel.DistortPixel(corner);
  EXPECT_NEAR((moved - Vec2(barrel.cx, barrel.cy)).norm(), 250.0 * (1.0 - 0.0390625), 1e-9);
  EXPECT_TRUE((barrel.UndistortPixel(Vec2(barrel.cx, barrel.cy)) - Vec2(barrel.cx, barrel.cy)).norm() < 1e-12);
}

TEST(RadialFalloffTest, FromCornerHitsTheCornerAndFallsMonotonically) {
  for (double corner : {0.4, 0.6, 0.9, 1.0}) {
    const RadialFalloff v = RadialFalloff::FromCorner(corner);
    EXPECT_NEAR(v.At(0.0), 1.0, 1e-15);
    EXPECT_NEAR(v.At(1.0), corner, 1e-12);
    for (double r = 0.05; r <= 1.0; r += 0.05) EXPECT_LE(v.At(r), v.At(r - 0.05) + 1e-15) << corner << " " << r;
  }
  // Close to the cos^4 law with the same corner value.
  const double t = 1.0 / std::sqrt(0.6) - 1.0;
  const RadialFalloff v = RadialFalloff::FromCorner(0.6);
  for (double r = 0.0; r <= 1.0; r += 0.1) EXPECT_NEAR(v.At(r), 1.0 / std::pow(1.0 + t * r * r, 2), 0.015) << r;
}

}  // namespace
}  // namespace uavm
