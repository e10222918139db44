#pragma once
// One picture out of many frames' brightness: each frame's gain (exposure, white balance), the lens's vignetting, a
// smooth flat field beyond it (off-centre falloff, sensor shading) and the sun's opposition hotspot, estimated from
// what overlapping frames show of the same ground, and removed before blending. Multi-band blending hides seams, not
// a darkening that every frame repeats at its corners, a bright mound that every frame repeats around the antisolar
// point, or a step between exposures.
#include <array>
#include <functional>
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
  // All samples of the end-of-flight solve: a long flight samples fewer points per edge (its edges share this count,
  // at least one point each, so every pair still ties its frames' gains) and the solve's memory stops growing there
  // (~0.3 KB per sample while it runs) until a flight has more edges than this.
  int max_samples = 50000;
  // Pulls each log gain towards 0 (the mean exposure), as a share of an average frame's samples: fixes the gauge of
  // a flight whose pieces do not overlap and damps noise, while biasing a real gain by about this share.
  double gain_prior_weight = 0.01;
  // The same for each channel's deviation from the exposure (white balance): stronger, as colour casts show more.
  double colour_prior_weight = 0.05;
  double huber_log = 0.05;           // robust loss width in log intensity (moving objects, misregistration, glint)
  int min_vignetting_samples = 300;  // fewer: the flight does not determine the falloff; gains only
  double max_corner_falloff = 0.8;   // a fitted corner darker than 1 - this is refused as implausible
  // Beyond the centred radial falloff, each kept only when it explains pairs it was not fitted on (a fifth of the
  // edges held out) better by `min_holdout_gain` of their robust cost: a flight that shows none keeps the radial model.
  bool flat_field = true;  // u, v, u^2 - v^2, uv, u r^2, v r^2 in the image (off-centre falloff, sensor shading)
  bool hotspot = true;     // a radial bump about the antisolar point, which turns with the frame's heading
  double min_holdout_gain = 0.03;
  // Up to this many frames the gains are solved by a sparse factorisation; beyond, by conjugate gradients over the
  // normal equations as they are summed (the same solution; the factorisation's fill grew ~10 MB at 5000 frames).
  int direct_max_frames = 1000;
  double iterative_tolerance = 1e-10;  // relative residual |N x - b| / |b|: the gains agree with the factorisation's
  int max_iterative_steps = 5000;      // a solve that needs more fails (the model is refused or keeps an earlier pass)

  [[nodiscard]] bool Check(std::string* why) const;
};

// A point of a frame: (u, v) from the image centre in half-diagonals (x right, y down; r^2 = u^2 + v^2), and the
// frame's heading (HeadingOf: its rotation into the mosaic), which turns the sun's hotspot in the image.
struct ImagePoint {
  float u = 0, v = 0;
  float heading = 0;
  [[nodiscard]] float R2() const { return u * u + v * v; }
};

// The same ground seen in two frames a and b, and the log of the low-pass colour (B, G, R) in each.
struct RadiometrySample {
  int a = -1, b = -1;
  ImagePoint in_a, in_b;
  cv::Vec3f log_a, log_b;
};

// The opposition hotspot: the ground is brightest around the antisolar point (where the drone's shadow falls), a
// direction fixed relative to the sun, so its place in each image turns with the frame's heading. Its log brightness
// is a radial profile about that place: a sum of Gaussians of fixed widths (any bump width is a combination of them).
struct Hotspot {
  static constexpr std::array<double, 3> kSigma{0.07, 0.14, 0.28};  // half-diagonals
  bool found = false;
  // Where a frame of heading 0 (its axes along the mosaic's) sees the antisolar point, in half-diagonals.
  double antisolar_u = 0, antisolar_v = 0;
  std::array<double, 3> weights{};

  [[nodiscard]] cv::Point2d Centre(double heading) const;  // in a frame of that heading
  [[nodiscard]] double LogBoost(double d2) const;          // at squared distance d2 from the centre
  [[nodiscard]] double CoreRadius() const;                 // where the boost falls to half its peak
};

// recorded = gain[frame][c] * V_c(r) * F(u, v) * H(frame's heading, u, v) * scene, with log V_c(r) = c1 r^2 + c2 r^4
// (V = 1 at the centre), log F = the flat field's terms (grey), H the hotspot (grey; 1 when not found).
struct RadiometryModel {
  static constexpr int kFlatTerms = 6;  // u, v, u^2 - v^2, uv, u r^2, v r^2
  bool ok = false;
  bool vignetting = false;
  std::array<std::array<double, 2>, 3> log_falloff{};  // (c1, c2) per channel B, G, R
  bool flat_field = false;
  std::array<double, kFlatTerms> log_flat{};
  Hotspot hotspot;
  std::unordered_map<int, cv::Vec3d> log_gain;
  int samples = 0;
  int edges = 0;
  double rms_log_before = 0.0;  // of the pair differences the model explains, before and after it
  double rms_log_after = 0.0;
  // The held-out pairs' robust cost under the radial model, with the flat field, with the hotspot too (0: not tried);
  // what chose the terms kept.
  std::array<double, 3> holdout_cost{};
  std::string note;  // why the falloff or the whole model was refused, if it was
  // How the final model's gains were solved (its exposure and colour fits, every reweighting): by conjugate gradients
  // (more frames than direct_max_frames), the most steps one solve took, and the reweightings whose solve failed
  // (the fit kept the pass before; a failed first pass refuses the model).
  bool iterative = false;
  int most_iterative_steps = 0;
  int failed_solves = 0;

