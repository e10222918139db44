#pragma once
// A real aerial frame for detector tests (needs UAVM_TEST_DATA, as every uavm_test has).
#include <gtest/gtest.h>

#include <algorithm>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <string>

namespace uavm::test {

// caliterra_small's IMG_9360 in grey, its long side resized to `long_side` (area averaging).
inline cv::Mat WorkingGray(int long_side) {
  const cv::Mat img =
      cv::imread(std::string(UAVM_TEST_DATA) + "/caliterra_small/images/IMG_9360.jpg", cv::IMREAD_GRAYSCALE);
  EXPECT_FALSE(img.empty());
  if (img.empty()) return img;
  const double s = static_cast<double>(long_side) / std::max(img.cols, img.rows);
  cv::Mat out;
  cv::resize(img, out, cv::Size(), s, s, cv::INTER_AREA);
  return out;
}

}  // namespace uavm::test
