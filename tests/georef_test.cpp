// core/georef: the robust pixel -> UTM fit against known synthetic georeferences.
#include "core/georef/georef.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>

namespace uavm {
namespace {

TEST(GeorefTest, UtmZoneFromLongitudeAndHemisphere) {
  EXPECT_EQ(UtmEpsg(46.84, -91.99), 32615);  // Duluth, MN (brighton_beach_small)
  EXPECT_EQ(UtmEpsg(50.82, -0.14), 32630);   // Brighton, UK
  EXPECT_EQ(UtmEpsg(-33.9, 151.2), 32756);   // Sydney: south
  EXPECT_EQ(UtmEpsg(0.0, 179.999), 32660);
  EXPECT_EQ(UtmEpsg(0.0, -180.0), 32601);
}

TEST(GeorefTest, ProjectionRoundTrip) {
  std::vector<Vec2> xy;
  std::string err;
  ASSERT_TRUE(LatLonToProjected(32615, {46.8426070833}, {-91.9945598889}, &xy, &err)) << err;
  // Zone 15's central meridian is -93: this point lies ~76 km east of it (false easting 500 km).
  EXPECT_NEAR(xy[0].x(), 576300, 2000);
  EXPECT_NEAR(xy[0].y(), 5187800, 2000);
  std::vector<double> lat, lon;
  ASSERT_TRUE(ProjectedToLatLon(32615, xy, &lat, &lon, &err)) << err;
  EXPECT_NEAR(lat[0], 46.8426070833, 1e-9);
  EXPECT_NEAR(lon[0], -91.9945598889, 1e-9);
}

// The frame loop's converter gives LatLonToProjected's numbers, bit for bit, across a change of zone and back.
TEST(GeorefTest, ProjectedConverterMatchesLatLonToProjected) {
  ProjectedConverter converter;
  std::string err;
  for (const int epsg : {32615, 32615, 32616, 32615}) {
    std::vector<Vec2> expected;
    ASSERT_TRUE(LatLonToProjected(epsg, {46.8426070833}, {-91.9945598889}, &expected, &err)) << err;
    Vec2 xy;
    ASSERT_TRUE(converter.ToProjected(epsg, 46.8426070833, -91.9945598889, &xy, &err)) << err;
    EXPECT_EQ(xy, expected[0]) << "EPSG:" << epsg;
  }
  Vec2 xy;
  EXPECT_FALSE(converter.ToProjected(999999, 46.8, -92.0, &xy, &err));
  EXPECT_FALSE(err.empty());
}

// Its inverse direction gives ProjectedToLatLon's numbers, bit for bit, interleaved with the forward one (each
// direction keeps its own transformation).
TEST(GeorefTest, ProjectedConverterMatchesProjectedToLatLon) {
  ProjectedConverter converter;
  std::string err;
  for (const int epsg : {32615, 32616, 32616, 32615}) {
    const Vec2 en(576000.0, 5187000.0);
    std::vector<double> lat, lon;
    ASSERT_TRUE(ProjectedToLatLon(epsg, {en}, &lat, &lon, &err)) << err;
    double got_lat = 0, got_lon = 0;
    ASSERT_TRUE(converter.ToLatLon(epsg, en, &got_lat, &got_lon, &err)) << err;
    EXPECT_EQ(got_lat, lat[0]) << "EPSG:" << epsg;
    EXPECT_EQ(got_lon, lon[0]) << "EPSG:" << epsg;
    Vec2 back;
    ASSERT_TRUE(converter.ToProjected(epsg, got_lat, got_lon, &back, &err)) << err;
    EXPECT_NEAR((back - en).norm(), 0.0, 1e-6);
  }
  double lat = 0, lon = 0;
  EXPECT_FALSE(converter.ToLatLon(999999, Vec2(576000.0, 5187000.0), &lat, &lon, &err));
  EXPECT_FALSE(err.empty());
}

TEST(GeorefTest, WorldFromPixel3IsHomogeneous) {
  Eigen::Matrix<double, 2, 3> m;
  m << 0.1, 0.02, 576000, 0.02, -0.1, 5187000;
  const Mat3 w = WorldFromPixel3(m);
  EXPECT_EQ(Apply(w, Vec2(10, 20)), Vec2(0.1 * 10 + 0.02 * 20 + 576000, 0.02 * 10 - 0.1 * 20 + 5187000));
  EXPECT_EQ(w.row(2), Eigen::RowVector3d(0, 0, 1));
}

// Frames on a grid, their mosaic pixels related to UTM by a known similarity (rotation 30 deg, 5 cm/px), GPS noise of
// 2 m and two frames with 60 m GPS jumps: the fit must reject the jumps and recover the map.
TEST(GeorefTest, RobustSimilarityRejectsGpsJumps) {
  const int epsg = 32630;
  const double gsd = 0.05, th = 30 * M_PI / 180;
  const Vec2 origin(699000, 5632000);  // near Brighton, UK
  std::mt19937 rng(7);
  std::normal_distribution<double> noise(0, 2.0);
  std::vector<GeoPoint> pts;
  std::vector<Vec2> truth;
  for (int i = 0; i < 20; ++i) {
    const Vec2 px(400.0 * (i % 5), 300.0 * (i / 5) + 50.0 * (i % 2));
    // y-down pixels -> (E, N): N decreases with y.
    const Vec2 en = origin + gsd * Vec2(std::cos(th) * px.x() - std::sin(th) * px.y(),
                                        -(std::sin(th) * px.x() + std::cos(th) * px.y()));
    Vec2 noisy = en + Vec2(noise(rng), noise(rng));
    if (i == 3 || i == 11) noisy += Vec2(60, -45);
    std::vector<double> lat, lon;
    std::string err;
    ASSERT_TRUE(ProjectedToLatLon(epsg, {noisy}, &lat, &lon, &err));
    pts.push_back({i, px, lat[0], lon[0]});
    truth.push_back(en);
  }
  GeorefOptions o;
  o.allow_affine = false;
  const GeorefFit fit = FitGeoref(pts, o);
  ASSERT_TRUE(fit.ok) << fit.failure;
  EXPECT_EQ(fit.epsg, epsg);
  EXPECT_EQ(fit.model, "similarity");
  EXPECT_EQ(fit.inliers, 18);
  EXPECT_NEAR(fit.gsd_m, gsd, 0.002);
  EXPECT_NEAR(fit.rotation_deg, 30.0, 1.0);
  EXPECT_LT(fit.rms_m, 4.0);
  EXPECT_GT(fit.rms_m, 0.5);  // the GPS noise is real and shows
  for (size_t i = 0; i < pts.size(); ++i) {
    const Vec2 p = fit.world_from_pixel.leftCols<2>() * pts[i].pixel + fit.world_from_pixel.col(2);
    EXPECT_LT((p - truth[i]).norm(), 2.5) << i;  // the map, not the noisy GPS, is recovered
  }
  EXPECT_GT(fit.residuals_m[3], 50);
}

TEST(GeorefTest, AffineOnlyWithSpreadAndEnoughFrames) {
  // A single straight line of frames: the affine is ill-posed, the similarity must be kept.
  std::vector<GeoPoint> line;
  for (int i = 0; i < 15; ++i) {
    std::vector<double> lat, lon;
    std::string err;
    ASSERT_TRUE(ProjectedToLatLon(32630, {Vec2(699000 + 10.0 * i, 5632000)}, &lat, &lon, &err));
    line.push_back({i, Vec2(100.0 * i, 0), lat[0], lon[0]});
  }
  GeorefFit fit = FitGeoref(line, GeorefOptions{});
  ASSERT_TRUE(fit.ok);
  EXPECT_EQ(fit.model, "similarity");
  EXPECT_NEAR(fit.gsd_m, 0.1, 1e-3);
  // Too few frames: no fit, a reason.
  fit = FitGeoref({line[0], line[1]}, GeorefOptions{});
  EXPECT_FALSE(fit.ok);
  EXPECT_FALSE(fit.failure.empty());
}

TEST(GeorefTest, GdalGeoTransformIsCornerBased) {
  Eigen::Matrix<double, 2, 3> m;
  m << 0.1, 0, 1000, 0, -0.1, 2000;
  const auto gt = GdalGeoTransform(m);
  EXPECT_DOUBLE_EQ(gt[0], 1000 - 0.05);
  EXPECT_DOUBLE_EQ(gt[3], 2000 + 0.05);
  EXPECT_DOUBLE_EQ(gt[1], 0.1);
  EXPECT_DOUBLE_EQ(gt[5], -0.1);
}

}  // namespace
}  // namespace uavm
