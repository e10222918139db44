// Telemetry without a network: the track's interpolation and refusals, geo.txt, EXIF time, --telemetry specs, and
// the serial link on a pseudo-terminal (the flight controller's side is the pty's master).
#include <fcntl.h>
#include <gtest/gtest.h>
#include <poll.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <chrono>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <thread>

#include "core/util/clock.h"
#include "hal/telemetry/geo_txt.h"
#include "hal/telemetry/mavlink.h"
#include "hal/telemetry/telemetry_config.h"
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
  track.AddFix(Fix(6, 50.1, 8.0));                               // telemetry was lost for 5 s
  track.AddFix(Fix(5, 50.1, 8.0));                               // a clock going back: refused
  EXPECT_TRUE(track.At(6 * kSecond + kSecond / 2).has_value());  // 0.5 s after the last: held
  track.AddFix(Fix(7, 0, 0), /*3-D fix=*/false);
  EXPECT_TRUE(track.At(kSecond / 2).has_value());
  EXPECT_FALSE(track.At(3 * kSecond).has_value());  // between fixes 5 s apart
  // The receiver has said since that it lost its fix: the last position is no longer held.
  EXPECT_FALSE(track.At(6 * kSecond + kSecond / 2).has_value());
  EXPECT_FALSE(track.At(9 * kSecond).has_value());  // 3 s after the last
  EXPECT_FALSE(track.At(-3 * kSecond).has_value());
  const TrackCounters c = track.counters();
  EXPECT_EQ(c.fixes, 3u);
  EXPECT_EQ(c.out_of_order, 1u);
  EXPECT_EQ(c.no_fix, 1u);
  EXPECT_EQ(c.stale, 1u);
  EXPECT_EQ(c.outside, 3u);
  EXPECT_EQ(c.answered, 2u);
}

// Past the newest fix (a link that went quiet) the vehicle's position is carried on by the fix's ground velocity,
// for max_hold only.
TEST(TelemetryTrackTest, HoldsTheNewestFixBrieflyAndCarriesItOnByItsVelocity) {
  TelemetryTrack track(16, 2 * kSecond, kSecond);
  PositionFix f = Fix(10, 50.0, 8.0);
  f.north_mps = 10.0;  // 10 m/s north-east-ish
  f.east_mps = 5.0;
  track.AddFix(f);
  const auto p = track.At(10 * kSecond + kSecond / 2);
  ASSERT_TRUE(p.has_value());
  constexpr double kMetresPerDeg = 6371008.8 * M_PI / 180.0;
  EXPECT_NEAR((p->lat_deg - 50.0) * kMetresPerDeg, 5.0, 1e-6);
  EXPECT_NEAR((p->lon_deg - 8.0) * kMetresPerDeg * std::cos(50.0 * M_PI / 180.0), 2.5, 1e-6);
  EXPECT_FALSE(track.At(11 * kSecond + kSecond / 10).has_value());  // 1.1 s on: past max_hold
  TelemetryTrack no_hold(16, 2 * kSecond, 0);
  no_hold.AddFix(f);
  EXPECT_TRUE(no_hold.At(10 * kSecond).has_value());
  EXPECT_FALSE(no_hold.At(10 * kSecond + kSecond / 10).has_value());
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

// mavlink-serial on a pseudo-terminal: termios set-up, fixes read as they come, STATUSTEXT written back, and a link
// that hangs up (the master closed: a USB adapter pulled) counted as lost without spinning or crashing.
TEST(TelemetrySourceTest, SerialLinkOnAPseudoTerminal) {
  const int master = posix_openpt(O_RDWR | O_NOCTTY);
  // qemu-user (the aarch64 suite) resolves /dev/ptmx in the target's sysroot, which has none: no pty to test on.
  if (master < 0) GTEST_SKIP() << "no pseudo-terminal here: " << std::strerror(errno);
  ASSERT_EQ(grantpt(master), 0);
  ASSERT_EQ(unlockpt(master), 0);
  const std::string slave = ptsname(master);
  std::string error;
  auto source = MakeTelemetrySource("mavlink-serial:" + slave + ":115200", {}, &error);
  ASSERT_NE(source, nullptr) << error;
  ASSERT_EQ(source->Start(&error), Status::kOk) << error;
  // The flight controller: its HEARTBEAT, then 20 Hz of GLOBAL_POSITION_INT for 1 s, moving north.
  const std::string heartbeat = mavlink::Encode(mavlink::Heartbeat{0, 2, 3, 209, 4}, 0, 1, 1);
  ASSERT_EQ(write(master, heartbeat.data(), heartbeat.size()), static_cast<ssize_t>(heartbeat.size()));
  for (int k = 0; k < 20; ++k) {
    mavlink::GlobalPositionInt g;
    g.time_boot_ms = static_cast<uint32_t>(50 * k);
    g.lat_deg = 50.0 + 1e-6 * k;
    g.lon_deg = 8.0;
    g.relative_alt_m = 42.0;
    g.heading_deg = 10.0;
    const std::string bytes = mavlink::Encode(g, static_cast<uint8_t>(k), 1, 1);
    ASSERT_EQ(write(master, bytes.data(), bytes.size()), static_cast<ssize_t>(bytes.size()));
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  Frame frame;
  frame.timestamp_ns = MonotonicNs() - 120'000'000;
  const auto pose = source->PoseFor(frame);
  ASSERT_TRUE(pose.has_value()) << "no fix read from " << slave;
  EXPECT_GT(pose->lat_deg, 50.0 + 10e-6);
  EXPECT_LT(pose->lat_deg, 50.0 + 19.5e-6);
  EXPECT_NEAR(*pose->relative_alt_m, 42.0, 1e-9);
  // The mapper's state goes back over the same wire.
  source->SendStatus("uavm: on the wire");
  mavlink::Parser parser;
  std::string heard;
  for (int tries = 0; tries < 20 && heard.empty(); ++tries) {
    pollfd pfd{master, POLLIN, 0};
    if (poll(&pfd, 1, 100) <= 0) continue;
    uint8_t buf[512];
    const ssize_t n = read(master, buf, sizeof(buf));
    if (n <= 0) continue;
    parser.Feed(buf, static_cast<size_t>(n), [&](const mavlink::Packet& p) {
      if (auto m = mavlink::Decode(p))
        if (auto* t = std::get_if<mavlink::Statustext>(&*m)) heard = t->text;
    });
  }
  EXPECT_EQ(heard, "uavm: on the wire");
  close(master);  // the wire is cut
  std::this_thread::sleep_for(std::chrono::milliseconds(800));
  EXPECT_EQ(source->Report().link_losses, 1u);
  const auto stop_start = std::chrono::steady_clock::now();
  source->Stop();
  EXPECT_LT(std::chrono::steady_clock::now() - stop_start, std::chrono::seconds(2));
}

}  // namespace
}  // namespace uavm::hal

