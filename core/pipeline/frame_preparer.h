#pragma once
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "core/features/sift.h"
#include "core/frame/frame.h"
#include "core/pipeline/work_lens.h"

namespace uavm {

// A frame made ready for registration: working copy and features. Preparing touches no session state, so the load
// and detect threads run it while the previous frame is being matched (PrepareImages, then DetectFeatures).
struct PreparedFrame {
  Frame frame;
  cv::Mat work_bgr;
  cv::Mat work_gray;
  Features features;
  std::vector<uchar> encoded;  // JPEG of the frame when the source has no file to copy
  double decode_ms = 0.0;      // measured by the caller around the source's Next()
  double prepare_ms = 0.0;
  double features_ms = 0.0;
  // Every pixel nearly one colour (lens cap, blown exposure, a blank sensor read, calm water): measured on the decoded
  // frame; `blank` when that colour is black or saturated. FlightSession decides what such a frame is worth.
  bool uniform = false;
  bool blank = false;
  bool resumed = false;     // already in the session (frames/, features/, journal): registered again, not stored
  std::string stored_name;  // its file in frames/ when resumed
};

// Makes frames ready for registration: the working copy (work_long_side, never upscaled) undistorted by the flight's
// lens, its grey image, a JPEG when the source has no file to copy, and the features (found on the recorded pixels,
// their positions undistorted). Const and thread-safe.
class FramePreparer {
 public:
  FramePreparer(int work_long_side, const CameraOptions& camera, const FeatureOptions& features)
      : work_long_side_(work_long_side), lens_(camera), extractor_(features) {}

  [[nodiscard]] PreparedFrame Prepare(Frame frame) const;        // PrepareImages, then DetectFeatures
  [[nodiscard]] PreparedFrame PrepareImages(Frame frame) const;  // working copies, no features
  void DetectFeatures(PreparedFrame* p) const;
  // The working grey image the features' coordinates refer to (undistorted when a lens is corrected).
  [[nodiscard]] cv::Mat IdealGray(const PreparedFrame& p) const;
  [[nodiscard]] const WorkLens& lens() const { return lens_; }

 private:
  int work_long_side_;
  WorkLens lens_;
  SiftExtractor extractor_;
};

}  // namespace uavm
