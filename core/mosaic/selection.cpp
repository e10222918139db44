#include "core/mosaic/selection.h"

#include <algorithm>
#include <opencv2/imgproc.hpp>

namespace uavm {

std::vector<bool> SelectByOverlap(const std::vector<std::vector<cv::Point2f>>& footprints, const cv::Rect2d& canvas,
                                  double max_covered_fraction, int raster_long_side) {
  std::vector<bool> keep(footprints.size(), true);
  if (max_covered_fraction >= 1.0 || footprints.empty()) return keep;
  const double s = raster_long_side / std::max(1.0, std::max(canvas.width, canvas.height));
  const cv::Size size(std::max(1, static_cast<int>(std::ceil(canvas.width * s)) + 1),
                      std::max(1, static_cast<int>(std::ceil(canvas.height * s)) + 1));
  cv::Mat covered(size, CV_8U, cv::Scalar(0));
  cv::Mat mine(size, CV_8U);
  for (size_t i = 0; i < footprints.size(); ++i) {
    std::vector<cv::Point> poly;
    for (const auto& p : footprints[i])
      poly.emplace_back(cv::saturate_cast<int>((p.x - canvas.x) * s), cv::saturate_cast<int>((p.y - canvas.y) * s));
    mine.setTo(0);
    cv::fillConvexPoly(mine, poly, cv::Scalar(255));
    const int area = cv::countNonZero(mine);
    if (area == 0) continue;
    cv::Mat both;
    cv::bitwise_and(mine, covered, both);
    const double fraction = static_cast<double>(cv::countNonZero(both)) / area;
    if (i > 0 && fraction > max_covered_fraction) {
      keep[i] = false;
      continue;
    }
    covered |= mine;
  }
  return keep;
}

}  // namespace uavm
