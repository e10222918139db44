#pragma once
#include <cstdint>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "core/stereo/daisy.h"

namespace uavm::stereo {

// Semi-global matching on a rectified pair (epipolar lines = image rows, disparity = x_left - x_right >= 0).
struct SgmOptions {
  // The matching cost: census (+ gradient), or DAISY descriptors (core/stereo/daisy.h) compared by L1 distance.
  enum class Cost { kCensus, kDaisy };
  Cost cost = Cost::kCensus;
  DaisyOptions daisy;
  // DAISY cost = min(255, L1 distance of the byte descriptors / daisy_divisor), on the census cost's scale.
  int daisy_divisor = 50;  // best of 25, 35, 50, 100, 200 on Middlebury (mean bad-2 10.5, 10.1, 9.9, 10.7, 13.2 %)
  int min_disparity = 0;
  int num_disparities = 64;  // disparities searched: min_disparity .. min_disparity + num_disparities - 1
  // Census window (odd sizes; at most 64 bits in total).
  int census_width = 9;
  int census_height = 7;
  // Weight of the absolute horizontal-gradient difference added to the census Hamming cost (0 = census only).
  int gradient_weight = 1;
  // Smoothness penalties per path step: P1 for |d change| = 1, P2 for larger jumps; P2 is divided by (1 + the
  // intensity step / p2_gradient_scale) so that depth jumps are cheaper on image edges.
  int p1 = 10;
  int p2 = 120;
  int p2_min = 30;
  double p2_gradient_scale = 0.0;  // 0 = constant P2
  // 4 (horizontal + vertical) or 8 (plus diagonals); on Middlebury 4 paths score as well as 8 (mean bad-2 4.6 % vs
  // 5.1 %) in half the aggregation time.
  int num_paths = 4;
  // Best cost must beat the second best (outside +-1) by this percentage.
  int uniqueness_ratio = 5;
  // Left-right check tolerance in pixels (< 0 = no check).
  double lr_tolerance = 1.0;
  // Speckle removal: regions smaller than speckle_size pixels whose disparity varies by <= speckle_range are invalid.
  int speckle_size = 100;
  double speckle_range = 2.0;
  // Fill invalid pixels from the lower (background) of the nearest valid neighbours along the row, then median.
  bool fill_holes = true;
  int median_size = 3;  // 0, 3 or 5
  int threads = 0;      // 0 = OpenCV's default
  // The work buffers take 5 bytes per pixel and disparity (rounded up to 16); larger problems are refused.
  int max_memory_mib = 4096;

  [[nodiscard]] bool Check(std::string* why = nullptr) const;
};

// The matcher with its work buffers (cost volume and path sums, ~5 bytes per pixel and disparity), kept between
// calls so that repeated matching does not pay for fresh pages each time.
class SgmMatcher {
 public:
  explicit SgmMatcher(const SgmOptions& options) : options_(options) {}
  const SgmOptions& options() const { return options_; }
  void set_options(const SgmOptions& options) { options_ = options; }
  // As ComputeDisparity below.
  [[nodiscard]] bool Compute(const cv::Mat& left, const cv::Mat& right, cv::Mat* disparity,
                             std::string* error = nullptr, cv::Mat* measured = nullptr);
  void ReleaseBuffers();

 private:
  SgmOptions options_;
  std::vector<uint8_t> cost_;
  std::vector<uint16_t> sum_[2];
};

// Disparity of the LEFT image, CV_32FC1, NaN where there is none. `left` and `right` are 8-bit gray or BGR of the
// same size. Fails (with a message) when the work buffers would exceed options.max_memory_mib. `measured` (optional,
// CV_8UC1): 255 where the disparity passed the checks, 0 where it was hole-filled.
[[nodiscard]] bool ComputeDisparity(const cv::Mat& left, const cv::Mat& right, const SgmOptions& options,
                                    cv::Mat* disparity, std::string* error = nullptr, cv::Mat* measured = nullptr);

}  // namespace uavm::stereo
