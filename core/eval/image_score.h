#pragma once
#include <opencv2/core.hpp>
#include <string>

#include "core/geometry/transform.h"

namespace uavm::eval {

// Score for a mosaic that has no transforms (e.g. a cv::Stitcher panorama): how well one affine explains SIFT
// matches between the mosaic and the canvas it was flown over. Residuals are in canvas pixels.
struct ImageScoreOptions {
  int max_long_side = 2000;  // both images are reduced to at most this for feature extraction
  int max_features = 8000;
  double ratio = 0.75;     // Lowe's ratio test
  double ransac_px = 3.0;  // RANSAC threshold, in reduced canvas pixels
};

struct ImageScore {
  int matches = 0;
  int inliers = 0;
  double median_px = 0.0;
  double p90_px = 0.0;
  Mat3 canvas_from_mosaic = Mat3::Identity();  // least-squares affine over the inliers
};

// `mosaic` may be BGRA (alpha 0 = not flown, ignored), BGR or grey. False with a reason when too few matches.
[[nodiscard]] bool ScoreMosaicImage(const cv::Mat& mosaic, const cv::Mat& canvas, ImageScore* score, std::string* error,
                                    const ImageScoreOptions& options = {});

}  // namespace uavm::eval
