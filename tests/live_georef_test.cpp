// core/georef/live_georef: the georeference of the live picture during the flight, on synthetic flights of known
// truth: the first fit as soon as the positions spread, corners within the GPS noise, the refresh schedule, the bound
// on the sample, frames of another component or moved since they were drawn left out, sidecars GDAL reads.
#include "core/georef/live_georef.h"

#include <gdal_priv.h>
#include <gtest/gtest.h>
#include <ogr_spatialref.h>

#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <opencv2/imgcodecs.hpp>
#include <random>

namespace uavm {
namespace {

constexpr int kEpsg = 32615;  // Duluth, MN

// Mosaic pixels -> UTM by a known similarity: 10 cm/px, the pixel grid turned 30 deg from north-up.
struct Truth {
  Vec2 origin{576300, 5187800};
  double gsd = 0.1;
  double theta = 30 * M_PI / 180;
  [[nodiscard]] Vec2 En(const Vec2& px) const {
    const double c = std::cos(theta), s = std::sin(theta);
    return origin + gsd * Vec2(c * px.x() - s * px.y(), -(s * px.x() + c * px.y()));
  }
};

// A lawnmower flight: strips of `per_strip` frames along mosaic x, `along_px` apart, strips `across_px` apart.
struct Flight {
  std::vector<Vec2> px;
  std::vector<LivePoint> points;  // drawn where the truth has them, GPS with noise
};

Flight MakeFlight(int frames, int per_strip, double along_px, double across_px, double noise_m, unsigned seed = 1) {
  const Truth truth;
  std::mt19937 rng(seed);
  std::normal_distribution<double> noise(0, noise_m);
  Flight f;
  std::vector<Vec2> en;
  for (int i = 0; i < frames; ++i) {
    const int strip = i / per_strip, k = i % per_strip;
    const double x = along_px * (strip % 2 == 0 ? k : per_strip - 1 - k);
    f.px.emplace_back(x, across_px * strip);
    en.push_back(truth.En(f.px.back()) + (noise_m > 0 ? Vec2(noise(rng), noise(rng)) : Vec2(0, 0)));
  }
  std::vector<double> lat, lon;
  std::string err;
  EXPECT_TRUE(ProjectedToLatLon(kEpsg, en, &lat, &lon, &err)) << err;
  for (int i = 0; i < frames; ++i) {
    const auto u = static_cast<size_t>(i);
    f.points.push_back({i, f.px[u], 150.0, lat[u], lon[u]});
  }
  return f;
}

// Every frame in one component, where it was drawn.
LiveLocate SameComponent(const Flight& f) {
  return [&f](int id) -> std::optional<LivePlacement> {
    return LivePlacement{0, static_cast<int>(f.points.size()), f.px[static_cast<size_t>(id)]};
  };
}

// Largest distance (metres) between the described corners and the truth's for a picture at 1/4 of the mosaic.
double CornerErrorM(const LiveGeoref& g, int width, int height) {
  Mat3 image_from_mosaic = Mat3::Identity();
  image_from_mosaic(0, 0) = image_from_mosaic(1, 1) = 0.25;
  image_from_mosaic(0, 2) = 40;
  image_from_mosaic(1, 2) = 30;
  const LiveGeorefView v = g.Describe(image_from_mosaic, width, height);
  EXPECT_TRUE(v.ok) << v.reason;
  if (!v.ok) return 1e9;
  const Mat3 mosaic_from_image = image_from_mosaic.inverse();
  const double w = width - 0.5, h = height - 0.5;
  const Vec2 px[4] = {Vec2(-0.5, -0.5), Vec2(w, -0.5), Vec2(w, h), Vec2(-0.5, h)};
  double worst = 0;
  for (int i = 0; i < 4; ++i) {
    std::vector<Vec2> en;
    std::string err;
    EXPECT_TRUE(LatLonToProjected(kEpsg, {v.corners[static_cast<size_t>(i)][0]}, {v.corners[static_cast<size_t>(i)][1]},
                                  &en, &err));
    worst = std::max(worst, (en[0] - Truth().En(Apply(mosaic_from_image, px[i]))).norm());
  }
  return worst;
}

TEST(LiveGeorefTest, FitsAsSoonAsThePositionsSpreadAndTheCornersHoldWithinTheGpsNoise) {
  const Flight f = MakeFlight(60, 20, 150, 400, 2.0);  // 15 m between frames, 40 m between strips
  LiveGeoref g;
  const LiveGeorefView before = g.Describe(Mat3::Identity(), 100, 100);
  EXPECT_FALSE(before.ok);
  EXPECT_EQ(before.reason, "no registered frame carries GPS yet");
  EXPECT_EQ(before.ToJson()["georeferenced"], false);
  int first = -1;
  for (int i = 0; i < 60; ++i) {
    g.AddFrame(f.points[static_cast<size_t>(i)]);
    if (g.Update(SameComponent(f)) && first < 0) {
      first = i;
      EXPECT_LT(g.fit().rms_m, 5.0);
      // A picture of the flight so far (80 x 24 m): a 30 m baseline with 2 m of noise holds it within metres.
      EXPECT_LT(CornerErrorM(g, 200, 60), 10.0) << "from " << i + 1 << " frames";
    }
    if (i == 0) {
      EXPECT_EQ(g.Describe(Mat3::Identity(), 10, 10).reason, "1 registered frames with GPS (need 3)");
    }
  }
  // Three frames 15 m apart span 30 m: the fit comes with the third or (GPS noise) the fourth frame.
  EXPECT_GE(first, 2);
  EXPECT_LE(first, 3);
  EXPECT_EQ(g.fit().epsg, kEpsg);
  const double err = CornerErrorM(g, 900, 400);
  std::printf("corner error after 60 frames: %.2f m (GPS noise 2 m per axis), %d refits\n", err, g.refits());
  EXPECT_LT(err, 3.0);
  const nlohmann::json j = g.Describe(Mat3::Identity(), 900, 400).ToJson();
  EXPECT_EQ(j["crs"], "EPSG:32615");
  EXPECT_EQ(j["bounds"].size(), 4u);
  EXPECT_EQ(j["corners"].size(), 4u);
  EXPECT_EQ(j["geotransform"].size(), 6u);
  EXPECT_LT(j["bounds"][0].get<double>(), j["bounds"][2].get<double>());  // south < north
  EXPECT_LT(j["bounds"][1].get<double>(), j["bounds"][3].get<double>());  // west < east
  EXPECT_NEAR(j["rotation_deg"].get<double>(), -30.0, 1.0);
}

TEST(LiveGeorefTest, RefitsEveryNFramesOrWhenTheSampleGrows) {
  LiveGeorefOptions o;
  o.refit_every = 10;
  o.refit_growth = 0.25;
  const Flight f = MakeFlight(200, 200, 151, 0, 0.0);  // one straight line, 15.1 m apart, exact GPS
  LiveGeoref g(o);
  for (int i = 0; i < 2; ++i) g.AddFrame(f.points[static_cast<size_t>(i)]);
  EXPECT_FALSE(g.Due());  // 2 frames
  o.min_spread_m = 31.0;
  LiveGeoref narrow(o);
  for (int i = 0; i < 3; ++i) narrow.AddFrame(f.points[static_cast<size_t>(i)]);
  EXPECT_FALSE(narrow.Due());  // 3 frames spanning 30 m
  EXPECT_EQ(narrow.Describe(Mat3::Identity(), 1, 1).reason, "the GPS positions span 30 m (need 31 m)");
  g.AddFrame(f.points[2]);
  ASSERT_TRUE(g.Due());
  ASSERT_TRUE(g.Refit(SameComponent(f)));
  EXPECT_FALSE(g.Due());
  g.AddFrame(f.points[3]);  // 3 -> 4 sampled frames: grown by a third
  EXPECT_TRUE(g.Due());
  ASSERT_TRUE(g.Refit(SameComponent(f)));
  for (int i = 4; i < 40; ++i) g.AddFrame(f.points[static_cast<size_t>(i)]);
  ASSERT_TRUE(g.Refit(SameComponent(f)));
  ASSERT_EQ(g.sample_size(), 40u);
  // The drone hovers: frames at sampled places do not grow the sample; the fit is refreshed after 10 of them.
  for (int k = 0; k < 10; ++k) {
    EXPECT_FALSE(g.Due()) << k;
    g.AddFrame(f.points[static_cast<size_t>(39 - k)]);
  }
  EXPECT_TRUE(g.Due());
  ASSERT_TRUE(g.Refit(SameComponent(f)));
  // 40 -> 50 new places: due at the tenth (40 + ceil(0.25 * 40)), not before.
  for (int i = 40; i < 50; ++i) {
    EXPECT_FALSE(g.Due()) << i;
    g.AddFrame(f.points[static_cast<size_t>(i)]);
  }
  EXPECT_TRUE(g.Due());
  // Frames without GPS count for the schedule, not for the sample.
  ASSERT_TRUE(g.Refit(SameComponent(f)));
  for (int k = 0; k < 9; ++k) g.AddFrame(std::nullopt);
  EXPECT_FALSE(g.Due());
  g.AddFrame(std::nullopt);
  EXPECT_TRUE(g.Due());
}

TEST(LiveGeorefTest, TheSampleStaysBoundedAndSpreadOverALongFlight) {
  LiveGeorefOptions o;
  o.max_points = 64;
  // 3000 frames (40 strips of 75 frames, 15 m apart, strips 40 m apart: 1.1 x 1.6 km), refitted every 5 frames as
  // the preview would.
  const Flight f = MakeFlight(3000, 75, 150, 400, 2.0);
  LiveGeoref g(o);
  size_t largest = 0;
  double slowest_ms = 0;
  for (int i = 0; i < 3000; ++i) {
    g.AddFrame(f.points[static_cast<size_t>(i)]);
    largest = std::max(largest, g.sample_size());
    if (i % 5 == 4) {
      const auto t0 = std::chrono::steady_clock::now();
      (void)g.Update(SameComponent(f));
      slowest_ms = std::max(slowest_ms,
                            std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
    }
  }
  std::printf("sample %zu (largest %zu), cell %.0f m, %d refits, slowest update %.1f ms\n", g.sample_size(), largest,
              g.cell_m(), g.refits(), slowest_ms);
  EXPECT_LE(largest, 64u);
  EXPECT_GE(g.sample_size(), 16u);
  EXPECT_LE(g.refits(), 3000 / 10 + 20);  // every 10 frames, plus a few for the sample's growth
  ASSERT_TRUE(g.ok());
  EXPECT_GE(g.fit().points, 16);
  // Spread over the whole flight: corners of a picture of it within the GPS noise.
  const double err = CornerErrorM(g, 75 * 150 / 4 + 100, 40 * 400 / 4 + 100);
  std::printf("corner error after 3000 frames: %.2f m\n", err);
  EXPECT_LT(err, 3.0);
}

TEST(LiveGeorefTest, FramesOfAnotherComponentAreLeftOut) {
  const Flight f = MakeFlight(40, 20, 150, 400, 2.0);
  // Frames 25-34 lost the link to the rest: their own component, drawn in its coordinates (its first frame at the
  // origin), which are not the main one's.
  const auto other = [](int id) { return id >= 25 && id < 35; };
  std::vector<LivePoint> drawn = f.points;
  for (int i = 25; i < 35; ++i) drawn[static_cast<size_t>(i)].drawn = f.px[static_cast<size_t>(i)] - f.px[25];
  const LiveLocate locate = [&](int id) -> std::optional<LivePlacement> {
    if (other(id)) return LivePlacement{25, 10, drawn[static_cast<size_t>(id)].drawn};
    return LivePlacement{0, 30, f.px[static_cast<size_t>(id)]};
  };
  LiveGeoref g;
  for (const auto& p : drawn) g.AddFrame(p);
  ASSERT_TRUE(g.Refit(locate));
  EXPECT_EQ(g.fit().points, 30);
  for (int id : g.fit().inlier_ids) EXPECT_FALSE(other(id)) << id;
  EXPECT_LT(CornerErrorM(g, 800, 300), 3.0);
  EXPECT_EQ(g.sample_size(), 40u);  // kept: they count once their component is the largest
}

TEST(LiveGeorefTest, FramesMovedSinceTheyWereDrawnLeaveTheSample) {
  const Flight f = MakeFlight(40, 20, 150, 400, 2.0);
  LiveGeoref g;
  for (const auto& p : f.points) g.AddFrame(p);
  // A merge re-expressed frames 0-19 elsewhere (500 px off); the picture still shows them where they were drawn.
  const LiveLocate locate = [&](int id) -> std::optional<LivePlacement> {
    const Vec2 now = f.px[static_cast<size_t>(id)] + (id < 20 ? Vec2(500, -200) : Vec2(3, -2));  // or a small drift
    return LivePlacement{0, 40, now};
  };
  ASSERT_TRUE(g.Refit(locate));
  EXPECT_EQ(g.sample_size(), 20u);
  EXPECT_EQ(g.fit().points, 20);
  for (int id : g.fit().inlier_ids) EXPECT_GE(id, 20);
  EXPECT_LT(CornerErrorM(g, 800, 300), 5.0);
}

TEST(LiveGeorefTest, WorldFileAndAuxXmlAreWhatGdalReads) {
  const Flight f = MakeFlight(40, 20, 150, 400, 1.0);
  LiveGeoref g;
  for (const auto& p : f.points) g.AddFrame(p);
  ASSERT_TRUE(g.Refit(SameComponent(f)));
  Mat3 image_from_mosaic = Mat3::Identity();
  image_from_mosaic(0, 0) = image_from_mosaic(1, 1) = 0.2;
  const LiveGeorefView v = g.Describe(image_from_mosaic, 640, 200);
  ASSERT_TRUE(v.ok);
  const auto dir = std::filesystem::temp_directory_path() / ("uavm_live_georef_" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  ASSERT_TRUE(cv::imwrite((dir / "live.jpg").string(), cv::Mat(200, 640, CV_8UC3, cv::Scalar(40, 90, 160))));
  std::ofstream((dir / "live.jgw").string()) << WorldFileText(v.world_from_pixel);
  std::ofstream((dir / "live.jpg.aux.xml").string()) << PamSrsXml(v.crs_wkt);
  GDALAllRegister();
  auto* ds = static_cast<GDALDataset*>(GDALOpen((dir / "live.jpg").c_str(), GA_ReadOnly));
  ASSERT_NE(ds, nullptr);
  double gt[6];
  ASSERT_EQ(ds->GetGeoTransform(gt), CE_None);
  const auto want = GdalGeoTransform(v.world_from_pixel);
  for (int i = 0; i < 6; ++i) EXPECT_NEAR(gt[i], want[static_cast<size_t>(i)], i == 0 || i == 3 ? 1e-3 : 1e-9) << i;
  const OGRSpatialReference* srs = ds->GetSpatialRef();
  ASSERT_NE(srs, nullptr);
  ASSERT_NE(srs->GetAuthorityCode(nullptr), nullptr);
  EXPECT_STREQ(srs->GetAuthorityCode(nullptr), "32615");
  GDALClose(ds);
  std::filesystem::remove_all(dir);
}

}  // namespace
}  // namespace uavm
