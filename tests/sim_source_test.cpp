#include "hal/sim/sim_source.h"

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "core/eval/ground_truth.h"
#include "core/session/session_dir.h"
#include "tools/sim_writer.h"

namespace uavm::hal {
namespace {

namespace fs = std::filesystem;
const std::string kCanvas = std::string(UAVM_TEST_DATA) + "/caliterra_small/images/IMG_9360.jpg";

// 400x300 frames at gsd 1 over the 1000x750 canvas: 2 strips of 480 px at 120 px spacing (forward overlap 0.7).
const std::string kNadirPlan =
    "frame_width: 400\nframe_height: 300\ngsd: 1.0\nstrips: 2\nstrip_length: 480\n"
    "forward_overlap: 0.7\nside_overlap: 0.3\nseed: 7\n";

SimSource Make(const std::string& yaml) {
  return SimSource({"", yaml, kCanvas, 0});
}

TEST(SimPlanTest, UnknownKeyAndWrongTypeAreErrors) {
  SimPlan plan;
  std::string err;
  EXPECT_FALSE(ParseSimPlan("gsd: 1\nspeed: 3\n", "", &plan, &err));
  EXPECT_NE(err.find("unknown key 'speed'"), std::string::npos) << err;
  EXPECT_FALSE(ParseSimPlan("strips: two\n", "", &plan, &err));
  EXPECT_NE(err.find("'strips' has the wrong type"), std::string::npos) << err;
  EXPECT_FALSE(ParseSimPlan("side_overlap: 1.5\n", "", &plan, &err));
  ASSERT_TRUE(ParseSimPlan("", "", &plan, &err)) << err;  // all defaults
  EXPECT_DOUBLE_EQ(plan.gsd, 1.5);
  SimPlan back;
  plan.tilt_deg = 1.25;
  ASSERT_TRUE(ParseSimPlan(ToYaml(plan), "", &back, &err)) << err;
  EXPECT_DOUBLE_EQ(back.tilt_deg, 1.25);
  // A bad plan makes Open() fail with the message, not throw.
  SimSource src = Make("gsd: -1\n");
  EXPECT_EQ(src.Open(&err), Status::kError);
  EXPECT_NE(err.find("gsd"), std::string::npos) << err;
}

TEST(SimSourceTest, FrameCountAndSpacingFollowTheOverlaps) {
  SimSource src = Make(kNadirPlan);
  std::string err;
  ASSERT_EQ(src.Open(&err), Status::kOk) << err;
  // 480 / (400 * (1 - 0.7)) + 1 = 5 frames per strip.
  ASSERT_EQ(src.NumFrames(), 10u);
  const auto& p = src.poses();
  EXPECT_NEAR((p[1].position - p[0].position).norm(), 120.0, 1e-9);
  EXPECT_NEAR(p[5].position.y() - p[0].position.y(), 210.0, 1e-9);  // 300 * (1 - 0.3)
  // Every footprint is inside the canvas.
  for (size_t i = 0; i < p.size(); ++i) {
    for (const auto& c : Footprint(CanvasFromFrame(src.plan(), p[i]), 400, 300)) {
      EXPECT_GE(c.x, 0.f);
      EXPECT_GE(c.y, 0.f);
      EXPECT_LE(c.x, 999.f);
      EXPECT_LE(c.y, 749.f);
    }
  }
  Frame f;
  int n = 0;
  while (src.Next(&f, &err) == Status::kOk) {
    EXPECT_EQ(f.image.size(), cv::Size(400, 300));
    EXPECT_EQ(f.index, static_cast<uint64_t>(n));
    ++n;
  }
  EXPECT_EQ(n, 10);
}

TEST(SimSourceTest, TooLongPlanIsShrunkIntoTheCanvas) {
  SimSource src = Make("frame_width: 400\nframe_height: 300\ngsd: 1.0\nstrips: 3\nstrip_length: 2000\n");
  std::string err;
  ASSERT_EQ(src.Open(&err), Status::kOk) << err;
  for (const auto& pose : src.poses())
    for (const auto& c : Footprint(CanvasFromFrame(src.plan(), pose), 400, 300)) {
      EXPECT_GE(c.x, 0.f);
      EXPECT_LE(c.x, 999.f);
    }
}

TEST(SimSourceTest, SameSeedSameBytes) {
  const std::string plan = kNadirPlan +
                           "yaw_jitter_deg: 2\nnoise_sigma: 3\nblur_px: 1.5\njpeg_quality: 90\n"
                           "exposure_gain: 0.1\naltitude_change: 0.1\n";
  SimSource a = Make(plan), b = Make(plan);
  std::string err;
  SimSource d = Make(std::string(plan).replace(plan.find("seed: 7"), 7, "seed: 8"));
  ASSERT_EQ(a.Open(&err), Status::kOk) << err;
  ASSERT_EQ(b.Open(&err), Status::kOk) << err;
  ASSERT_EQ(d.Open(&err), Status::kOk) << err;
  Frame fa, fb, fd;
  for (int i = 0; i < 3; ++i) {
    ASSERT_EQ(a.Next(&fa, &err), Status::kOk);
    ASSERT_EQ(b.Next(&fb, &err), Status::kOk);
    ASSERT_EQ(d.Next(&fd, &err), Status::kOk);
    EXPECT_EQ(cv::norm(fa.image, fb.image, cv::NORM_INF), 0.0);
    EXPECT_EQ(a.last_encoded(), b.last_encoded());
    EXPECT_TRUE(a.last_truth().canvas_from_frame == b.last_truth().canvas_from_frame);
  }
  EXPECT_GT(cv::norm(fa.image, fd.image, cv::NORM_INF), 0.0);
}

TEST(SimSourceTest, PixelsAreTheCanvasSampledThroughTheTruth) {
  const cv::Mat canvas = cv::imread(kCanvas, cv::IMREAD_COLOR | cv::IMREAD_IGNORE_ORIENTATION);
  ASSERT_FALSE(canvas.empty());
  SimSource src = Make(kNadirPlan + "yaw_jitter_deg: 5\n");
  std::string err;
  ASSERT_EQ(src.Open(&err), Status::kOk) << err;
  Frame f;
  for (int k = 0; k < 7; ++k) ASSERT_EQ(src.Next(&f, &err), Status::kOk);  // a return-strip frame
  const Mat3 h = src.last_truth().canvas_from_frame;
  for (const auto& p : {Vec2(10, 10), Vec2(200, 150), Vec2(377, 41), Vec2(55, 280), Vec2(390, 290)}) {
    const Vec2 q = Apply(h, p);
    cv::Mat patch;
    cv::getRectSubPix(canvas, cv::Size(1, 1), cv::Point2f(static_cast<float>(q.x()), static_cast<float>(q.y())), patch);
    const cv::Vec3b expect = patch.at<cv::Vec3b>(0, 0);
    const cv::Vec3b got = f.image.at<cv::Vec3b>(static_cast<int>(p.y()), static_cast<int>(p.x()));
    for (int ch = 0; ch < 3; ++ch) EXPECT_NEAR(got[ch], expect[ch], 2) << "at " << p.transpose();
  }
}

TEST(SimSourceTest, TiltMakesTheTruthProjectiveAndTheAffineIsItsBestFit) {
  SimSource src = Make(kNadirPlan + "tilt_deg: 3\n");
  std::string err;
  ASSERT_EQ(src.Open(&err), Status::kOk) << err;
  Frame f;
  ASSERT_EQ(src.Next(&f, &err), Status::kOk);
  const SimTruth t = src.last_truth();
  EXPECT_GT(std::abs(t.canvas_from_frame(2, 0)) + std::abs(t.canvas_from_frame(2, 1)), 1e-6);
  EXPECT_TRUE(IsAffine(t.affine));
  // Least squares: perturbing any affine coefficient makes the grid error larger.
  auto cost = [&](const Mat3& a) {
    double s = 0;
    for (int j = 0; j < 17; ++j)
      for (int i = 0; i < 17; ++i) {
        const Vec2 p(399.0 * i / 16, 299.0 * j / 16);
        s += (Apply(a, p) - Apply(t.canvas_from_frame, p)).squaredNorm();
      }
    return s;
  };
  const double best = cost(t.affine);
  EXPECT_GT(best, 0.0);
  for (int r = 0; r < 2; ++r)
    for (int c = 0; c < 3; ++c)
      for (double d : {-1e-3, 1e-3}) {
        Mat3 a = t.affine;
        a(r, c) += c == 2 ? d * 100 : d;
        EXPECT_GT(cost(a), best);
      }
}

TEST(SimSourceTest, ReturnStripsFaceTheOtherWay) {
  SimSource src = Make(kNadirPlan);
  std::string err;
  ASSERT_EQ(src.Open(&err), Status::kOk) << err;
  Frame f;
  std::vector<double> yaw;
  while (src.Next(&f, &err) == Status::kOk) yaw.push_back(Decompose(src.last_truth().affine).rotation);
  ASSERT_EQ(yaw.size(), 10u);
  for (int i = 0; i < 5; ++i) EXPECT_NEAR(yaw[static_cast<size_t>(i)], 0.0, 1e-9);
  for (int i = 5; i < 10; ++i) EXPECT_NEAR(std::abs(yaw[static_cast<size_t>(i)]), M_PI, 1e-9);
}

// A canvas written to a temporary file (the source reads its canvas from disk); removed by the caller.
std::string WriteCanvas(const std::string& name, const cv::Mat& image) {
  const fs::path path = fs::temp_directory_path() / ("uavm_sim_" + name + "_" + std::to_string(::getpid()) + ".png");
  EXPECT_TRUE(cv::imwrite(path.string(), image));
  return path.string();
}

TEST(SimPlanTest, LensAndRadiometryKeysParseValidateAndRoundTrip) {
  SimPlan plan;
  std::string err;
  ASSERT_TRUE(ParseSimPlan("", "", &plan, &err)) << err;
  EXPECT_EQ(plan.vignetting, 1.0);
  EXPECT_EQ(plan.vignetting_per_channel, 0.0);
  EXPECT_EQ(plan.white_balance, 0.0);
  EXPECT_TRUE(plan.Camera().distortion.IsZero());
  ASSERT_TRUE(
      ParseSimPlan("vignetting: 0.6\nvignetting_per_channel: 0.05\nwhite_balance: 0.1\nk1: -0.1\n"
                   "k2: 0.01\np1: 0.001\np2: -0.002\n",
                   "", &plan, &err))
      << err;
  EXPECT_NEAR(plan.Vignetting(0).At(1.0), 0.6 * 0.95, 1e-12);
  EXPECT_NEAR(plan.Vignetting(1).At(1.0), 0.6, 1e-12);
  EXPECT_NEAR(plan.Vignetting(2).At(1.0), 0.6 * 1.05, 1e-12);
  const PinholeCamera cam = plan.Camera();
  EXPECT_EQ(cam.cx, 199.5);
  EXPECT_EQ(cam.cy, 149.5);
  EXPECT_EQ(cam.focal_px, 400.0);
  EXPECT_EQ(cam.distortion.k1, -0.1);
  EXPECT_EQ(cam.distortion.p2, -0.002);
  SimPlan back;
  ASSERT_TRUE(ParseSimPlan(ToYaml(plan), "", &back, &err)) << err;
  EXPECT_EQ(ToYaml(back), ToYaml(plan));
  EXPECT_EQ(back.k2, 0.01);
  EXPECT_EQ(back.vignetting_per_channel, 0.05);
  for (const char* bad : {"vignetting: 0.1\n", "vignetting: 1.2\n", "vignetting: 0.95\nvignetting_per_channel: 0.1\n",
                          "vignetting_per_channel: -0.1\n", "white_balance: -0.1\n", "white_balance: 0.6\n", "k1: -2\n",
                          "k2: 5\n", "p1: 0.3\n"}) {
    EXPECT_FALSE(ParseSimPlan(bad, "", &plan, &err)) << bad;
    EXPECT_FALSE(err.empty());
  }
  EXPECT_NE(err.find("distortion too strong"), std::string::npos) << err;
}

TEST(SimSourceTest, VignettingDarkensTheCornersToThePlannedRatio) {
  const std::string canvas = WriteCanvas("flat", cv::Mat(750, 1000, CV_8UC3, cv::Scalar(200, 200, 200)));
  SimSource src({"", kNadirPlan + "vignetting: 0.6\n", canvas, 0});
  std::string err;
  ASSERT_EQ(src.Open(&err), Status::kOk) << err;
  Frame f;
  ASSERT_EQ(src.Next(&f, &err), Status::kOk) << err;
  const cv::Scalar centre = cv::mean(f.image(cv::Rect(197, 147, 6, 6)));
  for (const cv::Point corner : {cv::Point(0, 0), cv::Point(397, 0), cv::Point(0, 297), cv::Point(397, 297)}) {
    const cv::Scalar c = cv::mean(f.image(cv::Rect(corner, cv::Size(3, 3))));
    for (int ch = 0; ch < 3; ++ch) EXPECT_NEAR(c[ch] / centre[ch], 0.6, 0.03) << corner << " channel " << ch;
  }
  EXPECT_NEAR(centre[1], 200.0, 1.0);
  fs::remove(canvas);
}

// Issue 37's light: the opposition hotspot and the drone's shadow sit at the antisolar point, fixed on the ground, so
// they move across the frame with its yaw (the return strip sees them on the other side); the falloff may be
// off-centre.
TEST(SimSourceTest, HotspotAndShadowSitAtTheAntisolarPointAndTurnWithTheFrame) {
  const std::string canvas = WriteCanvas("flat150", cv::Mat(750, 1000, CV_8UC3, cv::Scalar(150, 150, 150)));
  SimSource src({"",
                 kNadirPlan + "hotspot: 0.3\nhotspot_width_deg: 5\nsun_elevation_deg: 80\nsun_azimuth_deg: 0\n"
                              "shadow: 0.5\nshadow_radius_px: 5\n",
                 canvas, 0});
  std::string err;
  ASSERT_EQ(src.Open(&err), Status::kOk) << err;
  // Sun at azimuth 0 (canvas +x), 80 deg high: the antisolar point 10 deg off nadir towards canvas -x, f tan(10 deg)
  // = 70.5 px from the centre of a 400 px focal frame: left of centre on the first strip, right on the return one.
  const double off = 400.0 * std::tan(10.0 * M_PI / 180.0);
  Frame f;
  for (size_t i = 0; i < 6; ++i) {
    ASSERT_EQ(src.Next(&f, &err), Status::kOk) << err;
    if (i != 0 && i != 5) continue;
    const double yaw = src.last_truth().pose.yaw_deg;
    const int x = static_cast<int>(std::lround(199.5 + (std::abs(yaw) < 1 ? -off : off)));
    const double shadow = cv::mean(f.image(cv::Rect(x - 1, 148, 3, 3)))[1];
    const double hot = cv::mean(f.image(cv::Rect(x + (x < 200 ? 12 : -12) - 1, 148, 3, 3)))[1];
    const double far = cv::mean(f.image(cv::Rect(x < 200 ? 380 : 10, 140, 10, 20)))[1];
    EXPECT_NEAR(shadow, 150 * 1.3 * 0.5, 3.0) << "frame " << i;  // the hotspot's peak, half of it in shadow
    EXPECT_NEAR(hot, 150 * (1 + 0.3 * std::exp(-std::pow(std::atan(12.0 / 400) / (5 * M_PI / 180), 2) / 2)), 3.0);
    EXPECT_NEAR(far, 150.0, 2.0) << "frame " << i;  // 25+ deg from the antisolar direction: no hotspot left
  }
  fs::remove(canvas);
  // The falloff's centre moved right by a tenth of the half-diagonal: the right edge is brighter than the left.
  const std::string flat = WriteCanvas("flat200", cv::Mat(750, 1000, CV_8UC3, cv::Scalar(200, 200, 200)));
  SimSource shaded({"", kNadirPlan + "vignetting: 0.6\nshading_offset_x: 0.1\n", flat, 0});
  ASSERT_EQ(shaded.Open(&err), Status::kOk) << err;
  ASSERT_EQ(shaded.Next(&f, &err), Status::kOk) << err;
  EXPECT_GT(cv::mean(f.image(cv::Rect(390, 140, 10, 20)))[1], cv::mean(f.image(cv::Rect(0, 140, 10, 20)))[1] + 10);
  fs::remove(flat);
  SimPlan plan;
  for (const char* bad : {"hotspot: 1.5\n", "sun_elevation_deg: 5\n", "shadow: 1\n", "shading_offset_x: 0.7\n"})
    EXPECT_FALSE(ParseSimPlan(bad, "", &plan, &err)) << bad;
}

TEST(SimSourceTest, WhiteBalanceIsPerFrameAndChannelAndLeavesTheOtherDrawsAlone) {
  const std::string canvas = WriteCanvas("flat100", cv::Mat(750, 1000, CV_8UC3, cv::Scalar(100, 100, 100)));
  SimSource src({"", kNadirPlan + "exposure_gain: 0.1\nwhite_balance: 0.2\n", canvas, 0});
  SimSource plain({"", kNadirPlan + "exposure_gain: 0.1\n", canvas, 0});
  std::string err;
  ASSERT_EQ(src.Open(&err), Status::kOk) << err;
  ASSERT_EQ(plain.Open(&err), Status::kOk) << err;
  Frame f;
  for (size_t i = 0; i < 4; ++i) {
    ASSERT_EQ(src.Next(&f, &err), Status::kOk) << err;
    const SimPose& pose = src.last_truth().pose;
    EXPECT_EQ(pose.gain, plain.poses()[i].gain);  // white balance draws from a stream of its own
    const cv::Scalar mean = cv::mean(f.image);
    for (size_t ch = 0; ch < 3; ++ch) {
      EXPECT_NEAR(pose.white_balance[ch], 1.0, 0.2);
      EXPECT_NEAR(mean[static_cast<int>(ch)], 100.0 * pose.gain * pose.white_balance[ch], 0.6) << i << " " << ch;
    }
    EXPECT_NE(pose.white_balance[0], pose.white_balance[2]);
  }
  fs::remove(canvas);
}

// Row (distorted pixels) where a canvas line at ideal row v0 crosses distorted column x, by the lens model alone.
double PredictedRow(const PinholeCamera& cam, double x, double v0) {
  double y = v0;
  for (int it = 0; it < 50; ++it) y -= cam.UndistortPixel(Vec2(x, y)).y() - v0;
  return y;
}

// Darkness-weighted centroid of column x's rows within +-5 of `around`.
double MeasuredRow(const cv::Mat& image, int x, double around) {
  double sw = 0, swy = 0;
  const int y0 = static_cast<int>(std::lround(around));
  for (int y = y0 - 5; y <= y0 + 5; ++y) {
    const double w = std::max(0.0, 230.0 - image.at<cv::Vec3b>(y, x)[1]);
    sw += w;
    swy += w * y;
  }
  return swy / sw;
}

TEST(SimSourceTest, DistortionBowsAStraightCanvasLineAsTheModelPredicts) {
  cv::Mat lines(750, 1000, CV_8UC3, cv::Scalar::all(230));
  for (int y = 30; y + 1 < lines.rows; y += 60) lines.rowRange(y - 1, y + 2).setTo(cv::Scalar::all(20));
  const std::string canvas = WriteCanvas("lines", lines);
  for (const double k1 : {0.0, -0.1}) {
    SimSource src({"", kNadirPlan + "k1: " + std::to_string(k1) + "\n", canvas, 0});
    std::string err;
    ASSERT_EQ(src.Open(&err), Status::kOk) << err;
    Frame f;
    ASSERT_EQ(src.Next(&f, &err), Status::kOk) << err;
    // The canvas line nearest to ideal row 30 of frame 0 (nadir, gsd 1, yaw 0: canvas rows are ideal rows).
    const Mat3 frame_from_canvas = src.last_truth().canvas_from_frame.inverse();
    double v0 = 1e9;
    for (int y = 30; y + 1 < lines.rows; y += 60) {
      const double v = Apply(frame_from_canvas, Vec2(500, y)).y();
      if (std::abs(v - 30) < std::abs(v0 - 30)) v0 = v;
    }
    ASSERT_LT(std::abs(v0 - 30), 31);
    const PinholeCamera cam = src.plan().Camera();
    for (const int x : {3, 100, 200, 300, 396}) {
      const double predicted = PredictedRow(cam, x, v0);
      EXPECT_NEAR(MeasuredRow(f.image, x, predicted), predicted, 0.15) << "k1 " << k1 << " column " << x;
    }
    // The bow, edge against centre: ~3 px towards the centre at the edges for k1 = -0.1, none without distortion.
    const double bow = PredictedRow(cam, 3, v0) - PredictedRow(cam, 200, v0);
    if (k1 == 0.0) {
      EXPECT_NEAR(bow, 0.0, 1e-9);
    } else {
      EXPECT_GT(bow, 2.5);
      std::printf("k1 %.2f: the line at ideal row %.2f bows %.3f px between the edge and the centre column\n", k1, v0,
                  bow);
    }
  }
  fs::remove(canvas);
}

TEST(SimWriterTest, WritesImagesGroundTruthAndPlan) {
  const fs::path dir = fs::temp_directory_path() / ("uavm_sim_writer_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  SimSource src = Make(kNadirPlan + "jpeg_quality: 92\n");
  std::string err;
  ASSERT_EQ(src.Open(&err), Status::kOk) << err;
  ASSERT_TRUE(tools::WriteSimFlight(&src, dir.string(), 4, &err)) << err;
  EXPECT_TRUE(fs::exists(dir / "images" / "frame_000003.jpg"));
  EXPECT_FALSE(fs::exists(dir / "images" / "frame_000004.jpg"));
  std::string text;
  ASSERT_TRUE(ReadTextFile((dir / "gt.csv").string(), &text, &err));
  std::vector<eval::GtRow> rows;
  ASSERT_TRUE(eval::ParseGroundTruthCsv(text, &rows, &err)) << err;
  ASSERT_EQ(rows.size(), 4u);
  EXPECT_EQ(rows[2].filename, "frame_000002.jpg");
  SimPlan plan;
  ASSERT_TRUE(LoadSimPlanFile((dir / "plan.yaml").string(), &plan, &err)) << err;
  EXPECT_EQ(plan.jpeg_quality, 92);
  EXPECT_TRUE(fs::path(plan.canvas).is_absolute());
  // The written JPEG decodes to exactly the emitted frame.
  SimSource again = Make(kNadirPlan + "jpeg_quality: 92\n");
  ASSERT_EQ(again.Open(&err), Status::kOk);
  Frame f;
  ASSERT_EQ(again.Next(&f, &err), Status::kOk);
  const cv::Mat read = cv::imread((dir / "images" / "frame_000000.jpg").string());
  EXPECT_EQ(cv::norm(read, f.image, cv::NORM_INF), 0.0);
  fs::remove_all(dir);
}

TEST(SimWriterTest, WritesTheCameraAndExposureTruth) {
  const fs::path dir = fs::temp_directory_path() / ("uavm_sim_writer_cam_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  SimSource src = Make(kNadirPlan +
                       "k1: -0.1\nvignetting: 0.6\nvignetting_per_channel: 0.05\nexposure_gain: 0.25\n"
                       "exposure_offset: 3\nwhite_balance: 0.1\n");
  std::string err;
  ASSERT_EQ(src.Open(&err), Status::kOk) << err;
  ASSERT_TRUE(tools::WriteSimFlight(&src, dir.string(), 3, &err)) << err;
  std::optional<eval::GtCamera> cam;
  ASSERT_TRUE(eval::LoadGroundTruthCamera((dir / "gt.csv").string(), &cam, &err)) << err;
  ASSERT_TRUE(cam.has_value());
  EXPECT_EQ(cam->camera.distortion.k1, -0.1);
  EXPECT_EQ(cam->camera.cx, 199.5);
  EXPECT_EQ(cam->camera.focal_px, 400.0);
  EXPECT_EQ(cam->half_diagonal_px, 250.0);
  EXPECT_NEAR(cam->vignetting[0].At(1.0), 0.57, 1e-12);
  EXPECT_NEAR(cam->vignetting[2].At(1.0), 0.63, 1e-12);
  std::string text;
  ASSERT_TRUE(ReadTextFile((dir / eval::kGroundTruthExposureFile).string(), &text, &err)) << err;
  std::vector<eval::GtExposure> exposure;
  ASSERT_TRUE(eval::ParseGroundTruthExposure(text, &exposure, &err)) << err;
  ASSERT_EQ(exposure.size(), 3u);
  EXPECT_EQ(exposure[2].filename, "frame_000002.png");
  EXPECT_EQ(exposure[2].gain, src.poses()[2].gain);
  EXPECT_EQ(exposure[2].offset, src.poses()[2].offset);
  EXPECT_EQ(exposure[2].white_balance, src.poses()[2].white_balance);
  // gt.csv itself is as before: old readers still read it.
  ASSERT_TRUE(ReadTextFile((dir / "gt.csv").string(), &text, &err)) << err;
  EXPECT_EQ(text.substr(0, text.find('\n')), eval::kGroundTruthHeader);
  fs::remove_all(dir);
}

}  // namespace
}  // namespace uavm::hal
