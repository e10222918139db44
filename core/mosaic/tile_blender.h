#pragma once
#include <memory>
#include <opencv2/core.hpp>

namespace uavm {

// One stage of the compositor, with OpenCV stitching's small lifecycle, applied to one tile (plus margin) at a time:
// prepare(roi) -> feed(image, mask, top_left) ... -> blend(). Nothing here ever sees the whole canvas. A blender is
// used for tile after tile (one per worker) and keeps its buffers between them, reserved (Reserve) for the largest ROI.
class TileBlender {
 public:
  virtual ~TileBlender() = default;
  virtual void Prepare(const cv::Rect& roi) = 0;
  // image: CV_8UC3, mask: CV_8U (255 = this frame owns the pixel), top_left in canvas pixels.
  virtual void Feed(const cv::Mat& image, const cv::Mat& mask, cv::Point top_left) = 0;
  // Writes the blended ROI (CV_8UC3) and its coverage (CV_8U), into *image and *mask's own memory when they are
  // already of the ROI's size and those types.
  virtual void Blend(cv::Mat* image, cv::Mat* mask) = 0;
  // Makes every buffer a ROI of up to `largest_roi` can need now, resident: the blender then allocates nothing per
  // tile, and its memory is the same for every tile and flight (else it grew with the largest piece a flight happened
  // to feed: 1.4-1.6 MiB more per worker at 5000 frames than at 200).
  virtual void Reserve(cv::Size largest_roi) = 0;
};

// Multi-band (Laplacian pyramid) blending, Burt & Adelson; `num_bands` pyramid levels (fewer for ROIs too small for
// them); the same pixels as OpenCV's cv::detail::MultiBandBlender (16-bit levels, float weights).
[[nodiscard]] std::unique_ptr<TileBlender> MakeMultiBandBlender(int num_bands);
// Hard seams: each pixel from its owner only (used to check the seams, and as a fast preview).
[[nodiscard]] std::unique_ptr<TileBlender> MakeSeamOnlyBlender();

}  // namespace uavm
