#pragma once
#include <opencv2/core.hpp>
#include <vector>

#include "core/geometry/transform.h"

namespace uavm {

// Guided matching by position, for frames whose relative placement is already known well (the ground tool, from the
// onboard maps): a point of A is compared, exhaustively, only with the points of B within `radius_px` of where
// `b_from_a` predicts it, then the ratio test among those candidates and the mutual check (the point of B has that
// point of A as its best among every point of A that reached it). At full resolution this keeps the ratio test
// meaningful: the unguided nearest neighbour among thousands of fine-scale features is too often a look-alike.
// MatchPair (pair_matcher.h) is the other guided matcher: its guide only drops source points predicted outside the
// target, the search stays the kd-tree over the whole frame (a coarse prediction, many pairs a second onboard).
struct RadiusMatchOptions {
  double radius_px = 0;  // in B's pixels
  double ratio = 0.8;    // Lowe's ratio test (on the distances, not their squares)
};

struct RadiusMatch {
  int a = -1;             // index into A's points
  int b = -1;             // into B's
  float distance_sq = 0;  // squared L2 between the descriptors
};

// `size_b`: B's frame (its points are bucketed over it). Descriptors: one row per point, float. The matches ascend in
// a.
[[nodiscard]] std::vector<RadiusMatch> MatchWithinRadius(const std::vector<Vec2>& points_a,
                                                         const cv::Mat& descriptors_a,
                                                         const std::vector<Vec2>& points_b,
                                                         const cv::Mat& descriptors_b, cv::Size size_b,
                                                         const Mat3& b_from_a, const RadiusMatchOptions& options);

}  // namespace uavm
