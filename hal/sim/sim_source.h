#pragma once
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "hal/common/frame_source.h"
#include "hal/sim/sim_plan.h"
#include "hal/telemetry/mavlink_signing.h"

namespace uavm::hal {

struct SimOptions {
  std::string plan_path;    // YAML plan file (see sim_plan.h); when empty, `plan_yaml` is parsed instead
  std::string plan_yaml;    // inline plan text (tests)
  std::string canvas_path;  // overrides the plan's `canvas` key
  int max_frames = 0;       // 0 = the whole flight
  // The plan's live behaviour, mavlink_udp and live_camera (uavmosaic-sim writes a .tlog and geo.txt instead: off).
  bool live_link = true;
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
  double gps_altitude_m = 0.0;   // height above take-off
  double gps_heading_deg = 0.0;  // of the direction of flight, compass degrees (clockwise from north), noisy
};

// What the flight controller reports at one instant of a simulated flight with GPS (plan gps: 1).
struct SimFix {
  LatLon true_position;                    // the ground under the camera's centre ray, on the true path
  LatLon gps_position;                     // as the (noisy, biased) receiver reports it
  double altitude_m = 0.0;                 // height above take-off
  double heading_deg = 0.0;                // compass heading of the direction of flight (frame +x), noisy
  double roll_deg = 0.0, pitch_deg = 0.0;  // attitude, noisy
  double east_mps = 0.0, north_mps = 0.0;  // velocity along the true path
};

class SimUdpLink;

// The plan's band of calm water painted over the canvas (water_from/water_to; nothing when there is none): the canvas
// the frames really show, for anyone who compares a mosaic with it.
void PaintSimWater(const SimPlan& plan, cv::Mat* canvas);

// A virtual camera flying a lawn-mower plan over a large image (the canvas). Every frame is rendered from the
// canvas through its true canvas_from_frame (cv::warpPerspective, reflected border; with lens distortion each pixel
// is undistorted first and the canvas sampled there), then blurred, vignetted, exposed, noised and JPEG round-tripped
// as the plan says. Deterministic by the plan's seed.
class SimSource final : public FrameSource {
 public:
  explicit SimSource(SimOptions options);
  ~SimSource() override;
  // Loads plan and canvas, lays out the flight; a bad plan or unreadable canvas is kError with the reason.
  [[nodiscard]] Status Open(std::string* error) override;
  [[nodiscard]] Status Next(Frame* frame, std::string* error) override;
  void Close() override;
  [[nodiscard]] std::string Describe() const override;

  [[nodiscard]] const SimTruth& last_truth() const { return truth_; }
  // The JPEG bytes of the last frame when jpeg_quality > 0 (the frame is exactly their decoding), else empty.
  [[nodiscard]] const std::vector<uchar>& last_encoded() const { return encoded_; }
  [[nodiscard]] const SimPlan& plan() const { return plan_; }
  [[nodiscard]] const std::string& plan_text() const { return plan_text_; }
  // The plan's mavlink_signing_key_file, read by Open(); none: the telemetry is not signed.
  [[nodiscard]] const std::optional<mavlink::SigningKey>& signing_key() const { return signing_key_; }
  [[nodiscard]] const std::vector<SimPose>& poses() const { return poses_; }
  [[nodiscard]] size_t NumFrames() const;
  // Name of frame `index`: frame_000000.jpg, or .png when the plan has no JPEG round trip.
  [[nodiscard]] std::string FrameName(uint64_t index) const;
  // Renders frame i exactly as Next() emits it (random access, for tests and tools).
  [[nodiscard]] bool Render(size_t i, cv::Mat* image, SimTruth* truth, std::vector<uchar>* encoded, std::string* error);
  void SimulateGps(size_t i, cv::Size size, SimTruth* truth) const;
  // The telemetry at flight time t_s (frame i is taken at FrameTime(i)): the true path runs straight from frame
  // centre to frame centre (before the first frame and after the last the drone hovers there); the receiver's error
  // is the slowly turning bias plus noise drawn with `draw`. At a frame's instant the position, height and heading
  // are exactly that frame's (SimTruth, geo.txt). Plan gps: 1.
  [[nodiscard]] SimFix FixAt(double t_s, uint64_t draw) const;
  [[nodiscard]] double FrameTime(size_t i) const { return static_cast<double>(i) * plan_.frame_interval_s; }
  // live_camera: waits for frame i's moment (frame_interval_s apart from the first frame's) and returns it; else now.
  [[nodiscard]] int64_t LiveCameraTime(size_t i);

 private:
  void PrepareLens();
  [[nodiscard]] cv::Mat SunLight(const SimPose& pose) const;
  [[nodiscard]] cv::Mat Project(const cv::Mat& src, const Mat3& src_from_frame) const;
  void Expose(size_t i, cv::Mat* frame);
  [[nodiscard]] Vec2 GroundOf(size_t i) const;                 // canvas point under frame i's centre
  [[nodiscard]] Vec2 GpsErrorM(double f, cv::RNG* rng) const;  // east, north metres at fractional frame index f
  const cv::Mat& CanvasLevel(int level);

  SimOptions options_;
  SimPlan plan_;
  std::string plan_text_;
  cv::Mat canvas_;
  std::map<int, cv::Mat> levels_;  // canvas reduced by 2^(level/4), for anti-aliased downsampling
  std::vector<SimPose> poses_;
  cv::Mat ideal_from_frame_;  // CV_32FC2: each recorded pixel's undistorted position; empty without distortion
  cv::Mat falloff_;           // CV_32FC3: vignetting per pixel and channel; empty without vignetting
  size_t next_ = 0;
  SimTruth truth_;
  std::vector<uchar> encoded_;
  // Expose's float frame and noise, kept between frames: made afresh they were 2 MB each per 480x360 frame, sizes the
  // program's buffer pool then had to map anew beside the detector's.
  cv::Mat exposure_;
  cv::Mat noise_;
  std::unique_ptr<SimUdpLink> link_;  // the plan's mavlink_udp
  std::optional<mavlink::SigningKey> signing_key_;
  int64_t live_start_ns_ = 0;  // live_camera: monotonic time of the first frame
};

}  // namespace uavm::hal
