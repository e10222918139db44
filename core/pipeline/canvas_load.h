#pragma once
// How the compositor reads a stored frame (frames/) at the canvas's sampling, and by parts.
#include <opencv2/core.hpp>
#include <string>

#include "core/mosaic/compositor.h"

namespace uavm {

// How a stored frame is read for the canvas: JPEG DCT-scaled decode by 1/reduce, then resized to `size` only when the
// decode is finer than the canvas's own sampling of the frame (an enlargement would add bytes, not detail: the warp
// onto the canvas resamples anyway), so cached images are no larger than the canvas needs.
struct CanvasLoad {
  int reduce = 1;
  cv::Size size;
  bool jpeg = false;      // then decoded by parts (see LoadCanvasPart)
  cv::Size decoded;       // the whole frame at 1/reduce
  size_t peak_bytes = 0;  // the whole decode plus its resized copy, if any: what a whole load holds at once
};

// The plan for a frame of `original` size stored at `path`; `keep`: canvas pixels per original pixel (at most 1).
[[nodiscard]] CanvasLoad PlanCanvasLoad(const std::string& path, cv::Size original, double keep);

// Part `need` (pixels of the load's grid, how.size) of a stored frame. A JPEG is decoded only over it, at the plan's
// DCT scale; when the plan resizes, the decoded part is resized with the whole frame's scale, so its pixels are the
// whole load's and only its origin moves (by a fraction of a pixel). Other formats, and a JPEG that libjpeg cannot
// decode by parts (CMYK), are loaded whole. Empty image: unreadable.
[[nodiscard]] FramePart LoadCanvasPart(const std::string& path, const CanvasLoad& how, const cv::Rect& need);

}  // namespace uavm
