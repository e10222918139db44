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

TEST(LivePreviewTest, PastesTheThumbnailsBoxOnlyWithTheWholeCanvasPicture) {
  MatPoolOptions pool_options;
  pool_options.min_block_bytes = 200 << 10;  // the canvas (768 KiB) and a whole-canvas mask (256 KiB) count
  MatPool* pool = InstallMatPool(pool_options);
  ASSERT_EQ(pool->Stats().hits + pool->Stats().misses, 0u);

  // The first thumbnail's box, 1.25x, fits the view at scale 1: the view is a translation that centres it.
  const cv::Mat first = Texture(200, 150, 1);
  const Mat3 mosaic_from_first = Translation(1000, 2000);
  const Mat3 view_from_mosaic = Translation(kSide / 2.0 - 1100, kSide / 2.0 - 2075);
  const cv::Mat second = Texture(120, 90, 2);
  const Mat3 mosaic_from_second = Translation(1150, 2040) * Rotation(20, 60, 45);
  Mat3 mosaic_from_third = Translation(950, 1960);
  mosaic_from_third(2, 0) = 2e-4;  // a tilted view: the perspective warp
  mosaic_from_third(2, 1) = -1e-4;
  const cv::Mat third = Texture(160, 100, 3);
  const std::vector<std::pair<cv::Mat, Mat3>> pastes = {
      {first, mosaic_from_first}, {second, mosaic_from_second}, {third, mosaic_from_third}};

  LivePreview preview(kSide);
  for (const auto& [thumb, mosaic_from_thumb] : pastes) preview.Add(thumb, mosaic_from_thumb);
  const MatPoolStats stats = pool->Stats();
  EXPECT_EQ(stats.hits + stats.misses, 1u) << "only the canvas itself is canvas-sized";

  cv::Mat expected(kSide, kSide, CV_8UC3, cv::Scalar::all(0));
  for (const auto& [thumb, mosaic_from_thumb] : pastes)
    PasteWholeCanvas(thumb, view_from_mosaic * mosaic_from_thumb, &expected);
  cv::Mat diff;
  cv::absdiff(preview.image(), expected, diff);
  double max_diff = 0;
  cv::minMaxLoc(diff.reshape(1), nullptr, &max_diff);
  const int covered = cv::countNonZero(cv::Mat(expected.reshape(1) > 0));
  const int differing = cv::countNonZero(diff.reshape(1) > 0);
  EXPECT_GT(covered, 3 * 200 * 150);  // the pictures are there: all three thumbnails' samples
  // The box's warp starts from another origin: the fixed-point sample positions may round the other way.
  EXPECT_LE(max_diff, 2.0);
  EXPECT_LT(differing, covered / 100) << differing << " of " << covered << " samples differ";
}

}  // namespace
}  // namespace uavm
