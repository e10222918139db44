// The operator's live picture: each thumbnail is pasted where its transform puts it, and a paste works on the
// thumbnail's box only (no canvas-sized buffer per frame), giving the picture a whole-canvas warp gives.
#include "core/mosaic/live_preview.h"

#include <gtest/gtest.h>

#include <cmath>
#include <opencv2/imgproc.hpp>
#include <vector>

#include "core/buffers/mat_pool.h"

namespace uavm {
namespace {

constexpr int kSide = 512;

cv::Mat Texture(int width, int height, int seed) {
  cv::Mat image(height, width, CV_8UC3);
  cv::RNG rng(static_cast<uint64_t>(seed));
  rng.fill(image, cv::RNG::UNIFORM, 0, 256);
  cv::GaussianBlur(image, image, cv::Size(0, 0), 1.5);
  return image;
}

Mat3 Rotation(double degrees, double cx, double cy) {
  const double a = degrees * M_PI / 180.0;
  Mat3 r = Mat3::Identity();
  r << std::cos(a), -std::sin(a), 0, std::sin(a), std::cos(a), 0, 0, 0, 1;
  return Translation(cx, cy) * r * Translation(-cx, -cy);
}

// The paste as a whole-canvas warp (what LivePreview did before it warped the thumbnail's box only).
void PasteWholeCanvas(const cv::Mat& thumb, const Mat3& view_from_thumb, cv::Mat* canvas) {
  const cv::Mat mask(thumb.size(), CV_8U, cv::Scalar(255));
  cv::Mat warped;
  cv::Mat warped_mask;
  if (IsAffine(view_from_thumb)) {
    cv::warpAffine(thumb, warped, cv::Mat(ToCvAffine(view_from_thumb)), canvas->size(), cv::INTER_LINEAR);
    cv::warpAffine(mask, warped_mask, cv::Mat(ToCvAffine(view_from_thumb)), canvas->size(), cv::INTER_NEAREST);
  } else {
    cv::warpPerspective(thumb, warped, cv::Mat(ToCv(view_from_thumb)), canvas->size(), cv::INTER_LINEAR);
    cv::warpPerspective(mask, warped_mask, cv::Mat(ToCv(view_from_thumb)), canvas->size(), cv::INTER_NEAREST);
  }
  cv::erode(warped_mask, warped_mask, cv::Mat());
  warped.copyTo(*canvas, warped_mask);
}

// The view a preview picks for its first paste when the footprint, with its 25 % room, fits the canvas at scale 1:
// the translation that centres the footprint's bounding box.
Mat3 ViewOfFirstPaste(const cv::Mat& thumb, const Mat3& mosaic_from_thumb) {
  const cv::Rect2d fp = cv::boundingRect(Footprint(mosaic_from_thumb, thumb.cols, thumb.rows));
  EXPECT_LT(1.25 * std::max(fp.width, fp.height), kSide);
  return Translation(kSide / 2.0 - (fp.x + fp.width / 2), kSide / 2.0 - (fp.y + fp.height / 2));
}

using Pastes = std::vector<std::pair<cv::Mat, Mat3>>;

// Pastes `pastes` into a preview and into a whole canvas; returns the preview's large buffers (pool requests).
uint64_t PasteBoth(const Pastes& pastes, cv::Mat* preview_image, cv::Mat* expected) {
  MatPoolOptions pool_options;
  pool_options.min_block_bytes = 200 << 10;  // the canvas (768 KiB) and a whole-canvas mask (256 KiB) count
  const MatPool* pool = InstallMatPool(pool_options);
  const Mat3 view_from_mosaic = ViewOfFirstPaste(pastes.front().first, pastes.front().second);
  const MatPoolStats before = pool->Stats();
  LivePreview preview(kSide);
  for (const auto& [thumb, mosaic_from_thumb] : pastes) preview.Add(thumb, mosaic_from_thumb);
  const MatPoolStats after = pool->Stats();
  *preview_image = preview.image().clone();
  *expected = cv::Mat(kSide, kSide, CV_8UC3, cv::Scalar::all(0));
  for (const auto& [thumb, mosaic_from_thumb] : pastes)
    PasteWholeCanvas(thumb, view_from_mosaic * mosaic_from_thumb, expected);
  return after.hits + after.misses - before.hits - before.misses;
}

struct Difference {
  double max = 0;
  int differing = 0;  // samples (pixel channels)
  int covered = 0;    // samples the whole-canvas paste wrote something into
};

Difference Compare(const cv::Mat& image, const cv::Mat& expected) {
  Difference d;
  cv::Mat diff;
  cv::absdiff(image, expected, diff);
  cv::minMaxLoc(diff.reshape(1), nullptr, &d.max);
  d.differing = cv::countNonZero(diff.reshape(1) > 0);
  d.covered = cv::countNonZero(expected.reshape(1) > 0);
  return d;
}

TEST(LivePreviewTest, PastesTheThumbnailsBoxOnlyWithTheWholeCanvasPicture) {
  Mat3 mosaic_from_third = Translation(950, 1960);
  mosaic_from_third(2, 0) = 2e-4;  // a tilted view: the perspective warp
  mosaic_from_third(2, 1) = -1e-4;
  const Pastes pastes = {{Texture(200, 150, 1), Translation(1000, 2000)},
                         {Texture(120, 90, 2), Translation(1150, 2040) * Rotation(20, 60, 45)},
                         {Texture(160, 100, 3), mosaic_from_third}};
  cv::Mat image;
  cv::Mat expected;
  EXPECT_EQ(PasteBoth(pastes, &image, &expected), 1u) << "only the canvas itself is canvas-sized";
  const Difference d = Compare(image, expected);
  EXPECT_GT(d.covered, 3 * 200 * 150);  // the pictures are there: at least the first thumbnail's samples
  // The box's warp starts from another origin: a fixed-point sample position may round the other way (measured: by 1
  // level, in 0.11 % of the samples).
  EXPECT_LE(d.max, 1.0);
  EXPECT_LT(d.differing, d.covered / 500) << d.differing << " of " << d.covered << " samples differ";
}

// Magnified 5x and turned 45 degrees, a thumbnail's nearest-neighbour mask reaches ~3.5 px beyond its corner pixels'
// centres: the box must hold it and its eroded rim.
TEST(LivePreviewTest, AMagnifiedTurnedPasteKeepsItsEdges) {
  const Mat3 magnified = Translation(800, 600) * Rotation(45, 0, 0) * ResizeMap(5.0, 5.0);
  const Pastes pastes = {{Texture(40, 30, 4), magnified}};
  cv::Mat image;
  cv::Mat expected;
  EXPECT_EQ(PasteBoth(pastes, &image, &expected), 1u);
  const Difference d = Compare(image, expected);
  EXPECT_GT(d.covered, 3 * 40 * 30 * 20);  // ~25x the thumbnail's area
  // Measured: 24 samples differ by 1 level (rounding, as above); 456 with a box around the corner pixels' centres.
  EXPECT_LE(d.max, 1.0);
  EXPECT_LT(d.differing, d.covered / 1000) << d.differing << " of " << d.covered << " samples differ";
}

}  // namespace
}  // namespace uavm
