#pragma once
#include <memory>
#include <opencv2/flann.hpp>
#include <string>
#include <vector>

#include "core/estimators/ransac.h"
#include "core/features/sift.h"
#include "core/geometry/transform.h"
#include "core/matching/descriptor_distance.h"
#include "core/matching/kd_forest.h"

namespace uavm {

struct MatchOptions {
  double ratio = 0.8;  // Lowe's ratio test (RootSIFT distances)
  int flann_trees = 4;
  // Points compared per query at most (beyond the first leaf of each tree).
  int flann_checks = 64;
  // Points per kd-tree leaf: more than 1 = the bucketed kd-forest of core/matching/kd_forest.h (4 with 64 checks:
  // matching ~40 % cheaper than cvflann, errors within 2 % on the simulated flights); 1 = cvflann's KDTreeIndex (one
  // point per leaf; 32 checks was its setting).
  int flann_leaf_size = 4;
  RansacOptions ransac;
  // A verified pair becomes a graph edge only with at least this many inliers (the seed method's relative 5 %
  // threshold is applied on top, in the graph).
  int min_inliers = 20;
  // Reject relative affines no drone flight produces (scale jump, strong shear, mirror).
  double max_scale_change = 2.0;
  double max_anisotropy = 0.25;
  // Correspondences kept per edge for the adjustment, spread over a grid of the source frame.
  int max_edge_correspondences = 64;
  int correspondence_grid = 8;
  // true: each kept correspondence is a grid cell's mean (CellMeanCorrespondences): every inlier counts, each cell of
  // the overlap weighs the same; at most correspondence_grid^2 of them (the grid shrinks to fit
  // max_edge_correspondences), the inliers themselves when they fill fewer than 4 cells. false: inliers picked
  // round-robin over the cells, each cell's first in keypoint order first. Off under subpixel.enabled (it tracks
  // keypoints).
  bool average_cells = true;
  // Further inliers, disjoint from those, kept aside per edge: the report's held-out residual (a check of the final
  // maps on points the adjustment never saw).
  int holdout_correspondences = 16;
  // A guided query (the pair's overlap already predicted) asks at most this many of the source points predicted
  // inside, spread over the overlap: the edge keeps max_edge_correspondences + holdout_correspondences inliers, and
  // hundreds of inliers fix a relative affine as well as thousands, at a fraction of the kd-tree searches. 0 = all.
  int max_guided_queries = 1200;

  [[nodiscard]] bool Check(std::string* why) const;
};

// FLANN kd-tree over one frame's 8-bit descriptors; built once per frame, queried by every candidate.
// The tree is cvflann's templated index compiled into this project (not the prebuilt cv::flann::Index): with
// integer-valued descriptors and -ffp-contract=off, an x86-64 and an aarch64 build build the same tree and return the
// same neighbours, so both produce the same mosaic. It also holds a quarter of the float copy's bytes.
class DescriptorIndex {
 public:
  DescriptorIndex(const Features& features, const MatchOptions& options);
  // For each row of `query`, its nearest neighbour here when it passes the ratio test; one-to-one (each point here
  // keeps its best query). DMatch.queryIdx indexes `query`, trainIdx this index's features; DMatch.distance is the
  // squared L2 distance between the 8-bit descriptors.
  [[nodiscard]] std::vector<cv::DMatch> Match(const cv::Mat& query_descriptors) const;
  [[nodiscard]] bool empty() const { return rows_ < 2; }

 private:
  using Tree = cvflann::Index<ByteL2>;
  cv::Mat descriptors_;  // CV_8U rows owned here (the tree borrows them)
  std::unique_ptr<Tree> index_;
  std::unique_ptr<KdForest> forest_;  // instead of index_ with flann_leaf_size > 1
  int rows_ = 0;
  MatchOptions options_;
};

// A verified pair: tgt_from_src maps pixels of the source frame to the target frame (working resolution).
struct PairResult {
  bool ok = false;
  int num_matches = 0;
  int num_inliers = 0;
  Mat3 tgt_from_src = Mat3::Identity();
  std::vector<Vec2> src_points;  // the adjustment's: cell means or grid-picked inliers (average_cells)
  std::vector<Vec2> tgt_points;
  std::vector<Vec2> holdout_src_points;  // further inliers, not in src_points (see holdout_correspondences)
  std::vector<Vec2> holdout_tgt_points;
  std::string failure;
};

// A prediction of where the source lands in the target: only source points predicted inside the target frame
// (grown by `margin` of its size) are queried. Halves the work for a typical overlap and removes hopeless matches.
// (A finer guide, candidates only within a radius of each predicted point, is radius_matcher.h's, the ground tool's.)
struct MatchGuide {
  Mat3 tgt_from_src = Mat3::Identity();
  cv::Size tgt_size;
  double margin = 0.15;
};

// A relative affine two frames of one flight can have: no mirror, no scale jump beyond max_scale_change, no shear
// beyond max_anisotropy. RANSAC only lets such models compete.
[[nodiscard]] bool PlausibleRelative(const Mat3& tgt_from_src, const MatchOptions& options);

// Matches `src` against the indexed target and verifies with RANSAC affine.
[[nodiscard]] PairResult MatchPair(const DescriptorIndex& tgt_index, const Features& tgt, const Features& src,
                                   const MatchOptions& options, const MatchGuide* guide = nullptr);

// Keeps at most `max_points` pairs, spread over a grid x grid partition of the source points' bounding box.
void GridSubsample(std::vector<Vec2>* src, std::vector<Vec2>* tgt, int grid, int max_points);
// The indices GridSubsample keeps, ascending.
[[nodiscard]] std::vector<size_t> GridSubsampleIndices(const std::vector<Vec2>& src, int grid, int max_points);
// One correspondence per occupied cell of a grid x grid division of src's bounding box, appended: the cell's centroid
// and its image under tgt_from_src plus the cell's mean residual tgt - tgt_from_src(src). Where tgt_from_src follows
// the true map to first order across a cell, the mean residual speaks for the centroid, and the keypoints' noise is
// averaged over the cell's points (a single point comes out as it went in). Under a curved residual (a lens the
// reference does not model) the mean flattens the curvature a little: ~0.1 px at -10 % barrel on 640 px frames.
void CellMeanCorrespondences(const std::vector<Vec2>& src, const std::vector<Vec2>& tgt, const Mat3& tgt_from_src,
                             int grid, std::vector<Vec2>* cell_src, std::vector<Vec2>* cell_tgt);

// Descriptor storage helpers: RootSIFT values lie in [0,1]; 8-bit storage quarters memory at no matching cost.
[[nodiscard]] cv::Mat QuantizeDescriptors(const cv::Mat& float_descriptors);
[[nodiscard]] cv::Mat DequantizeDescriptors(const cv::Mat& u8_descriptors);

}  // namespace uavm
