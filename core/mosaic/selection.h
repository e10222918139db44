#pragma once
#include <opencv2/core.hpp>
#include <vector>

namespace uavm {

// Overlap-based frame selection (the seed method's resampleByOverlap): walking frames in order, a frame whose
// footprint is covered more than `max_covered_fraction` by frames already kept adds nothing but ghosting and time,
// so it is dropped. Footprints are polygons in canvas pixels; coverage is rasterised at `raster_long_side`.
// Returns a keep flag per footprint.
[[nodiscard]] std::vector<bool> SelectByOverlap(const std::vector<std::vector<cv::Point2f>>& footprints,
                                                const cv::Rect2d& canvas, double max_covered_fraction,
                                                int raster_long_side = 1024);

}  // namespace uavm
