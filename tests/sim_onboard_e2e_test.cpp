// End to end with ground truth: simulated flight -> onboard binary (replay) -> evaluator.
#include <gtest/gtest.h>
#include <ogr_spatialref.h>
#include <sys/wait.h>

#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>

#include "core/eval/evaluator.h"
#include "core/eval/image_score.h"
#include "core/session/session_dir.h"
#include "tests/test_env.h"
#include "tools/sim_writer.h"

namespace uavm {
namespace {

namespace fs = std::filesystem;
const std::string kCanvas = std::string(UAVM_TEST_DATA) + "/caliterra_small/images/IMG_9360.jpg";

// 3 strips x 5 frames of 400x300 at gsd 1 over the 1000x750 canvas; forward overlap 0.7, side overlap 0.3. Under
// emulation 2 strips (an outbound and a return strip still meet) and the emulation options of tests/test_env.h
// (a 320 px working copy: the same assertions hold, checked natively).
const int kStrips = test::Emulated() ? 2 : 3;
const int kFrames = 5 * kStrips;
const std::string kPlan = "frame_width: 400\nframe_height: 300\ngsd: 1.0\nstrips: " + std::to_string(kStrips) +
                          "\nstrip_length: 480\nforward_overlap: 0.7\nside_overlap: 0.3\nseed: 3\n";

struct FlightRun {
  eval::EvalResult result;
  eval::EvalResult affine_floor;
  fs::path dir;
};

void FlyAndEvaluate(const std::string& name, const std::string& plan, FlightRun* run, const std::string& args = "") {
  run->dir = fs::temp_directory_path() / ("uavm_sim_e2e_" + name + "_" + std::to_string(::getpid()));
  fs::remove_all(run->dir);
  hal::SimSource source({"", plan, kCanvas, 0});
  std::string err;
  ASSERT_EQ(source.Open(&err), hal::Status::kOk) << err;
  ASSERT_TRUE(tools::WriteSimFlight(&source, (run->dir / "flight").string(), 0, &err)) << err;
  std::string cmd = std::string(UAVM_ONBOARD_BIN) + " --source replay:" + (run->dir / "flight/images").string() +
                    " --out " + (run->dir / "session").string() + " --log-level warn " + args;
  cmd += test::EmulationArgsString();
  const int status = std::system(cmd.c_str());
  ASSERT_TRUE(WIFEXITED(status));
  ASSERT_EQ(WEXITSTATUS(status), 0);
  std::string text;
  std::vector<TransformRow> rows;
  ASSERT_TRUE(ReadTextFile((run->dir / "session/transforms.csv").string(), &text, &err)) << err;
  ASSERT_TRUE(ParseTransformsCsv(text, &rows, &err)) << err;
  std::vector<eval::GtRow> gt;
  ASSERT_TRUE(ReadTextFile((run->dir / "flight/gt.csv").string(), &text, &err)) << err;
  ASSERT_TRUE(eval::ParseGroundTruthCsv(text, &gt, &err)) << err;
  ASSERT_EQ(gt.size(), static_cast<size_t>(kFrames));
  const cv::Size size(400, 300);
  ASSERT_TRUE(eval::EvaluateSession(rows, gt, size, &run->result, &err)) << err;
  ASSERT_TRUE(eval::EvaluateSession(eval::AffineFloorSession(gt), gt, size, &run->affine_floor, &err)) << err;
  std::printf("%s: registered %d/%d, rms %.4f max %.4f px; affine floor rms %.4f max %.4f px\n", name.c_str(),
              run->result.registered, run->result.frames, run->result.rms_px, run->result.max_px,
              run->affine_floor.rms_px, run->affine_floor.max_px);
}

TEST(SimOnboardE2ETest, NadirFlightRegistersEveryFrameToSubPixel) {
  FlightRun run;
  ASSERT_NO_FATAL_FAILURE(FlyAndEvaluate("nadir", kPlan, &run));
  EXPECT_DOUBLE_EQ(run.result.registered_share, 1.0);
  EXPECT_LT(run.affine_floor.rms_px, 1e-6);  // nadir over flat ground: the affine model is exact
  // Measured 0.009 px RMS, 0.027 px max (OpenCV 4.6). The bound leaves 10x for SIFT differences between OpenCV
  // builds and still catches convention bugs: e.g. an uncorrected 0.25 px SIFT offset biases pairs by
  // (I - A) * 0.25 px, 0.5 px between outbound and return strips (A = a 180 deg turn), which no global fit absorbs.
  EXPECT_LT(run.result.rms_px, 0.1);
  EXPECT_LT(run.result.max_px, 0.3);
  // The image-only score agrees: the quick-look mosaic is one affine away from the canvas.
  const cv::Mat mosaic = cv::imread((run.dir / "session/mosaic.png").string(), cv::IMREAD_UNCHANGED);
  const cv::Mat canvas = cv::imread(kCanvas, cv::IMREAD_COLOR | cv::IMREAD_IGNORE_ORIENTATION);
  eval::ImageScore score;
  std::string err;
  ASSERT_TRUE(eval::ScoreMosaicImage(mosaic, canvas, &score, &err)) << err;
  EXPECT_LT(score.median_px, 1.0);
  fs::remove_all(run.dir);
}

TEST(SimOnboardE2ETest, OneDegreeTiltWithTheAffineModelStaysNearTheAffineFloor) {
  FlightRun run;
  ASSERT_NO_FATAL_FAILURE(FlyAndEvaluate("tilt_affine", kPlan + "tilt_deg: 1.0\n", &run, "--model affine"));
  EXPECT_DOUBLE_EQ(run.result.registered_share, 1.0);
  EXPECT_GT(run.affine_floor.rms_px, 0.3);  // 1 deg of tilt is not affine: ~0.74 px RMS at best for 400 px frames
  // An affine pipeline pays the floor plus the inconsistency between neighbours' best affines.
  EXPECT_LT(run.result.rms_px, 2.0);
  EXPECT_GT(run.result.rms_px, run.affine_floor.rms_px * 0.9);
  fs::remove_all(run.dir);
}

TEST(SimOnboardE2ETest, OneDegreeTiltWithTheHomographyModelGoesBelowTheAffineFloor) {
  FlightRun run;
  ASSERT_NO_FATAL_FAILURE(FlyAndEvaluate("tilt_homography", kPlan + "tilt_deg: 1.0\n", &run, "--model homography"));
  EXPECT_DOUBLE_EQ(run.result.registered_share, 1.0);
  EXPECT_LT(run.result.rms_px, 0.5);
  EXPECT_LT(run.result.max_px, 2.5);
  EXPECT_LT(run.result.rms_px, 0.5 * run.affine_floor.rms_px);
  std::string text;
  std::string err;
  ASSERT_TRUE(ReadTextFile((run.dir / "session/transforms.csv").string(), &text, &err)) << err;
  std::vector<TransformRow> rows;
  ASSERT_TRUE(ParseTransformsCsv(text, &rows, &err)) << err;
  int projective = 0;
  for (const auto& r : rows) projective += IsAffine(r.mosaic_from_frame, 1e-12) ? 0 : 1;
  EXPECT_GT(projective, 2 * kFrames / 3);  // the session carries the perspective rows (h20, h21)
  fs::remove_all(run.dir);
}

// The flight carries GPS (noise 1 m per axis, a 0.5 m wandering bias) as an OpenDroneMap geo.txt, replayed with
// --telemetry geo: (the PNG frames have no EXIF). The map lands in the right UTM zone, and the frame centres, placed by
// the images and fitted to all fixes at once, are closer to their true ground positions than the fixes themselves.
TEST(SimOnboardE2ETest, GpsTelemetryGeoreferencesTheMapWithinTheGpsNoise) {
  FlightRun run;
  ASSERT_NO_FATAL_FAILURE(FlyAndEvaluate(
      "gps", kPlan + "gps: 1\nmetres_per_px: 0.1\ngps_noise_m: 1.0\ngps_bias_m: 0.5\n", &run,
      "--telemetry geo:" +
          (fs::temp_directory_path() / ("uavm_sim_e2e_gps_" + std::to_string(::getpid())) / "flight/geo.txt")
              .string()));
  EXPECT_DOUBLE_EQ(run.result.registered_share, 1.0);
  std::ifstream report_file(run.dir / "session/report.json");
  const auto report = nlohmann::json::parse(report_file);
  ASSERT_TRUE(report["georef"]["georeferenced"].get<bool>());
  EXPECT_EQ(report["georef"]["epsg"].get<int>(), 32615);  // 91.99 W: UTM zone 15 N
  EXPECT_EQ(report["telemetry"]["frames_placed"].get<int>(), kFrames);
  // Truth and fixes in the map's CRS.
  OGRSpatialReference wgs84, utm;
  wgs84.importFromEPSG(4326);
  wgs84.SetAxisMappingStrategy(OAMS_TRADITIONAL_GIS_ORDER);
  utm.importFromEPSG(32615);
  std::unique_ptr<OGRCoordinateTransformation> to_utm(OGRCreateCoordinateTransformation(&wgs84, &utm));
  ASSERT_TRUE(to_utm);
  const auto read_geo = [&](const fs::path& path) {
    std::map<std::string, Vec2> out;
    std::ifstream in(path);
    std::string line, name;
    std::getline(in, line);  // CRS
    for (double lon, lat, alt; in >> name >> lon >> lat >> alt;) {
      to_utm->Transform(1, &lon, &lat);
      out[name] = Vec2(lon, lat);
    }
    return out;
  };
  const auto truth = read_geo(run.dir / "flight/geo_truth.txt");
  const auto fixes = read_geo(run.dir / "flight/geo.txt");
  std::string text, err;
  std::vector<TransformRow> rows;
  ASSERT_TRUE(ReadTextFile((run.dir / "session/transforms.csv").string(), &text, &err)) << err;
  ASSERT_TRUE(ParseTransformsCsv(text, &rows, &err)) << err;
  const auto& g = report["georef"]["geotransform"];
  double map_sq = 0, gps_sq = 0;
  for (const auto& r : rows) {
    const Vec2 px = Apply(r.mosaic_from_frame, Vec2(199.5, 149.5));
    // GDAL geotransform: x = g0 + (px + 0.5) g1, y = g3 + (py + 0.5) g5 (the pixel's centre).
    const Vec2 world(g[0].get<double>() + (px.x() + 0.5) * g[1].get<double>(),
                     g[3].get<double>() + (px.y() + 0.5) * g[5].get<double>());
    map_sq += (world - truth.at(r.filename)).squaredNorm();
    gps_sq += (fixes.at(r.filename) - truth.at(r.filename)).squaredNorm();
  }
  const double map_rms = std::sqrt(map_sq / static_cast<double>(rows.size()));
  const double gps_rms = std::sqrt(gps_sq / static_cast<double>(rows.size()));
  std::printf("frame centres against the truth: map %.2f m RMS, GPS fixes %.2f m RMS\n", map_rms, gps_rms);
  EXPECT_LT(map_rms, gps_rms);
  EXPECT_LT(map_rms, 1.5);
  fs::remove_all(run.dir);
}

}  // namespace
}  // namespace uavm
