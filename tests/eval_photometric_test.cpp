#include <gtest/gtest.h>

#include <cmath>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "core/eval/photometric.h"
#include "core/geometry/camera_model.h"

namespace uavm::eval {
namespace {

const std::string kCanvas = std::string(UAVM_TEST_DATA) + "/caliterra_small/images/IMG_9360.jpg";
const double kFootprint = std::sqrt(400.0 * 300.0);  // 400x300 frames at gsd 1

cv::Mat Canvas() {
  return cv::imread(kCanvas, cv::IMREAD_COLOR | cv::IMREAD_IGNORE_ORIENTATION);
}

// The canvas multiplied, cell by cell, by a 0.6-corner vignetting (RadialFalloff::FromCorner) of a w x h frame whose
// centre is at the cell's centre: cells of a whole footprint, or the central part a seam keeps of each frame.
cv::Mat CellPattern(const cv::Mat& canvas, int cell_w, int cell_h) {
  const RadialFalloff v = RadialFalloff::FromCorner(0.6);
  const double half_diagonal = 0.5 * std::hypot(400.0, 300.0);
  cv::Mat pattern(canvas.size(), CV_32FC3);
  for (int y = 0; y < canvas.rows; ++y)
    for (int x = 0; x < canvas.cols; ++x) {
      const double dx = x % cell_w - (cell_w - 1) / 2.0, dy = y % cell_h - (cell_h - 1) / 2.0;
      pattern.at<cv::Vec3f>(y, x) = cv::Vec3f::all(static_cast<float>(v.At(std::hypot(dx, dy) / half_diagonal)));
    }
  cv::Mat out;
  canvas.convertTo(out, CV_32FC3);
  return out.mul(pattern);
}

TEST(PhotometricTest, TheCanvasItselfAndAGlobalGainHaveNoError) {
  const cv::Mat canvas = Canvas();
  ASSERT_FALSE(canvas.empty());
  PhotometricResult r;
  std::string err;
  ASSERT_TRUE(PhotometricError(canvas, Mat3::Identity(), canvas, Mat3::Identity(), kFootprint, &r, &err)) << err;
  EXPECT_LT(r.rms_percent, 0.05);  // the two grids are reduced along different paths
  for (double g : r.gain) EXPECT_NEAR(g, 1.0, 1e-4);
  EXPECT_NEAR(r.sigma_canvas_px, 0.25 * kFootprint, 1e-9);
  EXPECT_GT(r.pixels, 1000);
  // Float, so that x1.3 does not clip: one global gain is all the difference.
  cv::Mat brighter;
  canvas.convertTo(brighter, CV_32FC3, 1.3);
  ASSERT_TRUE(PhotometricError(brighter, Mat3::Identity(), canvas, Mat3::Identity(), kFootprint, &r, &err)) << err;
  EXPECT_LT(r.rms_percent, 0.05);  // the two grids are reduced along different paths
  for (double g : r.gain) EXPECT_NEAR(g, 1.3, 1e-4);
}

TEST(PhotometricTest, AWarpedPartialMosaicIsComparedWhereItWasFlown) {
  const cv::Mat canvas = Canvas();
  ASSERT_FALSE(canvas.empty());
  // mosaic_from_canvas: scale 0.6, 15 degrees, shifted; a hole and the warp's outside are not flown (alpha 0).
  const double c = 0.6 * std::cos(0.26), s = 0.6 * std::sin(0.26);
  Mat3 mosaic_from_canvas;
  mosaic_from_canvas << c, -s, 200, s, c, 10, 0, 0, 1;
  cv::Mat bgra, alpha;
  cv::cvtColor(canvas, bgra, cv::COLOR_BGR2BGRA);
  cv::warpPerspective(bgra, bgra, ToCv(mosaic_from_canvas), cv::Size(800, 700), cv::INTER_LINEAR, cv::BORDER_CONSTANT);
  cv::extractChannel(bgra, alpha, 3);
  alpha.setTo(0, alpha < 255);
  alpha(cv::Rect(300, 300, 120, 80)).setTo(0);
  bgra(cv::Rect(300, 300, 120, 80)).setTo(cv::Scalar::all(0));
  cv::insertChannel(alpha, bgra, 3);
  // The quick-look convention: an image at half the mosaic's size.
  cv::Mat half;
  cv::resize(bgra, half, cv::Size(400, 350), 0, 0, cv::INTER_AREA);
  PhotometricResult r;
  std::string err;
  ASSERT_TRUE(PhotometricError(half, ResizeMap(2.0, 2.0), canvas, mosaic_from_canvas.inverse(), kFootprint, &r, &err))
      << err;
  std::printf("warped partial mosaic: %.4f %% RMS over %ld grid px\n", r.rms_percent, r.pixels);
  EXPECT_LT(r.rms_percent, 0.5);
  for (double g : r.gain) EXPECT_NEAR(g, 1.0, 0.01);
}

TEST(PhotometricTest, AVignettingPatternRepeatedPerFootprintIsClearlyAnError) {
  const cv::Mat canvas = Canvas();
  ASSERT_FALSE(canvas.empty());
  PhotometricResult r;
  std::string err;
  ASSERT_TRUE(
      PhotometricError(CellPattern(canvas, 400, 300), Mat3::Identity(), canvas, Mat3::Identity(), kFootprint, &r, &err))
      << err;
  std::printf("0.6 vignetting per 400x300 footprint: %.3f %% RMS (gain %.3f)\n", r.rms_percent, r.gain[1]);
  EXPECT_GT(r.rms_percent, 3.0);
  EXPECT_LT(r.gain[1], 0.95);  // the pattern's mean brightness went into the gain
  // What a seamed mosaic keeps of each frame: its central 120x210 (the frame spacing of a 0.7/0.3-overlap flight).
  for (double fraction : {0.25, 0.125, 0.0625}) {
    PhotometricOptions options;
    options.sigma_footprint_fraction = fraction;
    ASSERT_TRUE(PhotometricError(CellPattern(canvas, 120, 210), Mat3::Identity(), canvas, Mat3::Identity(), kFootprint,
                                 &r, &err, options))
        << err;
    std::printf("0.6 vignetting, central 120x210 cells, sigma %.4f footprint: %.3f %% RMS\n", fraction, r.rms_percent);
  }
}

TEST(PhotometricTest, OptionsAreChecked) {
  PhotometricOptions o;
  std::string err;
  EXPECT_TRUE(o.Check(&err));
  o.sigma_footprint_fraction = 0;
  EXPECT_FALSE(o.Check(&err));
  o = {};
  o.dark_floor = 1.5;
  EXPECT_FALSE(o.Check(&err));
  const cv::Mat canvas = Canvas();
  PhotometricResult r;
  cv::Mat unflown(100, 100, CV_8UC4, cv::Scalar::all(0));
  EXPECT_FALSE(PhotometricError(unflown, Mat3::Identity(), canvas, Mat3::Identity(), kFootprint, &r, &err));
  EXPECT_NE(err.find("covers none"), std::string::npos) << err;
}

}  // namespace
}  // namespace uavm::eval