  [[nodiscard]] double Falloff(int channel, double r2) const;  // V_c
  [[nodiscard]] cv::Vec3d Gain(int id) const;                  // 1 for a frame the solve did not see
  // Whether anything beyond the radial falloff was kept (the correction then depends on the position, not only r).
  [[nodiscard]] bool BeyondRadial() const { return flat_field || hotspot.found; }
  // log(V_c F H) at a point (without the frame's gain).
  [[nodiscard]] double LogShading(int channel, const ImagePoint& p) const;
};

// The frame's heading: the rotation (radians) of the similarity closest to mosaic_from_work at the image centre.
[[nodiscard]] double HeadingOf(const Mat3& mosaic_from_work, cv::Size work_size);

// Area-averaged thumbnail of a frame's working image (long side `long_side`), 8-bit BGR.
[[nodiscard]] cv::Mat MakeThumbnail(const cv::Mat& bgr, int long_side);

// A frame as the overlap sampler sees it (borrowed thumbnail).
struct OverlapView {
  int id = -1;
  const cv::Mat* thumb = nullptr;
  cv::Size work_size;
  double heading = 0.0;
};

// Samples the overlap of frames a and b on a grid over a's thumbnail: b_from_a maps a's working pixels to b's.
// Saturated and near-black samples are skipped (no gain is visible there). Appends at most `max_samples`.
void SampleOverlap(const OverlapView& a, const OverlapView& b, const Mat3& b_from_a, int max_samples,
                   std::vector<RadiometrySample>* out);

// Least squares over the pairs' log differences (iteratively reweighted with a Huber loss): the exposure (grey) with
// a log gain per frame in `frames` (prior towards 0), the falloff when options.vignetting and the samples span enough
// radii, the flat field and the hotspot when the held-out pairs keep them (the antisolar point searched on a grid,
// then refined); then each channel's deviation (white balance, the falloff's tint). `terms_chosen`, when given, runs
// once the choice of terms has freed its copies of the samples and its trial solves (the end of the flight gives the
// heap's free pages back there; the live fits, every 20 frames, do not pay for it).
[[nodiscard]] RadiometryModel SolveRadiometry(std::vector<RadiometrySample> samples, const std::vector<int>& frames,
                                              const RadiometryOptions& options,
                                              const std::function<void()>& terms_chosen = nullptr);

// The shading during the flight, for the live view (vignetting, flat field, the sun's hotspot): the lens does not
// change and the sun moves slowly, so a fit over the recent frames' overlaps, refreshed every `solve_every` frames,
// removes the pattern that every frame repeats. Bounded: thumbnails of
// the last `window` frames and the samples of their edges; each solve sees only those (never the whole flight).
// Frame gains are not applied live (a new frame's gain is only known at the next solve; a step between frames drawn
// with and without one would be worse than none); the end-of-flight solve does both.
class LiveRadiometry {
 public:
  LiveRadiometry(const RadiometryOptions& options, int window = 48, int solve_every = 20);
  // `thumb`: the frame's MakeThumbnail (made once per frame by the caller), of a working image of `work_size`;
  // `heading`: HeadingOf its registration.
  void AddFrame(int id, const cv::Mat& thumb, cv::Size work_size, double heading);
  // An edge verified between two frames (b_from_a maps a's working pixels to b's); ignored when either is no
  // longer in the window.
  void AddEdge(int a, int b, const Mat3& b_from_a);
  // Solves when `solve_every` frames came since the last solve; true when the model changed.
  bool MaybeSolve();
  // The live model: vignetting, flat field and hotspot (no gains); not ok before the first successful fit.
  [[nodiscard]] const RadiometryModel& model() const { return model_; }

 private:
  struct Thumb {
    int id;
    cv::Mat image;
    cv::Size work_size;
    double heading;
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

// Divides the frame's gain and shading out of `bgr`, a part of the frame's image whose pixel (0, 0) is at `origin` in
// an image of `full_size` (any resolution of the frame: positions are relative to its half-diagonal); `heading` is
// the frame's (HeadingOf).
void CorrectRadiometry(const RadiometryModel& model, int id, double heading, cv::Size full_size, cv::Point2d origin,
                       cv::Mat* bgr);

// Where the frame's seams should not go: the hotspot's core (and the drone's shadow at its centre), a disc in the
// pixels of an image of `size`; radius 0 when no hotspot was found.
struct AvoidDisc {
  cv::Point2d centre;
  double radius = 0.0;
};
[[nodiscard]] AvoidDisc HotspotDisc(const RadiometryModel& model, double heading, cv::Size size);

}  // namespace uavm
