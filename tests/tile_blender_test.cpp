#include "core/mosaic/tile_blender.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/stitching/detail/blenders.hpp>
#include <random>

#include "core/buffers/mat_pool.h"
#include "tests/test_env.h"

namespace uavm {
namespace {

struct Piece {
  cv::Mat image;  // CV_8UC3
  cv::Mat mask;   // CV_8U
  cv::Point top_left;
};

// Pieces of a real aerial frame, each owning a random blob of its rectangle, within `roi` (canvas pixels), as the
// compositor feeds them: the owned area plus a margin, edges of the ROI included.
std::vector<Piece> MakePieces(const cv::Mat& ground, const cv::Rect& roi, int count, std::mt19937* rng) {
  std::vector<Piece> pieces;
  std::uniform_int_distribution<int> side(8, std::min({roi.width, roi.height, ground.cols - 20, ground.rows - 20}));
  for (int k = 0; k < count; ++k) {
    const int w = side(*rng);
    const int h = side(*rng);
    std::uniform_int_distribution<int> px(0, roi.width - w);
    std::uniform_int_distribution<int> py(0, roi.height - h);
    const cv::Point at(px(*rng), py(*rng));
    // Parts of larger Mats, as the compositor feeds them: the blender must border the fed pixels alone, not read
    // their surroundings (the ground around the image, a mask of 255 around the mask).
    constexpr int kAround = 10;
    std::uniform_int_distribution<int> gx(kAround, ground.cols - w - kAround);
    std::uniform_int_distribution<int> gy(kAround, ground.rows - h - kAround);
    Piece p;
    p.image = ground(cv::Rect(gx(*rng), gy(*rng), w, h));
    cv::Mat around(h + 2 * kAround, w + 2 * kAround, CV_8U, cv::Scalar(255));
    p.mask = around(cv::Rect(kAround, kAround, w, h));
    p.mask.setTo(0);
    cv::ellipse(p.mask, cv::Point(w / 2, h / 2), cv::Size(std::max(1, w / 3), std::max(1, h / 3)), 30.0 * k, 0, 360,
                cv::Scalar(255), cv::FILLED);
    p.top_left = roi.tl() + at;
    pieces.push_back(p);
  }
  return pieces;
}

void BlendWithOpenCv(const std::vector<Piece>& pieces, const cv::Rect& roi, int bands, cv::Mat* image, cv::Mat* mask) {
  cv::detail::MultiBandBlender blender(false, bands, CV_32F);
  blender.prepare(roi);
  for (const Piece& p : pieces) {
    cv::Mat s16;
    p.image.convertTo(s16, CV_16SC3);
    blender.feed(s16, p.mask, p.top_left);
  }
  cv::Mat result;
  blender.blend(result, *mask);
  result.convertTo(*image, CV_8UC3);
}

// Our multi-band blender against OpenCV's (the reference it follows): the same pixels and coverage, tile after tile
// through one blender whose buffers are reused, grown and reused again at smaller sizes.
TEST(TileBlenderTest, MultiBandMatchesOpenCvsBlenderTileAfterTile) {
  const cv::Mat ground = cv::imread(std::string(UAVM_TEST_DATA) + "/caliterra_small/images/IMG_9360.jpg");
  ASSERT_FALSE(ground.empty());
  std::mt19937 rng(7);
  for (int bands : {5, 3, 0}) {
    auto ours = MakeMultiBandBlender(bands);
    const cv::Rect rois[] = {
        {0, 0, 300, 200}, {1000, 37, 704, 704}, {5, 9, 211, 517}, {-40, 1200, 64, 33}, {300, 300, 512, 511}};
    for (const cv::Rect& roi : rois) {
      const std::vector<Piece> pieces = MakePieces(ground, roi, 6, &rng);
      cv::Mat want_image;
      cv::Mat want_mask;
      BlendWithOpenCv(pieces, roi, bands, &want_image, &want_mask);
      ours->Prepare(roi);
      for (const Piece& p : pieces) ours->Feed(p.image, p.mask, p.top_left);
      cv::Mat image;
      cv::Mat mask;
      ours->Blend(&image, &mask);
      ASSERT_EQ(image.size(), roi.size());
      ASSERT_EQ(image.type(), CV_8UC3);
      EXPECT_EQ(cv::countNonZero(mask != want_mask), 0) << "bands " << bands << " roi " << roi;
      cv::Mat diff;
      cv::absdiff(image, want_image, diff);
      double worst = 0.0;
      cv::minMaxLoc(diff.reshape(1), nullptr, &worst);
      EXPECT_EQ(worst, 0.0) << "bands " << bands << " roi " << roi;
      EXPECT_GT(cv::countNonZero(mask), 0);
    }
  }
}

// The blend is a blend: where two pieces meet, the seam is smooth (no step the size of their difference).
TEST(TileBlenderTest, MultiBandSmoothsAStepAcrossTheSeam) {
  auto blender = MakeMultiBandBlender(5);
  const cv::Rect roi(0, 0, 256, 64);
  blender->Prepare(roi);
  cv::Mat left(64, 256, CV_8UC3, cv::Scalar::all(60));
  cv::Mat right(64, 256, CV_8UC3, cv::Scalar::all(160));
  cv::Mat left_mask = cv::Mat::zeros(64, 256, CV_8U);
  left_mask.colRange(0, 128).setTo(255);
  cv::Mat right_mask = 255 - left_mask;
  blender->Feed(left, left_mask, {0, 0});
  blender->Feed(right, right_mask, {0, 0});
  cv::Mat image;
  cv::Mat mask;
  blender->Blend(&image, &mask);
  EXPECT_EQ(cv::countNonZero(mask), 64 * 256);
  const auto at = [&](int x) { return image.at<cv::Vec3b>(32, x)[0]; };
  EXPECT_NEAR(at(2), 60, 2);
  EXPECT_NEAR(at(253), 160, 2);
  for (int x = 1; x < 256; ++x) EXPECT_LE(std::abs(at(x) - at(x - 1)), 12) << "at x = " << x;
}

// Hard seams: each pixel from the piece that owns it, nothing where no piece does, tile after tile.
TEST(TileBlenderTest, SeamOnlyTakesEachPixelFromItsOwner) {
  auto blender = MakeSeamOnlyBlender();
  for (const cv::Rect& roi : {cv::Rect(10, 20, 100, 50), cv::Rect(0, 0, 40, 30)}) {
    blender->Prepare(roi);
    cv::Mat a(roi.size(), CV_8UC3, cv::Scalar(10, 20, 30));
    cv::Mat b(roi.size(), CV_8UC3, cv::Scalar(200, 100, 50));
    cv::Mat a_mask = cv::Mat::zeros(roi.size(), CV_8U);
    a_mask.colRange(0, roi.width / 2).setTo(255);
    cv::Mat b_mask = cv::Mat::zeros(roi.size(), CV_8U);
    b_mask(cv::Rect(roi.width / 2, 0, roi.width / 2, roi.height / 2)).setTo(255);
    blender->Feed(a, a_mask, roi.tl());
    blender->Feed(b, b_mask, roi.tl());
    cv::Mat image;
    cv::Mat mask;
    blender->Blend(&image, &mask);
    ASSERT_EQ(image.size(), roi.size());
    EXPECT_EQ(image.at<cv::Vec3b>(1, 1), cv::Vec3b(10, 20, 30));
    EXPECT_EQ(image.at<cv::Vec3b>(1, roi.width - 1), cv::Vec3b(200, 100, 50));
    EXPECT_EQ(mask.at<uchar>(roi.height - 1, roi.width - 1), 0);
    EXPECT_EQ(cv::countNonZero(mask), cv::countNonZero(a_mask) + cv::countNonZero(b_mask));
  }
}

// Blends `rois` one after another, each from `pieces_per_roi` pieces and one piece over the whole ROI (the largest a
// tile can feed); returns the blended images, and in *requests the large buffers asked of the pool meanwhile.
std::vector<cv::Mat> BlendTiles(TileBlender* blender, const cv::Mat& ground, const std::vector<cv::Rect>& rois,
                                uint64_t* requests) {
  std::mt19937 rng(11);
  std::vector<std::vector<Piece>> pieces;
  std::vector<cv::Mat> images;
  std::vector<cv::Mat> masks;
  for (const cv::Rect& roi : rois) {  // made before counting: the test's own Mats are not the blender's
    pieces.push_back(MakePieces(ground, roi, 5, &rng));
    Piece whole;
    cv::resize(ground, whole.image, roi.size(), 0, 0, cv::INTER_AREA);
    whole.mask = cv::Mat(roi.size(), CV_8U, cv::Scalar(0));
    cv::circle(whole.mask, {roi.width / 2, roi.height / 2}, std::min(roi.width, roi.height) / 3, cv::Scalar(255), -1);
    whole.top_left = roi.tl();
    pieces.back().push_back(whole);
    images.emplace_back(roi.size(), CV_8UC3);  // the compositor's views: of the ROI's size and type
    masks.emplace_back(roi.size(), CV_8U);
  }
  const MatPoolStats before = InstalledMatPool()->Stats();
  for (size_t t = 0; t < rois.size(); ++t) {
    blender->Prepare(rois[t]);
    for (const Piece& p : pieces[t]) blender->Feed(p.image, p.mask, p.top_left);
    blender->Blend(&images[t], &masks[t]);
  }
  const MatPoolStats after = InstalledMatPool()->Stats();
  *requests = after.hits + after.misses - before.hits - before.misses;
  return images;
}

// Reserved for the largest ROI, a blender asks for no buffer however its tiles and pieces come (its memory is then the
// same at any flight length), and blends the same pixels as one that grows its buffers as pieces come.
TEST(TileBlenderTest, ReservedBuffersServeEveryTileWithoutGrowing) {
  MatPoolOptions pool_options;
  pool_options.min_block_bytes = 4 << 10;  // every buffer counts (ImageBuffer's blocks are whole 4 KiB rows)
  ASSERT_NE(InstallMatPool(pool_options), nullptr);
  const cv::Mat ground = cv::imread(std::string(UAVM_TEST_DATA) + "/caliterra_small/images/IMG_9360.jpg");
  ASSERT_FALSE(ground.empty());
  const cv::Size largest(704, 704);
  // Smaller first, then the largest, then smaller again and odd sizes; every ROI within `largest`.
  const std::vector<cv::Rect> rois = {
      {0, 0, 300, 200}, {37, 1000, 704, 704}, {5, 9, 211, 517}, {-40, 1200, 64, 33}, {300, 300, 703, 701}};
  for (int bands : {5, 0}) {
    auto make = [bands] { return bands > 0 ? MakeMultiBandBlender(bands) : MakeSeamOnlyBlender(); };
    auto growing = make();
    uint64_t growing_requests = 0;
    const std::vector<cv::Mat> want = BlendTiles(growing.get(), ground, rois, &growing_requests);
    EXPECT_GT(growing_requests, 0U) << "bands " << bands << ": the unreserved blender grows (the count can fail)";
    auto reserved = make();
    const MatPoolStats before = InstalledMatPool()->Stats();
    reserved->Reserve(largest);
    const MatPoolStats after = InstalledMatPool()->Stats();
    EXPECT_GT(after.in_use_bytes, before.in_use_bytes) << "bands " << bands;
    uint64_t reserved_requests = 0;
    const std::vector<cv::Mat> got = BlendTiles(reserved.get(), ground, rois, &reserved_requests);
    EXPECT_EQ(reserved_requests, 0U) << "bands " << bands;
    for (size_t t = 0; t < rois.size(); ++t)
      EXPECT_EQ(cv::norm(got[t], want[t], cv::NORM_INF), 0.0) << "bands " << bands << " roi " << rois[t];
  }
}

}  // namespace
}  // namespace uavm
