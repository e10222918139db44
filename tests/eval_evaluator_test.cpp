#include <gtest/gtest.h>

#include <cmath>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "core/eval/evaluator.h"
#include "core/eval/ground_truth.h"
#include "core/eval/image_score.h"
#include "hal/sim/sim_plan.h"
#include "tests/test_image.h"

namespace uavm::eval {
namespace {

const std::string kCanvas = std::string(UAVM_TEST_DATA) + "/caliterra_small/images/IMG_9360.jpg";
const cv::Size kFrame(400, 300);

// Ground truth of a 15-frame flight (3 strips of 5) over the 1000x750 canvas, without rendering; or of a longer one
// (`strips` strips of `strip_length`) over a canvas that holds it.
std::vector<GtRow> Flight(double tilt_deg, double yaw_jitter_deg = 3.0, int strips = 3, int strip_length = 480) {
  hal::SimPlan plan;
  std::string err;
  std::string yaml = "frame_width: 400\ngsd: 1.0\nframe_height: 300\nstrips: ";
  yaml.append(std::to_string(strips)).append("\nstrip_length: ").append(std::to_string(strip_length)).append("\n");
  // Appends, not operator+ on a literal: GCC 12 warns falsely (-Wrestrict) on the latter.
  yaml.append("altitude_change: 0.05\nyaw_jitter_deg: ").append(std::to_string(yaw_jitter_deg));
  yaml.append("\ntilt_deg: ").append(std::to_string(tilt_deg)).append("\n");
  EXPECT_TRUE(hal::ParseSimPlan(yaml, "", &plan, &err)) << err;
  std::vector<hal::SimPose> poses;
  std::string note;
  const cv::Size canvas(std::max(1000, strip_length + 520), std::max(750, strips * 210 + 540));
  EXPECT_TRUE(hal::BuildFlight(plan, canvas, &poses, &note, &err)) << err;
  std::vector<GtRow> gt;
  for (size_t i = 0; i < poses.size(); ++i) {
    const Mat3 h = hal::CanvasFromFrame(plan, poses[i]);
    const std::string name = std::string("f").append(std::to_string(i)).append(".png");
    gt.push_back({static_cast<int>(i), name, h, ClosestAffine(h, 400, 300)});
  }
  return gt;
}

// An arbitrary similarity standing in for the mosaic's own frame: scale 0.5, 20 degrees, offset.
Mat3 MosaicFromCanvas() {
  const double c = 0.5 * std::cos(0.35), s = 0.5 * std::sin(0.35);
  Mat3 m;
  m << c, -s, 120.0, s, c, -40.0, 0, 0, 1;
  return m;
}

std::vector<TransformRow> SessionFrom(const std::vector<GtRow>& gt) {
  std::vector<TransformRow> rows;
  for (const auto& g : gt)
    rows.push_back({g.index, g.filename, true, MosaicFromCanvas() * g.canvas_from_frame, "image"});
  return rows;
}

TEST(GroundTruthCsvTest, RoundTripsExactly) {
  const auto gt = Flight(2.0);
  std::vector<GtRow> back;
  std::string err;
  ASSERT_TRUE(ParseGroundTruthCsv(FormatGroundTruthCsv(gt), &back, &err)) << err;
  ASSERT_EQ(back.size(), gt.size());
  EXPECT_TRUE(back[3].canvas_from_frame == gt[3].canvas_from_frame);
  EXPECT_TRUE(back[3].affine == gt[3].affine);
  EXPECT_FALSE(ParseGroundTruthCsv("index,filename\n", &back, &err));
}

TEST(EvaluatorTest, TheTruthItselfHasNoError) {
  const auto gt = Flight(1.5);
  EvalResult r;
  std::string err;
  ASSERT_TRUE(EvaluateSession(SessionFrom(gt), gt, kFrame, &r, &err)) << err;
  EXPECT_EQ(r.registered, 15);
  EXPECT_DOUBLE_EQ(r.registered_share, 1.0);
  EXPECT_LT(r.rms_px, 1e-6);
  EXPECT_LT(r.max_px, 1e-6);
  EXPECT_LT((r.canvas_from_mosaic - MosaicFromCanvas().inverse()).norm(), 1e-6);
}

TEST(EvaluatorTest, AKnownShiftOfOneFrameShowsOnThatFrame) {
  const auto gt = Flight(0.0);
  auto session = SessionFrom(gt);
  session[7].mosaic_from_frame = session[7].mosaic_from_frame * Translation(2.0, 0.0);  // 2 frame px
  session[11].registered = false;
  EvalResult r;
  std::string err;
  ASSERT_TRUE(EvaluateSession(session, gt, kFrame, &r, &err)) << err;
  EXPECT_EQ(r.registered, 14);
  EXPECT_NEAR(r.registered_share, 14.0 / 15.0, 1e-12);
  // One global least-squares fit over 14 frames absorbs about 1/14 of the shift.
  EXPECT_NEAR(r.per_frame[7].rms_px, 2.0, 0.25);
  for (size_t i = 0; i < r.per_frame.size(); ++i) {
    if (i == 7) continue;
    EXPECT_LT(r.per_frame[i].rms_px, 0.25) << i;
  }
  EXPECT_FALSE(r.per_frame[11].registered);
  EXPECT_GT(r.per_frame[14].path_length_px, r.per_frame[13].path_length_px);
}

TEST(EvaluatorTest, PairsByIndexWhenNamesDiffer) {
  const auto gt = Flight(0.0);
  auto session = SessionFrom(gt);
  for (auto& row : session) row.filename = "renamed.jpg";
  EvalResult r;
  std::string err;
  ASSERT_TRUE(EvaluateSession(session, gt, kFrame, &r, &err)) << err;
  EXPECT_LT(r.rms_px, 1e-6);
}

TEST(EvaluatorTest, AffineFloorIsZeroForNadirAndPositiveForTilt) {
  EvalResult nadir, tilted;
  std::string err;
  const auto gn = Flight(0.0);
  const auto gtl = Flight(1.0);
  ASSERT_TRUE(EvaluateSession(AffineFloorSession(gn), gn, kFrame, &nadir, &err)) << err;
  ASSERT_TRUE(EvaluateSession(AffineFloorSession(gtl), gtl, kFrame, &tilted, &err)) << err;
  EXPECT_LT(nadir.rms_px, 1e-6);
  EXPECT_GT(tilted.rms_px, 0.05);
  EXPECT_GT(tilted.max_px, tilted.rms_px);
  std::printf("affine floor at 1 deg tilt: rms %.4f max %.4f px\n", tilted.rms_px, tilted.max_px);
  const auto j = ToJson(nadir, &tilted);
  EXPECT_EQ(j["per_frame"].size(), 15u);
  EXPECT_DOUBLE_EQ(j["affine_floor_rms_px"].get<double>(), tilted.rms_px);
}

TEST(GroundTruthCsvTest, CameraAndExposureRoundTripExactly) {
  GtCamera cam;
  cam.camera = PinholeCamera::Centred(400, 300, 412.5, {-0.1, 0.013, 1e-4, -2e-4});
  cam.half_diagonal_px = 250.0;
  cam.vignetting = {RadialFalloff::FromCorner(0.57), RadialFalloff::FromCorner(0.6), RadialFalloff::FromCorner(0.63)};
  GtCamera back;
  std::string err;
  ASSERT_TRUE(ParseGroundTruthCamera(FormatGroundTruthCamera(cam), &back, &err)) << err;
  EXPECT_EQ(back.camera.focal_px, 412.5);
  EXPECT_EQ(back.camera.cy, 149.5);
  EXPECT_EQ(back.camera.distortion.k2, 0.013);
  EXPECT_EQ(back.camera.distortion.p2, -2e-4);
  EXPECT_EQ(back.vignetting[2].a1, cam.vignetting[2].a1);
  EXPECT_EQ(back.vignetting[0].a2, cam.vignetting[0].a2);
  PinholeCamera only;
  ASSERT_TRUE(ParseCameraBlock(FormatGroundTruthCamera(cam), &only, &err)) << err;
  EXPECT_EQ(only.distortion.k1, -0.1);
  EXPECT_FALSE(ParseGroundTruthCamera("camera: {width: 4}\n", &back, &err));
  const std::vector<GtExposure> rows{{0, "a.png", 1.2, -3.5, {0.9, 1.0, 1.1}}, {1, "b.png", 0.8, 0.0, {1, 1, 1}}};
  std::vector<GtExposure> rows_back;
  ASSERT_TRUE(ParseGroundTruthExposure(FormatGroundTruthExposure(rows), &rows_back, &err)) << err;
  ASSERT_EQ(rows_back.size(), 2u);
  EXPECT_EQ(rows_back[0].offset, -3.5);
  EXPECT_EQ(rows_back[0].white_balance[2], 1.1);
  EXPECT_EQ(rows_back[1].filename, "b.png");
  EXPECT_FALSE(ParseGroundTruthExposure("index,filename,gain\n", &rows_back, &err));
}

// k1 = -0.1 on the 400x300 frames at the default focal (400 px): corners 3.9 % = 9.8 px towards the centre.
PinholeCamera Barrel() {
  return PinholeCamera::Centred(400, 300, 400.0, {-0.1, 0.0, 0.0, 0.0});
}

TEST(EvaluatorTest, AMosaickerThatIgnoresTheLensShowsTheDistortionDisplacement) {
  // A flight wide enough (8 strips of 25 frames) that the global mosaic->canvas fit cannot absorb the lens by a
  // scale change (over the 15-frame flight it absorbs a good part of it).
  const auto gt = Flight(0.0, 3.0, 8, 2880);
  EvalOptions options;
  options.truth_camera = Barrel();
  // Analytic: a frame pixel p really shows the canvas at the truth's map of undistort(p), the session puts it at the
  // map of p: the error is |p - undistort(p)| (gsd 1, nadir; the altitude change scales both alike).
  double sum_sq = 0.0, worst = 0.0;
  for (int j = 0; j < 9; ++j)
    for (int i = 0; i < 9; ++i) {
      const Vec2 p(399.0 * i / 8, 299.0 * j / 8);
      const double d = (Barrel().UndistortPixel(p) - p).norm();
      sum_sq += d * d;
      worst = std::max(worst, d);
    }
  const double analytic_rms = std::sqrt(sum_sq / 81.0);
  EvalResult r;
  std::string err;
  ASSERT_TRUE(EvaluateSession(SessionFrom(gt), gt, kFrame, &r, &err, options)) << err;
  std::printf("k1 -0.1 ignored: rms %.4f px (analytic %.4f), max %.4f px (analytic %.4f)\n", r.rms_px, analytic_rms,
              r.max_px, worst);
  EXPECT_GT(analytic_rms, 3.0);
  EXPECT_NEAR(r.rms_px, analytic_rms, 0.05 * analytic_rms);
  EXPECT_NEAR(r.max_px, worst, 0.1 * worst);
  // A session whose transforms act on undistorted pixels, and says so, has no error.
  options.session_camera = Barrel();
  ASSERT_TRUE(EvaluateSession(SessionFrom(gt), gt, kFrame, &r, &err, options)) << err;
  EXPECT_LT(r.rms_px, 1e-6);
  EXPECT_LT(r.max_px, 1e-6);
}

TEST(EvaluatorTest, ACameraWithoutDistortionChangesNothing) {
  const auto gt = Flight(1.0);
  auto session = SessionFrom(gt);
  session[4].mosaic_from_frame = session[4].mosaic_from_frame * Translation(1.5, -0.5);
  EvalOptions ideal;
  ideal.truth_camera = PinholeCamera::Centred(400, 300, 400.0, {});
  ideal.session_camera = ideal.truth_camera;
  EvalResult plain, with_camera;
  std::string err;
  ASSERT_TRUE(EvaluateSession(session, gt, kFrame, &plain, &err)) << err;
  ASSERT_TRUE(EvaluateSession(session, gt, kFrame, &with_camera, &err, ideal)) << err;
  EXPECT_EQ(plain.rms_px, with_camera.rms_px);
  EXPECT_EQ(plain.max_px, with_camera.max_px);
  EXPECT_EQ(plain.drift_slope_px_per_kpx, with_camera.drift_slope_px_per_kpx);
}

TEST(ImageScoreTest, AnAffineWarpOfTheCanvasScoresBelowOnePixel) {
  const cv::Mat canvas =
      test::ScaledForEmulation(cv::imread(kCanvas, cv::IMREAD_COLOR | cv::IMREAD_IGNORE_ORIENTATION));
  ASSERT_FALSE(canvas.empty());
  const double k = test::EmulationImageScale();  // half size under emulation: shift, size and test points with it
  // mosaic_from_canvas: scale 0.8, 12 degrees, shift.
  const double c = 0.8 * std::cos(0.21), s = 0.8 * std::sin(0.21);
  const cv::Matx23d a(c, -s, 150.0 * k, s, c, 20.0 * k);
  cv::Mat mosaic;
  cv::warpAffine(canvas, mosaic, a, cv::Size(static_cast<int>(1100 * k), static_cast<int>(900 * k)), cv::INTER_LINEAR,
                 cv::BORDER_CONSTANT);
  cv::Mat alpha;
  cv::warpAffine(cv::Mat(canvas.size(), CV_8U, cv::Scalar(255)), alpha, a, mosaic.size(), cv::INTER_NEAREST);
  cv::Mat bgra;
  cv::cvtColor(mosaic, bgra, cv::COLOR_BGR2BGRA);
  cv::insertChannel(alpha, bgra, 3);
  ImageScore score;
  std::string err;
  ASSERT_TRUE(ScoreMosaicImage(bgra, canvas, &score, &err)) << err;
  std::printf("image score: %d matches, %d inliers, median %.3f p90 %.3f px\n", score.matches, score.inliers,
              score.median_px, score.p90_px);
  EXPECT_GT(score.inliers, 100);
  EXPECT_LT(score.median_px, 1.0);
  // The fitted affine is the inverse of the warp.
  Mat3 m = Mat3::Identity();
  m.topRows<2>() << a(0, 0), a(0, 1), a(0, 2), a(1, 0), a(1, 1), a(1, 2);
  const Mat3 expect = m.inverse();
  for (const auto& p : {Vec2(100 * k, 100 * k), Vec2(900 * k, 700 * k)})
    EXPECT_LT((Apply(score.canvas_from_mosaic, p) - Apply(expect, p)).norm(), 1.0);
}

}  // namespace
}  // namespace uavm::eval
