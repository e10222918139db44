#pragma once
// Pixel work of the live tile pyramid: a frame warped into one 256x256 RGBA tile with a feathered blend, and a parent
// tile made from its four children.
#include <opencv2/core.hpp>

#include "core/geometry/transform.h"

namespace uavm {

// Blend weight of a w x h frame (CV_8U): 255 inside, ramping down over `feather` pixels to its border (>= 1 on every
// frame pixel, so that coverage is never lost).
[[nodiscard]] cv::Mat FeatherWeight(cv::Size size, int feather);

// Draws `bgr` (with its `weight`) into `tile` (CV_8UC4) through tile_from_work (work pixel centres -> tile pixel
// centres): where the tile is empty the frame is taken as is; elsewhere newest on top, blended by the weight. Returns
// false when the frame does not reach the tile.
bool PaintFrame(const cv::Mat& bgr, const cv::Mat& weight, const Mat3& tile_from_work, cv::Mat* tile);

// `children` (512x512 RGBA, the four children in place) halved into `parent` (256x256 RGBA), averaging colours by
// their alpha (a transparent child pixel adds no black).
void HalveRgba(const cv::Mat& children, cv::Mat* parent);

// Largest distance a corner of a w x h frame moves between two transforms.
[[nodiscard]] double MaxCornerShift(const Mat3& before, const Mat3& after, cv::Size size);

// Whether the frame's footprint meets the max_zoom tile (x, y) (its pixels [x*256, (x+1)*256) in both axes).
[[nodiscard]] bool FrameTouchesTile(const Mat3& grid_from_work, cv::Size size, int x, int y);

}  // namespace uavm
