#pragma once
#include <mutex>
#include <nlohmann/json.hpp>
#include <string>
#include <thread>

#include "core/adjust/lens_calibration.h"
#include "core/frame/frame.h"
#include "core/lens/camera_setup.h"

namespace uavm {

// The flight's lens for its working copies: chosen once, on the first frame prepared (configuration, lensfun's
// database, none), then undistorting every working copy and its features. Thread-safe: the load and detect threads
// prepare frames while the frame loop registers. A frame of another size than the first (a second camera?) is used as
// recorded.
class WorkLens {
 public:
  explicit WorkLens(CameraOptions options) : options_(std::move(options)) {}
  WorkLens(const WorkLens&) = delete;
  WorkLens& operator=(const WorkLens&) = delete;

  // The undistortion of `frame`'s working copy of `work_size` pixels (the first call chooses the lens).
  [[nodiscard]] const Undistorter& For(const Frame& frame, cv::Size work_size) const;

  // Set by the first For(); before it, no lens (chosen() false). Read them on a thread that a For() happened before
  // (the frame loop after the capture queue's hand-over; the tile worker after its job's): they are not locked.
  [[nodiscard]] bool chosen() const { return original_size_.width > 0; }
  [[nodiscard]] const CameraChoice& choice() const { return choice_; }
  [[nodiscard]] cv::Size original_size() const { return original_size_; }
  // The first frame's working-copy undistortion (the live tiles undo it on frames read back from frames/).
  [[nodiscard]] const Undistorter& work() const { return work_; }

 private:
  CameraOptions options_;
  mutable std::once_flag once_;
  // Written once, under once_.
  mutable CameraChoice choice_;
  mutable Undistorter work_;
  mutable cv::Size original_size_;
};

// lensfun's database (~0.1 s of XML) parsed on a thread of its own when `options` will look the camera up, so that
// the first frame's decode runs beside it instead of before it (For() waits for it only if it gets there first);
// joined when the returned thread is destroyed. Source to first frame on brighton_beach 369 -> 329 ms (medians of 5).
[[nodiscard]] std::jthread PreloadLensDatabase(const CameraOptions& options);

// The lens of the session's outputs: the chosen one, or the self-calibrated one when the end of the flight accepted a
// calibration (or dropped the chosen lens). Original pixels.
[[nodiscard]] PinholeCamera FinalCamera(const WorkLens& lens, const LensCalibration& calibration);
// camera.yaml's text (empty when no frame was prepared).
[[nodiscard]] std::string CameraYaml(const WorkLens& lens, const LensCalibration& calibration);
// report.json "lens".
[[nodiscard]] nlohmann::json LensJson(const WorkLens& lens, const LensCalibration& calibration);

}  // namespace uavm
