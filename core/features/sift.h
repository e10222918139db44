#pragma once
#include <opencv2/core.hpp>
#include <string>
#include <vector>

namespace uavm {

struct FeatureOptions {
  // Keep at most this many keypoints (strongest first).
  int max_features = 3000;
  // Start threshold. OpenCV's default 0.04 finds only tens of keypoints on soft aerial frames.
  double contrast_threshold = 0.01;
  // When fewer keypoints than this are found, the threshold is lowered (x1/3) down to min_contrast_threshold.
  int target_min_features = 1500;
  double min_contrast_threshold = 0.001;
  int octave_layers = 3;
  // L1-normalise and square-root descriptors (RootSIFT): better ratio-test matching at no cost.
  bool root_sift = true;

  [[nodiscard]] bool Check(std::string* why) const;
};

// Keypoints of one frame at working resolution. Descriptors are CV_32F, one row per point.
struct Features {
  std::vector<cv::Point2f> points;
  cv::Mat descriptors;
  double contrast_threshold_used = 0.0;

  [[nodiscard]] size_t size() const { return points.size(); }
  [[nodiscard]] size_t MemoryBytes() const {
    return points.size() * sizeof(cv::Point2f) + descriptors.total() * descriptors.elemSize();
  }
};

class SiftExtractor {
 public:
  explicit SiftExtractor(const FeatureOptions& options);
  // `gray` is CV_8UC1. Never throws on valid 8-bit input; an empty image gives no features.
  [[nodiscard]] Features Extract(const cv::Mat& gray) const;

 private:
  FeatureOptions options_;
};

}  // namespace uavm
