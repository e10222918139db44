#pragma once
#include <map>
#include <string>
#include <vector>

#include "hal/common/frame_source.h"
#include "hal/sim/sim_plan.h"

namespace uavm::hal {

struct SimOptions {
  std::string plan_path;    // YAML plan file (see sim_plan.h); when empty, `plan_yaml` is parsed instead
  std::string plan_yaml;    // inline plan text (tests)
  std::string canvas_path;  // overrides the plan's `canvas` key
  int max_frames = 0;       // 0 = the whole flight
};

// Ground truth of one emitted frame (original-resolution frame pixels, pixel centres).
struct SimTruth {
  uint64_t index = 0;
  Mat3 canvas_from_frame = Mat3::Identity();  // exact projective map, (2, 2) = 1
  Mat3 affine = Mat3::Identity();             // closest affine over the frame (least squares on a 17x17 grid)
  SimPose pose;
  // With the plan's gps: the ground under the frame centre, true and as the (noisy, biased) receiver reports it.
  LatLon true_position;
  LatLon gps_position;
  double gps_altitude_m = 0.0;  // height above take-off
  double gps_heading_deg = 0.0;  // of the direction of flight, compass degrees (clockwise from north), noisy
};

// A virtual camera flying a lawn-mower plan over a large image (the canvas). Every frame is rendered from the
// canvas through its true canvas_from_frame (cv::warpPerspective, reflected border), then blurred, exposed, noised
// and JPEG round-tripped as the plan says. Deterministic by the plan's seed.
class SimSource final : public FrameSource {
 public:
  explicit SimSource(SimOptions options);
  // Loads plan and canvas, lays out the flight; a bad plan or unreadable canvas is kError with the reason.
  [[nodiscard]] Status Open(std::string* error) override;
  [[nodiscard]] Status Next(Frame* frame, std::string* error) override;
  void Close() override;
  [[nodiscard]] std::string Describe() const override;
  [[nodiscard]] bool IsReplay() const override { return true; }  // synthetic: the consumer may back-pressure

  [[nodiscard]] const SimTruth& last_truth() const { return truth_; }
  // The JPEG bytes of the last frame when jpeg_quality > 0 (the frame is exactly their decoding), else empty.
  [[nodiscard]] const std::vector<uchar>& last_encoded() const { return encoded_; }
  [[nodiscard]] const SimPlan& plan() const { return plan_; }
  [[nodiscard]] const std::string& plan_text() const { return plan_text_; }
  [[nodiscard]] const std::vector<SimPose>& poses() const { return poses_; }
  [[nodiscard]] size_t NumFrames() const;
  // Name of frame `index`: frame_000000.jpg, or .png when the plan has no JPEG round trip.
  [[nodiscard]] std::string FrameName(uint64_t index) const;
  // Renders frame i exactly as Next() emits it (random access, for tests and tools).
  [[nodiscard]] bool Render(size_t i, cv::Mat* image, SimTruth* truth, std::vector<uchar>* encoded, std::string* error);
  void SimulateGps(size_t i, cv::Size size, SimTruth* truth) const;

 private:
  void PaintWater();
  const cv::Mat& CanvasLevel(int level);

  SimOptions options_;
  SimPlan plan_;
  std::string plan_text_;
  cv::Mat canvas_;
  std::map<int, cv::Mat> levels_;  // canvas reduced by 2^(level/4), for anti-aliased downsampling
  std::vector<SimPose> poses_;
  size_t next_ = 0;
  SimTruth truth_;
  std::vector<uchar> encoded_;
};

}  // namespace uavm::hal
