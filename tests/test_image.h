#pragma once
// Real images for SIFT-heavy unit tests, made smaller under emulation (tests/test_env.h): a caller scales the shifts
// and sizes it knows by test::EmulationImageScale() too, so the assertions stay the same.
#include <opencv2/imgproc.hpp>

#include "tests/test_env.h"

namespace uavm::test {

inline cv::Mat ScaledForEmulation(cv::Mat img) {
  const double scale = EmulationImageScale();
  if (scale != 1.0 && !img.empty()) cv::resize(img, img, cv::Size(), scale, scale, cv::INTER_AREA);
  return img;
}

}  // namespace uavm::test
