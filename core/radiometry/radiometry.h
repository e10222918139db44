#pragma once
// One picture out of many frames' brightness: each frame's gain (exposure, white balance) and the lens's vignetting,
// estimated from what overlapping frames show of the same ground, and removed before blending. Multi-band blending
// hides seams, not a darkening that every frame repeats at its corners or a step between exposures.
#include <array>
#include <opencv2/core.hpp>
#include <string>
#include <unordered_map>
#include <vector>

#include "core/geometry/transform.h"

namespace uavm {

struct RadiometryOptions {
  bool enabled = true;
  bool vignetting = true;     // estimate the falloff (else gains only)
  int thumb_long_side = 128;  // per-frame thumbnail the overlaps are sampled on (low frequencies only)
  int samples_per_edge = 64;  // grid points sampled in each pair's overlap (bounded statistics per edge)
  // All samples of the end-of-flight solve: a long flight samples fewer points per edge (4 at least) so that the
  // solve's memory stays bounded (~0.3 KB per sample while it runs).
  int max_samples = 50000;
  // Pulls each log gain towards 0 (the mean exposure), as a share of an average frame's samples: fixes the gauge of
  // a flight whose pieces do not overlap and damps noise, while biasing a real gain by about this share.
  double gain_prior_weight = 0.01;
  // The same for each channel's deviation from the exposure (white balance): stronger, as colour casts show more.
  double colour_prior_weight = 0.05;
  double huber_log = 0.05;           // robust loss width in log intensity (moving objects, misregistration, glint)
  int min_vignetting_samples = 300;  // fewer: the flight does not determine the falloff; gains only
  double max_corner_falloff = 0.8;   // a fitted corner darker than 1 - this is refused as implausible

  [[nodiscard]] bool Check(std::string* why) const;
};

// The same ground seen in two frames a and b: radii (r^2, r = distance from the image centre / half-diagonal) and the
// log of the low-pass colour (B, G, R) in each.
struct RadiometrySample {
  int a = -1, b = -1;
  float r2_a = 0, r2_b = 0;
  cv::Vec3f log_a, log_b;
};

// recorded = gain[frame][c] * V_c(r) * scene, with log V_c(r) = c1 r^2 + c2 r^4 (V = 1 at the centre).
struct RadiometryModel {
  bool ok = false;
  bool vignetting = false;
  std::array<std::array<double, 2>, 3> log_falloff{};  // (c1, c2) per channel B, G, R
  std::unordered_map<int, cv::Vec3d> log_gain;
  int samples = 0;
  int edges = 0;
  double rms_log_before = 0.0;  // of the pair differences the model explains, before and after it
  double rms_log_after = 0.0;
  std::string note;  // why the falloff or the whole model was refused, if it was

  [[nodiscard]] double Falloff(int channel, double r2) const;  // V_c
  [[nodiscard]] cv::Vec3d Gain(int id) const;                  // 1 for a frame the solve did not see
};

// Area-averaged thumbnail of a frame's working image (long side `long_side`), 8-bit BGR.
[[nodiscard]] cv::Mat MakeThumbnail(const cv::Mat& bgr, int long_side);

// Samples the overlap of frames a and b on a grid over a's thumbnail: b_from_a maps a's working pixels to b's.
// Saturated and near-black samples are skipped (no gain is visible there). Appends at most `max_samples`.
void SampleOverlap(int a, int b, const cv::Mat& thumb_a, const cv::Mat& thumb_b, cv::Size work_a, cv::Size work_b,
                   const Mat3& b_from_a, int max_samples, std::vector<RadiometrySample>* out);

// Least squares over the pairs' log differences (iteratively reweighted with a Huber loss), one channel at a time:
// a log gain per frame in `frames` with a prior towards 0, and the falloff when options.vignetting and the samples
// span enough radii.
[[nodiscard]] RadiometryModel SolveRadiometry(const std::vector<RadiometrySample>& samples,
                                              const std::vector<int>& frames, const RadiometryOptions& options);

// The vignetting during the flight, for the live view: the lens does not change, so a fit over the recent frames'
// overlaps, refreshed every `solve_every` frames, removes the pattern that every frame repeats. Bounded: thumbnails of
// the last `window` frames and the samples of their edges; each solve sees only those (never the whole flight).
// Frame gains are not applied live (a new frame's gain is only known at the next solve; a step between frames drawn
// with and without one would be worse than none); the end-of-flight solve does both.
class LiveRadiometry {
 public:
  LiveRadiometry(const RadiometryOptions& options, int window = 48, int solve_every = 20);
  // `thumb`: the frame's MakeThumbnail (made once per frame by the caller), of a working image of `work_size`.
  void AddFrame(int id, const cv::Mat& thumb, cv::Size work_size);
  // An edge verified between two frames (b_from_a maps a's working pixels to b's); ignored when either is no
  // longer in the window.
  void AddEdge(int a, int b, const Mat3& b_from_a);
  // Solves when `solve_every` frames came since the last solve; true when the model changed.
  bool MaybeSolve();
  // The live model: vignetting only (no gains); not ok before the first successful fit.
  [[nodiscard]] const RadiometryModel& model() const { return model_; }

 private:
  struct Thumb {
    int id;
    cv::Mat image;
    cv::Size work_size;
  };
  [[nodiscard]] const Thumb* Find(int id) const;
  RadiometryOptions options_;
  size_t window_;
  int solve_every_;
  int frames_since_solve_ = 0;
  std::vector<Thumb> thumbs_;  // oldest first, at most window_
  std::vector<RadiometrySample> samples_;
  RadiometryModel model_;
};

// Divides the frame's gain and falloff out of `bgr`, a part of the frame's image whose pixel (0, 0) is at `origin` in
// an image of `full_size` (any resolution of the frame: r is relative to its half-diagonal).
void CorrectRadiometry(const RadiometryModel& model, int id, cv::Size full_size, cv::Point2d origin, cv::Mat* bgr);

}  // namespace uavm
