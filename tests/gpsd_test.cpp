// --telemetry gpsd:HOST:PORT against a real gpsd: gpsfake (Debian gpsd-clients) runs its own daemon on a free port and
// plays an NMEA log written here (GGA + RMC with their checksums) of a receiver that waits on the ground, then flies a
// straight line at a known speed, course and climb, with a few epochs without a fix; the test asks for poses while it
// plays and then kills gpsfake (and its daemon).
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <signal.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>
#include <thread>
#include <vector>

#include "core/util/clock.h"
#include "hal/telemetry/gpsd_source.h"
#include "hal/telemetry/telemetry_source.h"
#include "tests/gpsfake_test_util.h"
#include "tests/test_net.h"

namespace uavm::hal {
namespace {

namespace fs = std::filesystem;
using std::chrono::milliseconds;
using test::GpsFake;
using test::NmeaAngle;
using test::Sentence;

// The flight in the log: kLeadIn epochs (1 s apart in NMEA time) standing at step 0, then steps 1..kSteps along a
// straight line; steps kNoFixFirst..kNoFixLast have no fix (GGA quality 0, RMC status V).
constexpr double kLat0 = 46.52, kLon0 = 6.63;
constexpr double kSpeedMps = 5.0, kCourseDeg = 30.0;
constexpr double kAlt0 = 500.0, kClimbPerStep = 2.0;
constexpr int kLeadIn = 15, kSteps = 30;
constexpr int kNoFixFirst = 12, kNoFixLast = 15;
constexpr int kKillAtStep = 22;  // gpsfake is killed once poses reach this step, before the log ends
constexpr double kMetresPerDegLat = 111320.0;

double StepLat() {
  return kSpeedMps * std::cos(kCourseDeg * M_PI / 180) / kMetresPerDegLat;
}
double StepLon() {
  return kSpeedMps * std::sin(kCourseDeg * M_PI / 180) / (kMetresPerDegLat * std::cos(kLat0 * M_PI / 180));
}

// One epoch: GGA then RMC at NMEA time 12:00:00 + `second`, at step `step` (moving or not).
std::string Epoch(int second, int step, bool moving, bool fix) {
  char time[16];
  std::snprintf(time, sizeof(time), "12%02d%02d.00", second / 60, second % 60);
  const std::string t = time;
  if (!fix) return Sentence("GPGGA," + t + ",,,,,0,00,99.9,,M,,M,,") + Sentence("GPRMC," + t + ",V,,,,,,,150626,,,N");
  const std::string pos =
      NmeaAngle(kLat0 + step * StepLat(), 2, 'N', 'S') + "," + NmeaAngle(kLon0 + step * StepLon(), 3, 'E', 'W');
  char gga[64], rmc[64];
  std::snprintf(gga, sizeof(gga), ",1,08,0.9,%.1f,M,48.0,M,,", kAlt0 + step * kClimbPerStep);
  if (moving)
    std::snprintf(rmc, sizeof(rmc), ",%.2f,%.1f,150626,,,A", kSpeedMps / 0.514444, kCourseDeg);
  else
    std::snprintf(rmc, sizeof(rmc), ",0.00,,150626,,,A");
  return Sentence("GPGGA," + t + "," + pos + gga) + Sentence("GPRMC," + t + ",A," + pos + rmc);
}

std::string FlightLog() {
  std::string log;
  for (int i = 0; i < kLeadIn; ++i) log += Epoch(i, 0, false, true);
  for (int s = 1; s <= kSteps; ++s) log += Epoch(kLeadIn + s - 1, s, true, s < kNoFixFirst || s > kNoFixLast);
  return log;
}

// Where a pose lies on the flown line: `along` in steps, `across` in degrees off it.
struct OnLine {
  double along = 0, across = 0;
};
OnLine Project(const InterpolatedPose& p) {
  const double dy = p.lat_deg - kLat0, dx = p.lon_deg - kLon0;
  const double sy = StepLat(), sx = StepLon();
  const double along = (dy * sy + dx * sx) / (sy * sy + sx * sx);
  return {along, std::hypot(dy - along * sy, dx - along * sx)};
}

struct Sample {
  int64_t t_ns = 0;
  std::optional<InterpolatedPose> pose;
  uint64_t no_fix = 0;
};

class GpsdTest : public ::testing::Test {
 protected:
  void SetUp() override {
    if (std::system("command -v gpsfake >/dev/null 2>&1") != 0)
      GTEST_SKIP() << "gpsfake is not installed (Debian gpsd-clients, with gpsd: scripts/setup.sh)";
    dir_ = fs::temp_directory_path() / ("uavm_gpsd_" + std::to_string(getpid()));
    fs::create_directories(dir_);
    std::ofstream(dir_ / "flight.nmea", std::ios::binary) << FlightLog();
  }
  void TearDown() override {
    std::error_code ec;
    if (!dir_.empty()) fs::remove_all(dir_, ec);
  }
  fs::path dir_;
};

TEST(GpsdSpecTest, ParsesHostAndPort) {
  std::string error;
  auto ok = MakeTelemetrySource("gpsd:127.0.0.1:2947", {}, &error);
  ASSERT_TRUE(ok) << error;
  EXPECT_EQ(ok->Describe(), "gpsd 127.0.0.1:2947");
  EXPECT_EQ(ok->Report().kind, "gpsd");
  for (const char* bad : {"gpsd:127.0.0.1", "gpsd::2947", "gpsd:localhost:0", "gpsd:localhost:70000"}) {
    EXPECT_EQ(MakeTelemetrySource(bad, {}, &error), nullptr) << bad;
    EXPECT_NE(error.find("HOST:PORT"), std::string::npos) << error;
  }
}

TEST(GpsdSpecTest, NoDaemonIsNotAStartUpErrorAndStopsPromptly) {
  const int port = test::FreePort();
  ASSERT_GT(port, 0);
  auto source = MakeGpsdSource("127.0.0.1", port, {});
  std::string error;
  ASSERT_EQ(source->Start(&error), Status::kOk) << error;
  std::this_thread::sleep_for(milliseconds(700));  // a first attempt and a retry
  Frame frame;
  frame.timestamp_ns = MonotonicNs();
  EXPECT_FALSE(source->PoseFor(frame));
  const int64_t t0 = MonotonicNs();
  source->Stop();
  EXPECT_LT(MonotonicNs() - t0, 1'000'000'000);
  EXPECT_EQ(source->Report().frames_without, 1u);
}

// Asks for the pose every 50 ms (a frame just taken) until poses reach `until_step` or `timeout` passes.
std::vector<Sample> SampleUntil(TelemetrySource* source, double until_step, milliseconds timeout) {
  std::vector<Sample> samples;
  const auto end = std::chrono::steady_clock::now() + timeout;
  while (std::chrono::steady_clock::now() < end) {
    Frame frame;
    frame.timestamp_ns = MonotonicNs();
    Sample s{frame.timestamp_ns, source->PoseFor(frame), source->Report().track.no_fix};
    samples.push_back(s);
    if (s.pose && Project(*s.pose).along >= until_step) break;
    std::this_thread::sleep_for(milliseconds(50));
  }
  return samples;
}

// One pose: on the flown line, at the log's altitude for where it is, its height above the take-off altitude (the
// lead-in's), no roll or pitch, no course while standing.
void CheckPose(const InterpolatedPose& p, const OnLine& o) {
  EXPECT_LT(o.across, 1e-5) << "off the flown line at step " << o.along;
  EXPECT_GE(o.along, -1e-3);
  EXPECT_LE(o.along, kSteps + 1e-3);
  EXPECT_NEAR(p.alt_msl_m, kAlt0 + o.along * kClimbPerStep, 0.05) << "at step " << o.along;
  ASSERT_TRUE(p.relative_alt_m);
  EXPECT_NEAR(p.alt_msl_m - *p.relative_alt_m, kAlt0, 1e-6) << "take-off reference: the first 3-D fix";
  EXPECT_FALSE(p.roll_deg || p.pitch_deg);
  if (o.along < 1e-6) {
    EXPECT_FALSE(p.yaw_deg) << "standing: no course";
  }
}

// Every pose checked, in order along the line, the course as yaw while moving; poses up to the kill step.
void CheckPoses(const std::vector<Sample>& samples) {
  double last_along = -1;
  int placed = 0, with_yaw = 0;
  for (const Sample& s : samples) {
    if (!s.pose) continue;
    ++placed;
    const OnLine o = Project(*s.pose);
    CheckPose(*s.pose, o);
    EXPECT_GE(o.along, last_along - 1e-6) << "went backwards";
    last_along = o.along;
    if (o.along > 2 && s.pose->yaw_deg) {
      ++with_yaw;
      EXPECT_NEAR(*s.pose->yaw_deg, kCourseDeg, 0.5);
    }
  }
  EXPECT_GT(placed, 20);
  EXPECT_GT(with_yaw, 5);
  EXPECT_GE(last_along, kKillAtStep);
}

// No-fix reports arrive while poses pass the no-fix steps (and are counted); before, others may be (gpsd's own while
// it waits for a first fix), so the count is compared across them.
void CheckNoFixCounted(const std::vector<Sample>& samples) {
  uint64_t before = 0, after = 0;
  for (const Sample& s : samples) {
    if (!s.pose) continue;
    const double along = Project(*s.pose).along;
    if (along <= kNoFixFirst - 2) before = s.no_fix;
    if (along >= kNoFixLast + 2 && after == 0) after = s.no_fix;
  }
  EXPECT_GE(after, before + 2) << "no-fix epochs (GGA quality 0, RMC V) counted";
}

TEST_F(GpsdTest, PlacesFramesFromALiveDaemonAndSurvivesItsLoss) {
  const int port = test::FreePort();
  ASSERT_GT(port, 0);
  const auto t_start = std::chrono::steady_clock::now();
  GpsFake fake(dir_ / "flight.nmea", port, dir_ / "gpsfake.log");
  ASSERT_TRUE(fake.running());
  TelemetryOptions options;
  options.max_gap_ns = 1'500'000'000;  // the no-fix epochs (4 x 0.2 s) are bridged
  options.latency_ns = 150'000'000;    // frames are looked up 150 ms back: between fixes (100 ms apart), interpolated
  auto source = MakeGpsdSource("127.0.0.1", port, options);
  std::string error;
  ASSERT_EQ(source->Start(&error), Status::kOk) << error;

  const auto samples = SampleUntil(source.get(), kKillAtStep, milliseconds(30000));
  CheckPoses(samples);
  CheckNoFixCounted(samples);
  EXPECT_EQ(source->Report().link_losses, 0u);

  fake.Kill();  // the daemon goes with it, mid-flight
  const auto lost_by = std::chrono::steady_clock::now() + milliseconds(3000);
  while (source->Report().link_losses == 0 && std::chrono::steady_clock::now() < lost_by)
    std::this_thread::sleep_for(milliseconds(20));
  EXPECT_EQ(source->Report().link_losses, 1u) << "the lost daemon is counted";
  std::this_thread::sleep_for(milliseconds(1800));  // beyond max_gap: the last fix no longer stands for now
  Frame frame;
  frame.timestamp_ns = MonotonicNs();
  EXPECT_FALSE(source->PoseFor(frame));

  const int64_t t_stop = MonotonicNs();
  source->Stop();
  EXPECT_LT(MonotonicNs() - t_stop, 1'000'000'000) << "Stop() joins the reader promptly, reconnecting or not";
  const TelemetryReport r = source->Report();
  EXPECT_EQ(r.kind, "gpsd");
  EXPECT_GT(r.track.fixes, 20u);
  EXPECT_EQ(r.track.out_of_order, 0u);
  EXPECT_GE(r.frames_without, 1u);
  EXPECT_EQ(r.frames_asked, r.frames_placed + r.frames_without);
  std::printf("gpsd test: %zu samples, %llu fixes, %llu no-fix, %llu placed, %.1f s\n", samples.size(),
              static_cast<unsigned long long>(r.track.fixes), static_cast<unsigned long long>(r.track.no_fix),
              static_cast<unsigned long long>(r.frames_placed),
              std::chrono::duration<double>(std::chrono::steady_clock::now() - t_start).count());
}

}  // namespace
}  // namespace uavm::hal
