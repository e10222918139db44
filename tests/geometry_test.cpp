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

TEST(GeometryTest, FootprintBoundsGrowsTheStartBox) {
  const std::vector<Mat3> maps = {Translation(-5, 2), Mat3::Identity(), Translation(30, 40)};
  const auto size_of = [](int id) { return id == 0 ? cv::Size(11, 21) : cv::Size(101, 51); };
  const Bounds2 b = FootprintBounds({0, 2}, maps, size_of);
  EXPECT_EQ(b.minx, -5);
  EXPECT_EQ(b.miny, 2);
  EXPECT_EQ(b.maxx, 130);
  EXPECT_EQ(b.maxy, 90);
  const Bounds2 grown = FootprintBounds({0}, maps, size_of, {-10, 0, 500, 5});
  EXPECT_EQ(grown.minx, -10);
  EXPECT_EQ(grown.miny, 0);
  EXPECT_EQ(grown.maxx, 500);
  EXPECT_EQ(grown.maxy, 22);
  EXPECT_GT(FootprintBounds({}, maps, size_of).minx, FootprintBounds({}, maps, size_of).maxx);  // empty
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
