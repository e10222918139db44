#include <gtest/gtest.h>

#include "core/geometry/transform.h"

namespace uavm {
namespace {

TEST(GeometryTest, ResizeMapFollowsPixelCentres) {
  // Halving: the centre of original pixels 0 and 1 (x = 0.5) is the centre of reduced pixel 0.
  const Mat3 m = ResizeMap(0.5, 0.5);
  EXPECT_NEAR(Apply(m, Vec2(0.5, 0.5)).x(), 0.0, 1e-12);
  EXPECT_NEAR(Apply(m, Vec2(3999.0, 0)).x(), 1999.25, 1e-12);
}

TEST(GeometryTest, OverlapOfShiftedSquares) {
  const auto a = Footprint(Mat3::Identity(), 101, 101);  // 100 x 100 between pixel centres
  const auto b = Footprint(Translation(50, 0), 101, 101);
  EXPECT_NEAR(PolygonArea(a), 10000.0, 1e-6);
  EXPECT_NEAR(ConvexOverlapArea(a, b), 5000.0, 1e-3);
  EXPECT_NEAR(ConvexOverlapArea(a, Footprint(Translation(500, 0), 101, 101)), 0.0, 1e-9);
}

TEST(GeometryTest, DecomposeSimilarity) {
  Mat3 m = Mat3::Identity();
  const double s = 1.3;
  const double th = 0.4;
  m << s * std::cos(th), -s * std::sin(th), 5, s * std::sin(th), s * std::cos(th), 7, 0, 0, 1;
  const LinearPart lp = Decompose(m);
  EXPECT_NEAR(lp.scale, s, 1e-12);
  EXPECT_NEAR(lp.rotation, th, 1e-12);
  EXPECT_NEAR(lp.anisotropy, 0.0, 1e-12);
}

}  // namespace
}  // namespace uavm
