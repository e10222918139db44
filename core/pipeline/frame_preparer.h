#pragma once
#include <opencv2/core.hpp>
#include <optional>
#include <string>
#include <vector>

#include "core/features/sift.h"
#include "core/frame/frame.h"
#include "core/pipeline/work_lens.h"

namespace uavm {

// Every pixel nearly one colour (lens cap, blown exposure, a blank sensor read, calm water); `blank` when that colour
// is black or saturated.
struct Flatness {
  bool uniform = false;
  bool blank = false;
};
[[nodiscard]] Flatness MeasureFlatness(const cv::Mat& image);
// The session's rule, the same for every source: a frame of one colour has nothing to register and is kept only when
// its position (its own GPS or the telemetry's) can place it (calm water between two shores); a black or saturated one
// (a lens cap, a blown exposure) is never a picture. The reason to skip it, or null when it is worth registering.
[[nodiscard]] const char* WhyNotRegistrable(const Flatness& flatness, const FrameMetadata& metadata);

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
  Flatness flatness;        // of the decoded frame
  bool resumed = false;     // already in the session (frames/, features/, journal): registered again, not stored
  std::string stored_name;  // its file in frames/ when resumed
};

// Makes frames ready for registration: the working copy (work_long_side, never upscaled) undistorted by the flight's
// lens, its grey image, a JPEG when the source has no file to copy, and the features (found on the recorded pixels,
// their positions undistorted). Const and thread-safe. A frame of one colour neither chooses the lens nor needs it.
class FramePreparer {
 public:
  FramePreparer(int work_long_side, const CameraOptions& camera, const FeatureOptions& features)
      : work_long_side_(work_long_side), lens_(camera), extractor_(features) {}

  [[nodiscard]] PreparedFrame Prepare(Frame frame) const;  // PrepareImages, then DetectFeatures
  // Working copies, no features; `flatness` when the caller measured it already (MeasureFlatness on frame.image).
  [[nodiscard]] PreparedFrame PrepareImages(Frame frame, std::optional<Flatness> flatness = std::nullopt) const;
  void DetectFeatures(PreparedFrame* p) const;
  // The detector's scale space, held from frame to frame (SiftExtractor), goes back: the flight is over.
  void ReleaseDetectorBuffers() const { extractor_.ReleaseBuffers(); }
  // The working grey image the features' coordinates refer to (undistorted when a lens is corrected).
  [[nodiscard]] cv::Mat IdealGray(const PreparedFrame& p) const;
  [[nodiscard]] const WorkLens& lens() const { return lens_; }

 private:
  int work_long_side_;
  WorkLens lens_;
  SiftExtractor extractor_;
};

}  // namespace uavm
