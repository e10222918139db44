// Telemetry without a link: the track's interpolation and refusals, geo.txt, EXIF time, --telemetry specs.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>

#include "hal/telemetry/geo_txt.h"
#include "hal/telemetry/telemetry_source.h"
#include "hal/telemetry/track.h"

namespace uavm::hal {
namespace {

constexpr int64_t kSecond = 1'000'000'000;

PositionFix Fix(double t_s, double lat, double lon) {
  PositionFix f;
  f.t_ns = static_cast<int64_t>(t_s * kSecond);
  f.lat_deg = lat;
  f.lon_deg = lon;
  f.alt_msl_m = 100 + t_s;
  return f;
}

TEST(TelemetryTrackTest, InterpolatesBetweenFixesAndTheShortWayRoundInYaw) {
  TelemetryTrack track;
  track.AddFix(Fix(10, 50.0, 8.0));
  track.AddFix(Fix(11, 50.001, 8.002));
  track.AddAttitude({10 * kSecond, 0, 0, 359});
  track.AddAttitude({11 * kSecond, 2, 0, 3});
  const auto p = track.At(10 * kSecond + kSecond / 4);
  ASSERT_TRUE(p.has_value());
  EXPECT_NEAR(p->lat_deg, 50.00025, 1e-12);
  EXPECT_NEAR(p->lon_deg, 8.0005, 1e-12);
  EXPECT_NEAR(p->alt_msl_m, 110.25, 1e-9);
  ASSERT_TRUE(p->yaw_deg.has_value());
  EXPECT_NEAR(*p->yaw_deg, 0.0, 1e-9);  // 359 -> 3 passes through 0
  EXPECT_NEAR(*p->roll_deg, 0.5, 1e-9);
}

TEST(TelemetryTrackTest, RefusesStaleGapsTimesOutsideAndNoFix) {
  TelemetryTrack track(16, 2 * kSecond);
  track.AddFix(Fix(0, 50.0, 8.0));
  track.AddFix(Fix(1, 50.0, 8.0));
  track.AddFix(Fix(6, 50.1, 8.0));  // telemetry was lost for 5 s
  track.AddFix(Fix(5, 50.1, 8.0));  // a clock going back: refused
  track.AddFix(Fix(7, 0, 0), /*3-D fix=*/false);
  EXPECT_TRUE(track.At(kSecond / 2).has_value());
  EXPECT_FALSE(track.At(3 * kSecond).has_value());  // between fixes 5 s apart
  EXPECT_TRUE(track.At(7 * kSecond).has_value());   // 1 s after the last: still within max_gap
  EXPECT_FALSE(track.At(9 * kSecond).has_value());  // 3 s after the last
  EXPECT_FALSE(track.At(-3 * kSecond).has_value());
  const TrackCounters c = track.counters();
  EXPECT_EQ(c.fixes, 3u);
  EXPECT_EQ(c.out_of_order, 1u);
  EXPECT_EQ(c.no_fix, 1u);
  EXPECT_EQ(c.stale, 1u);
  EXPECT_EQ(c.outside, 2u);
  EXPECT_EQ(c.answered, 2u);
}

TEST(TelemetryTrackTest, KeepsTheNewestFixesWithinItsCapacity) {
  TelemetryTrack track(8);
  for (int i = 0; i < 20; ++i) track.AddFix(Fix(i * 0.1, 50 + i * 1e-5, 8));
  EXPECT_EQ(track.counters().overwritten, 12u);
  EXPECT_EQ(track.span().first, static_cast<int64_t>(1.2 * kSecond));
  EXPECT_NEAR(track.At(static_cast<int64_t>(1.85 * kSecond))->lat_deg, 50 + 18.5e-5, 1e-12);
}

class GeoTxtTest : public ::testing::Test {
 protected:
  std::string Write(const std::string& text) {
    const auto p = std::filesystem::temp_directory_path() / ("uavm_geo_" + std::to_string(::getpid()) + ".txt");
    std::ofstream(p) << text;
    paths_.push_back(p);
    return p.string();
  }
  void TearDown() override {
    for (const auto& p : paths_) std::filesystem::remove(p);
  }
  std::vector<std::filesystem::path> paths_;
};

TEST_F(GeoTxtTest, ReadsWgs84AndUtmLines) {
  GeoTxt wgs;
  std::string error;
  ASSERT_TRUE(wgs.Load(Write("EPSG:4326\n# comment\nDJI_0001.JPG -0.1376 50.8198 112.5\n"
                             "sub/DJI_0002.JPG -0.1377 50.8199 112.0 0 0 91.5 1.5 3.0\n"),
                       &error))
      << error;
  ASSERT_EQ(wgs.size(), 2u);
  const GeoTag* a = wgs.Find("DJI_0001.JPG");
  ASSERT_NE(a, nullptr);
  EXPECT_DOUBLE_EQ(a->lat_deg, 50.8198);
  EXPECT_DOUBLE_EQ(a->lon_deg, -0.1376);
  EXPECT_DOUBLE_EQ(*a->alt_m, 112.5);
  const GeoTag* b = wgs.Find("/mnt/sd/DJI_0002.JPG");  // found by file name
  ASSERT_NE(b, nullptr);
  EXPECT_DOUBLE_EQ(*b->kappa_deg, 91.5);
  EXPECT_DOUBLE_EQ(*b->h_acc_m, 1.5);
  // UTM 33N: the central meridian (15 E) at the false easting, the equator at northing 0.
  GeoTxt utm;
  ASSERT_TRUE(utm.Load(Write("EPSG:32633\nIMG_1.JPG 500000 0 30\n"), &error)) << error;
  EXPECT_NEAR(utm.Find("IMG_1.JPG")->lat_deg, 0.0, 1e-9);
  EXPECT_NEAR(utm.Find("IMG_1.JPG")->lon_deg, 15.0, 1e-9);
}

TEST_F(GeoTxtTest, BadFilesNameTheLine) {
  std::string error;
  EXPECT_FALSE(GeoTxt().Load(Write("EPSG:4326\nA.JPG 8.0 50.0\nB.JPG 8.0 north\n"), &error));
  EXPECT_NE(error.find(":3:"), std::string::npos) << error;
  EXPECT_FALSE(GeoTxt().Load(Write("EPSG:4326\nA.JPG 8.0 50.0\nA.JPG 8.1 50.0\n"), &error));
  EXPECT_NE(error.find("listed twice"), std::string::npos) << error;
  EXPECT_FALSE(GeoTxt().Load(Write("EPSG:999999\nA.JPG 8.0 50.0\n"), &error));
  EXPECT_NE(error.find("CRS"), std::string::npos) << error;
  EXPECT_FALSE(GeoTxt().Load(Write("EPSG:4326\nA.JPG 250.0 50.0\n"), &error));  // not a longitude
  EXPECT_FALSE(GeoTxt().Load(Write(""), &error));
  EXPECT_FALSE(GeoTxt().Load("/nonexistent/geo.txt", &error));
}

TEST(TelemetrySourceTest, SpecsAndExifTime) {
  std::string error;
  EXPECT_EQ(MakeTelemetrySource("mavlink-udp", {}, &error), nullptr);
  EXPECT_EQ(MakeTelemetrySource("mavlink-udp:0.0.0.0:port", {}, &error), nullptr);
  EXPECT_EQ(MakeTelemetrySource("carrier-pigeon:x", {}, &error), nullptr);
  EXPECT_NE(error.find("unknown kind"), std::string::npos);
  EXPECT_NE(MakeTelemetrySource("mavlink-udp:0.0.0.0:14550", {}, &error), nullptr);
  EXPECT_NE(MakeTelemetrySource("mavlink-serial:/dev/ttyAMA0:921600", {}, &error), nullptr);
  EXPECT_EQ(*ExifTimeUtcNs("2023:11:14 22:13:20"), 1700000000LL * kSecond);
  EXPECT_FALSE(ExifTimeUtcNs("").has_value());
  EXPECT_FALSE(ExifTimeUtcNs("yesterday at noon!!").has_value());
}

}  // namespace
}  // namespace uavm::hal