namespace uavm::hal {
namespace {

// The telemetry's config keys are hal's: read from the program's YAML (other sections passed over), checked, and
// turned into the sources' units.
TEST(TelemetryConfigTest, ReadsItsSectionChecksItAndHandsTheSourcesNanoseconds) {
  const std::string yaml = "work_long_side: 800\ntelemetry:\n  latency_ms: 250\n  max_gap_s: 3\n";
  TelemetryConfig c;
  std::string error;
  ASSERT_TRUE(ParseTelemetryConfigYaml(yaml, "test.yaml", &c, &error)) << error;
  EXPECT_DOUBLE_EQ(c.latency_ms, 250);
  EXPECT_DOUBLE_EQ(c.max_hold_s, 1.0);  // not given: the default
  const TelemetryOptions o = c.ToOptions();
  EXPECT_EQ(o.latency_ns, 250'000'000);
  EXPECT_EQ(o.max_gap_ns, 3'000'000'000);
  TelemetryConfig round;
  ASSERT_TRUE(ParseTelemetryConfigYaml(ToYaml(c), "round", &round, &error)) << error;
  EXPECT_DOUBLE_EQ(round.max_gap_s, 3);

  TelemetryConfig bad;
  EXPECT_FALSE(ParseTelemetryConfigYaml("telemetry:\n  latency: 5\n", "a.yaml", &bad, &error));
  EXPECT_EQ(error, "config a.yaml: unknown key 'telemetry.latency'");
  EXPECT_FALSE(ParseTelemetryConfigYaml("telemetry:\n  max_gap_s: 90\n", "b.yaml", &bad, &error));
  EXPECT_EQ(error, "config b.yaml: telemetry.max_gap_s must be in (0,60]");
  EXPECT_FALSE(ParseTelemetryConfigYaml("telemetry:\n  max_hold_s: x\n", "c.yaml", &bad, &error));
  EXPECT_DOUBLE_EQ(bad.max_hold_s, 1.0);  // a refused config leaves the defaults
}

}  // namespace
}  // namespace uavm::hal
