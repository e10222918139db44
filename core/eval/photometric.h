#pragma once
#include <array>
#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "core/eval/ground_truth.h"
#include "core/geometry/transform.h"

namespace uavm::eval {

// The mosaic's low-frequency brightness error against the canvas a simulated flight was flown over: what vignetting
// and exposure changes leave in a map (a pattern repeated per frame, brighter and darker frames), not texture.
//   1. The mosaic image is resampled onto a reduced copy of the canvas grid (canvas_from_mosaic: the evaluator's
//      fitted global homography); canvas pixels the mosaic does not wholly cover are left out.
//   2. Both are blurred with a Gaussian of sigma = sigma_footprint_fraction x the frame footprint's side (canvas
//      pixels; a quarter of a footprint by default: registration, resampling, noise and JPEG differences vanish,
//      the per-frame pattern stays), as normalised convolutions over the covered pixels, so the mosaic's edge does not
//      darken either.
//   3. Per channel, one global gain g_c is removed (mosaic = g_c x canvas: a camera's fixed exposure and white
//      balance are no error), chosen by least squares on the reported error itself.
//   4. The figure is the RMS over covered pixels and the three channels of the relative error
//      (mosaic / g_c - canvas) / max(canvas, dark_floor x mean canvas), in percent.
struct PhotometricOptions {
  double sigma_footprint_fraction = 0.25;
  // The comparison grid is the canvas reduced so that sigma spans this many of its pixels (never enlarged): low
  // frequencies survive, and a 4000x3000 canvas costs a few hundred thousand pixels.
  double grid_sigma_px = 8.0;
  // A pixel counts when at least this share of its Gaussian window is covered (both images' normalisations then
  // rest on enough pixels).
  double min_window_coverage = 0.5;
  // Relative errors are divided by at least this fraction of the mean canvas level (a dark spot would make them
  // explode).
  double dark_floor = 0.1;
  [[nodiscard]] bool Check(std::string* error) const;
};

struct PhotometricResult {
  double rms_percent = 0.0;
  std::array<double, 3> gain{1.0, 1.0, 1.0};  // B, G, R: mosaic = gain x canvas
  double sigma_canvas_px = 0.0;
  double grid_px_per_canvas_px = 1.0;
  long pixels = 0;  // grid pixels counted
};

// `mosaic_image`: BGR or BGRA (alpha 0 = not flown), any depth; mosaic_from_image maps its pixels to the mosaic's
// (a quick-look's reduction; identity for the full mosaic). `canvas`: BGR. `footprint_side_px`: canvas pixels
// (FootprintSidePx). False with a reason when nothing is covered or the inputs are unusable.
[[nodiscard]] bool PhotometricError(const cv::Mat& mosaic_image, const Mat3& mosaic_from_image, const cv::Mat& canvas,
                                    const Mat3& canvas_from_mosaic, double footprint_side_px, PhotometricResult* result,
                                    std::string* error, const PhotometricOptions& options = {});

// {"rms_percent", "gain": [b, g, r], "sigma_canvas_px", "grid_px_per_canvas_px", "pixels"}.
[[nodiscard]] nlohmann::json ToJson(const PhotometricResult& result);

// Median over the ground truth's frames of sqrt(footprint area): the side of a frame's footprint, canvas pixels.
[[nodiscard]] double FootprintSidePx(const std::vector<GtRow>& gt, cv::Size frame_size);

}  // namespace uavm::eval
