#include "core/matching/global_index.h"

#include <gtest/gtest.h>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "tests/test_image.h"

namespace uavm {
namespace {

// Frames of a real flight are indexed; a rotated, rescaled copy of one of them must vote for it first.
TEST(GlobalIndexTest, RelocalisesARotatedFrameAmongRealFrames) {
  const std::string dir = std::string(UAVM_TEST_DATA) + "/brighton_beach_small/images/";
  const SiftExtractor sift{FeatureOptions{}};
  GlobalIndexOptions o;
  o.max_descriptors = 2048;  // small, so that thinning happens during the test
  GlobalIndex index(o);
  cv::Mat probe_src;
  for (int i = 18; i <= 35; ++i) {
    // Under emulation every other frame (27 among them), at half size: still more than the cap holds, so it thins.
    if (test::Emulated() && i % 2 == 0) continue;
    char name[32];
    std::snprintf(name, sizeof(name), "DJI_%04d.JPG", i);
    const cv::Mat img = test::ScaledForEmulation(cv::imread(dir + name, cv::IMREAD_GRAYSCALE));
    ASSERT_FALSE(img.empty());
    if (i == 27) probe_src = img;
    index.Add(i, sift.Extract(img));
  }
  EXPECT_LE(index.size(), 2048u);
  EXPECT_LT(index.per_frame_quota(), o.descriptors_per_frame);  // it thinned instead of forgetting frames
  cv::Mat rotated;
  const cv::Mat r = cv::getRotationMatrix2D(
      cv::Point2f(static_cast<float>(probe_src.cols) / 2, static_cast<float>(probe_src.rows) / 2), 150.0, 0.85);
  cv::warpAffine(probe_src, rotated, r, probe_src.size());
  const auto ranked = index.Query(sift.Extract(rotated), 3);
  ASSERT_FALSE(ranked.empty());
  // The memory plan's line for the index (core/pipeline/memory_budget.cpp) counts 80 bytes a descriptor for the
  // forest: 4 trees of row orders (16) and one reserved node a row each (64). More means its nodes outgrew the reserve.
  EXPECT_GT(index.forest_bytes(), 0u);
  EXPECT_LE(index.forest_bytes(), 80 * index.size() + 64);
  // Frame 27 or a frame of the next strip that covers the same ground (the return pass overlaps it).
  EXPECT_NE(std::find(ranked.begin(), ranked.end(), 27), ranked.end());
}

}  // namespace
}  // namespace uavm
