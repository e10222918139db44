#include "core/pipeline/canvas_load.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "core/pipeline/stored_frame.h"

namespace uavm {
namespace {

const std::string kFrame = std::string(UAVM_TEST_DATA) + "/caliterra_small/images/IMG_9360.jpg";  // 1000 x 750
const cv::Size kOriginal(1000, 750);

TEST(CanvasLoadTest, PlanUsesDctScalingAndResizesOnlyWhenFiner) {
  const CanvasLoad half = PlanCanvasLoad(kFrame, kOriginal, 0.5);
  EXPECT_EQ(half.reduce, 2);
  EXPECT_EQ(half.size, cv::Size(500, 375));  // used as decoded
  EXPECT_TRUE(half.jpeg);
  const CanvasLoad fine = PlanCanvasLoad(kFrame, kOriginal, 0.7);
  EXPECT_EQ(fine.reduce, 1);
  EXPECT_EQ(fine.size, cv::Size(700, 525));
  const CanvasLoad resized = PlanCanvasLoad(kFrame, kOriginal, 0.35);
  EXPECT_EQ(resized.reduce, 2);
  EXPECT_EQ(resized.decoded, cv::Size(500, 375));
  EXPECT_EQ(resized.size, cv::Size(350, 263));
  // 1.2x coarser than the canvas is accepted for a cheaper decode.
  const CanvasLoad coarse = PlanCanvasLoad(kFrame, kOriginal, 0.3);
  EXPECT_EQ(coarse.reduce, 4);
  EXPECT_EQ(coarse.size, cv::Size(250, 188));
  EXPECT_FALSE(PlanCanvasLoad("/x/frame.png", kOriginal, 0.5).jpeg);
}

// Samples `part` at the whole load's pixel positions of `need` (bilinear: a resized part's origin is fractional) and
// returns the mean and largest absolute difference to the whole load there.
std::pair<double, double> PartAgainstWhole(const FramePart& part, const cv::Mat& whole, const cv::Rect& need) {
  cv::Mat map_x(need.size(), CV_32F);
  cv::Mat map_y(need.size(), CV_32F);
  for (int r = 0; r < need.height; ++r)
    for (int c = 0; c < need.width; ++c) {
      map_x.at<float>(r, c) = static_cast<float>(need.x + c - part.origin.x);
      map_y.at<float>(r, c) = static_cast<float>(need.y + r - part.origin.y);
    }
  cv::Mat sampled;
  cv::remap(part.image, sampled, map_x, map_y, cv::INTER_LINEAR, cv::BORDER_CONSTANT, cv::Scalar::all(0));
  cv::Mat diff;
  cv::absdiff(sampled, whole(need), diff);
  double max_diff = 0;
  cv::minMaxLoc(diff.reshape(1), nullptr, &max_diff);
  const cv::Scalar mean = cv::mean(diff);
  return {(mean[0] + mean[1] + mean[2]) / 3, max_diff};
}

TEST(CanvasLoadTest, PartsHoldTheWholeLoadsPixels) {
  for (double keep : {0.7, 0.5, 0.35, 0.3}) {
    const CanvasLoad how = PlanCanvasLoad(kFrame, kOriginal, keep);
    const cv::Mat whole = LoadStoredFrame(kFrame, how.size, how.reduce);
    ASSERT_EQ(whole.size(), how.size);
    for (const cv::Rect& need :
         {cv::Rect(37, 29, how.size.width / 3, how.size.height / 4),
          cv::Rect(how.size.width / 2, how.size.height / 2, how.size.width / 2, how.size.height / 2),
          cv::Rect(cv::Point(), how.size)}) {
      const FramePart part = LoadCanvasPart(kFrame, how, need);
      ASSERT_FALSE(part.image.empty());
      // The part covers what was asked for, and not much more (at most an MCU column and the resize's margin).
      EXPECT_LE(part.origin.x, need.x);
      EXPECT_LE(part.origin.y, need.y);
      // (A resized part may stop short of the frame's last pixel by less than one: the warp reflects there.)
      EXPECT_GE(part.origin.x + part.image.cols, std::min<double>(need.br().x, how.size.width - 1)) << keep << need;
      EXPECT_GE(part.origin.y + part.image.rows, std::min<double>(need.br().y, how.size.height - 1)) << keep << need;
      EXPECT_LE(part.image.cols, need.width + 40);
      EXPECT_LE(part.image.rows, need.height + 8);
      const auto [mean, max] = PartAgainstWhole(part, whole, need);
      if (how.size == how.decoded) {
        EXPECT_EQ(max, 0.0) << "a part used as decoded is the whole decode's pixels, keep " << keep;
      } else {
        // Resampled at a fractional offset: texture differs a little, never systematically.
        EXPECT_LT(mean, 1.5) << "keep " << keep << " need " << need;
        // and that is the texture, not a misplaced origin: half a pixel off is clearly worse.
        FramePart shifted = part;
        shifted.origin += cv::Point2d(0.5, 0.5);
        EXPECT_GT(PartAgainstWhole(shifted, whole, need).first, 1.5 * mean) << "keep " << keep << " need " << need;
      }
    }
  }
}

TEST(CanvasLoadTest, OtherFormatsLoadWhole) {
  const auto png = std::filesystem::temp_directory_path() / ("uavm_canvas_load_" + std::to_string(::getpid()) + ".png");
  ASSERT_TRUE(cv::imwrite(png.string(), cv::imread(kFrame)));
  const CanvasLoad how = PlanCanvasLoad(png.string(), kOriginal, 0.5);
  const FramePart part = LoadCanvasPart(png.string(), how, cv::Rect(10, 10, 50, 50));
  EXPECT_EQ(part.image.size(), how.size);
  EXPECT_EQ(part.origin, cv::Point2d());
  std::filesystem::remove(png);
}

}  // namespace
}  // namespace uavm
