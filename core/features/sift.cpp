#include "core/features/sift.h"

#include <opencv2/features2d.hpp>

namespace uavm {

bool FeatureOptions::Check(std::string* why) const {
  auto fail = [&](const char* msg) {
    if (why != nullptr) *why = msg;
    return false;
  };
  if (max_features < 16) return fail("features.max_features must be >= 16");
  if (!(contrast_threshold > 0.0 && contrast_threshold < 1.0))
    return fail("features.contrast_threshold must be in (0,1)");
  if (!(min_contrast_threshold > 0.0 && min_contrast_threshold <= contrast_threshold))
    return fail("features.min_contrast_threshold must be in (0, contrast_threshold]");
  if (target_min_features < 0) return fail("features.target_min_features must be >= 0");
  if (octave_layers < 1 || octave_layers > 8) return fail("features.octave_layers must be in [1,8]");
  return true;
}

SiftExtractor::SiftExtractor(const FeatureOptions& options) : options_(options) {}

Features SiftExtractor::Extract(const cv::Mat& gray) const {
  Features out;
  if (gray.empty() || gray.type() != CV_8UC1) return out;
  std::vector<cv::KeyPoint> keypoints;
  double threshold = options_.contrast_threshold;
  for (;;) {
    keypoints.clear();
    auto sift = cv::SIFT::create(options_.max_features, options_.octave_layers, threshold, 10.0, 1.6);
    sift->detectAndCompute(gray, cv::noArray(), keypoints, out.descriptors);
    out.contrast_threshold_used = threshold;
    if (static_cast<int>(keypoints.size()) >= options_.target_min_features) break;
    const double next = threshold / 3.0;
    if (next < options_.min_contrast_threshold) break;
    threshold = next;
  }
  // OpenCV's SIFT doubles the image first and reports positions as doubled-image index / 2, while pixel centres of
  // the doubled image sit at (i + 0.5) / 2 - 0.5: every keypoint is 0.25 px too far right and down. Harmless for a
  // pure translation, but with rotation or scale it biases the fitted transform by (I - L) * 0.25 px.
  constexpr float kSiftCentreShift = 0.25f;
  out.points.reserve(keypoints.size());
  for (const auto& kp : keypoints) out.points.emplace_back(kp.pt.x - kSiftCentreShift, kp.pt.y - kSiftCentreShift);
  if (options_.root_sift && !out.descriptors.empty()) {
    for (int r = 0; r < out.descriptors.rows; ++r) {
      cv::Mat row = out.descriptors.row(r);
      const double l1 = cv::norm(row, cv::NORM_L1);
      if (l1 > 0) row /= l1;
      cv::sqrt(row, row);
    }
  }
  return out;
}

}  // namespace uavm
