#include "core/matching/pair_matcher.h"

#include <algorithm>
#include <cmath>
#include <numeric>
#include <unordered_map>

#include "core/estimators/affine.h"
#include "core/estimators/homography.h"

namespace uavm {

namespace {
constexpr double kQuantScale = 512.0;

}  // namespace

bool MatchOptions::Check(std::string* why) const {
  auto fail = [&](const char* msg) {
    if (why != nullptr) *why = msg;
    return false;
  };
  if (!(ratio > 0.0 && ratio <= 1.0)) return fail("matching.ratio must be in (0,1]");
  if (flann_trees < 1 || flann_checks < 1) return fail("matching.flann_trees and flann_checks must be >= 1");
  if (flann_leaf_size < 1 || flann_leaf_size > 64) return fail("matching.flann_leaf_size must be in [1, 64]");
  if (min_inliers < 6) return fail("matching.min_inliers must be >= 6");
  if (!(max_scale_change > 1.0)) return fail("matching.max_scale_change must be > 1");
  if (!(max_anisotropy > 0.0)) return fail("matching.max_anisotropy must be > 0");
  if (max_edge_correspondences < 3) return fail("matching.max_edge_correspondences must be >= 3");
  if (correspondence_grid < 1 || correspondence_grid > 64)
    return fail("matching.correspondence_grid must be in [1, 64]");
  // Cell means: a grid of floor(sqrt(max_edge_correspondences)) cells a side at most, and one cell is no geometry.
  if (average_cells && (max_edge_correspondences < 4 || correspondence_grid < 2))
    return fail("matching.average_cells needs matching.max_edge_correspondences >= 4 and correspondence_grid >= 2");
  if (holdout_correspondences < 0) return fail("matching.holdout_correspondences must be >= 0");
  if (max_guided_queries != 0 && max_guided_queries < min_inliers)
    return fail("matching.max_guided_queries must be 0 (all) or >= min_inliers");
  return ransac.Check(why);
}

cv::Mat QuantizeDescriptors(const cv::Mat& f) {
  if (f.type() == CV_8U) return f;  // already quantised (read back from the session)
  cv::Mat out;
  f.convertTo(out, CV_8U, kQuantScale);  // saturating
  return out;
}

cv::Mat DequantizeDescriptors(const cv::Mat& q) {
  cv::Mat out;
  q.convertTo(out, CV_32F, 1.0 / kQuantScale);
  return out;
}

DescriptorIndex::DescriptorIndex(const Features& features, const MatchOptions& options)
    : rows_(features.descriptors.rows), options_(options) {
  descriptors_ = QuantizeDescriptors(features.descriptors);
  if (!descriptors_.isContinuous() || descriptors_.data == features.descriptors.data) {
    descriptors_ = descriptors_.clone();
  }
  if (rows_ >= 2 && options.flann_leaf_size > 1) {
    forest_ = std::make_unique<KdForest>(descriptors_,
                                         KdForest::Options{options.flann_trees, options.flann_leaf_size, 0x5eed});
  } else if (rows_ >= 2) {
    const cvflann::Matrix<unsigned char> rows(descriptors_.ptr<unsigned char>(), static_cast<size_t>(rows_),
                                              static_cast<size_t>(descriptors_.cols));
    index_ = std::make_unique<Tree>(rows, cvflann::KDTreeIndexParams(options.flann_trees));
    index_->buildIndex();
  }
}

std::vector<cv::DMatch> DescriptorIndex::Match(const cv::Mat& query_descriptors) const {
  std::vector<cv::DMatch> out;
  if ((!index_ && !forest_) || query_descriptors.rows < 1 || query_descriptors.cols != descriptors_.cols) return out;
  cv::Mat query = QuantizeDescriptors(query_descriptors);
  if (!query.isContinuous()) query = query.clone();
  cv::Mat indices(query.rows, 2, CV_32S);
  cv::Mat dists(query.rows, 2, CV_32F);
  if (forest_) {
    for (int q = 0; q < query.rows; ++q) {
      int idx[2];
      uint32_t d[2];
      forest_->Nearest2(query.ptr<uint8_t>(q), options_.flann_checks, idx, d);
      for (int k = 0; k < 2; ++k) {
        indices.at<int>(q, k) = idx[k];
        dists.at<float>(q, k) = static_cast<float>(d[k]);  // exact: below 2^24
      }
    }
  } else {
    cvflann::Matrix<unsigned char> query_rows(query.ptr<unsigned char>(), static_cast<size_t>(query.rows),
                                              static_cast<size_t>(query.cols));
    cvflann::Matrix<int> index_rows(indices.ptr<int>(), static_cast<size_t>(query.rows), 2);
    cvflann::Matrix<float> dist_rows(dists.ptr<float>(), static_cast<size_t>(query.rows), 2);
    index_->knnSearch(query_rows, index_rows, dist_rows, 2, cvflann::SearchParams(options_.flann_checks));
  }
  const float ratio_sq = static_cast<float>(options_.ratio * options_.ratio);  // squared distances
  std::unordered_map<int, size_t> best_for_train;
  for (int q = 0; q < query.rows; ++q) {
    const int t = indices.at<int>(q, 0);
    const float d0 = dists.at<float>(q, 0);
    const float d1 = dists.at<float>(q, 1);
    if (t < 0 || t >= rows_ || !(d0 < ratio_sq * d1)) continue;
    auto it = best_for_train.find(t);
    if (it == best_for_train.end()) {
      best_for_train.emplace(t, out.size());
      out.emplace_back(q, t, d0);
    } else if (d0 < out[it->second].distance) {
      out[it->second] = cv::DMatch(q, t, d0);
    }
  }
  return out;
}

namespace {

// The points of each cell of a grid x grid division of their bounding box, row by row (ascending indices in a cell).
std::vector<std::vector<size_t>> GridCells(const std::vector<Vec2>& src, int grid) {
  Vec2 lo = src[0];
  Vec2 hi = lo;
  for (const auto& p : src) {
    lo = lo.cwiseMin(p);
    hi = hi.cwiseMax(p);
  }
  const Vec2 extent = (hi - lo).cwiseMax(Vec2(1e-6, 1e-6));
  std::vector<std::vector<size_t>> cells(static_cast<size_t>(grid * grid));
  for (size_t i = 0; i < src.size(); ++i) {
    const Vec2 r = (src[i] - lo).cwiseQuotient(extent);
    const int cx = std::min(grid - 1, static_cast<int>(r.x() * grid));
    const int cy = std::min(grid - 1, static_cast<int>(r.y() * grid));
    cells[static_cast<size_t>(cy * grid + cx)].push_back(i);
  }
  return cells;
}

}  // namespace

std::vector<size_t> GridSubsampleIndices(const std::vector<Vec2>& src, int grid, int max_points) {
  const size_t n = src.size();
  std::vector<size_t> keep;
  if (n <= static_cast<size_t>(std::max(0, max_points))) {
    for (size_t i = 0; i < n; ++i) keep.push_back(i);
    return keep;
  }
  if (max_points <= 0) return keep;
  const std::vector<std::vector<size_t>> cells = GridCells(src, grid);
  // Round-robin over cells: every occupied cell is represented before any cell gets a second point.
  keep.reserve(static_cast<size_t>(max_points));
  for (size_t round = 0; keep.size() < static_cast<size_t>(max_points); ++round) {
    bool any = false;
    for (const auto& cell : cells) {
      if (round < cell.size()) {
        any = true;
        // Spread picks inside a cell rather than taking its first points (which cluster by detection order).
        keep.push_back(cell[(round * 7919) % cell.size()]);
        if (keep.size() == static_cast<size_t>(max_points)) break;
      }
    }
    if (!any) break;
  }
  std::sort(keep.begin(), keep.end());
  keep.erase(std::unique(keep.begin(), keep.end()), keep.end());
  return keep;
}

void CellMeanCorrespondences(const std::vector<Vec2>& src, const std::vector<Vec2>& tgt, const Mat3& tgt_from_src,
                             int grid, std::vector<Vec2>* cell_src, std::vector<Vec2>* cell_tgt) {
  if (src.empty() || grid < 1 || tgt.size() != src.size()) return;
  for (const std::vector<size_t>& cell : GridCells(src, grid)) {
    if (cell.empty()) continue;
    Vec2 centroid = Vec2::Zero();
    Vec2 residual = Vec2::Zero();
    for (size_t i : cell) {
      centroid += src[i];
      residual += tgt[i] - Apply(tgt_from_src, src[i]);
    }
    const double n = static_cast<double>(cell.size());
    centroid /= n;
    cell_src->push_back(centroid);
    cell_tgt->push_back(Apply(tgt_from_src, centroid) + residual / n);
  }
}

void GridSubsample(std::vector<Vec2>* src, std::vector<Vec2>* tgt, int grid, int max_points) {
  if (src->size() <= static_cast<size_t>(max_points)) return;
  const std::vector<size_t> keep = GridSubsampleIndices(*src, grid, max_points);
  std::vector<Vec2> s;
  std::vector<Vec2> t;
  s.reserve(keep.size());
  t.reserve(keep.size());
  for (size_t i : keep) {
    s.push_back((*src)[i]);
    t.push_back((*tgt)[i]);
  }
  *src = std::move(s);
  *tgt = std::move(t);
}

bool PlausibleRelative(const Mat3& tgt_from_src, const MatchOptions& options) {
  const LinearPart lin = Decompose(tgt_from_src);
  return lin.det > 0 && lin.scale <= options.max_scale_change && lin.scale >= 1.0 / options.max_scale_change &&
         lin.anisotropy <= options.max_anisotropy;
}

namespace {

// The inliers of an edge split into the adjustment's sample (one per cell, round-robin, spread over the frame) and a
// disjoint, equally spread sample held out to check the maps: indices of each, ascending.
void SplitInliers(const std::vector<Vec2>& in_src, const MatchOptions& options, std::vector<size_t>* kept,
                  std::vector<size_t>* held) {
  *kept = GridSubsampleIndices(in_src, options.correspondence_grid, options.max_edge_correspondences);
  held->clear();
  std::vector<char> is_kept(in_src.size(), 0);
  for (size_t i : *kept) is_kept[i] = 1;
  std::vector<size_t> rest;
  std::vector<Vec2> rest_src;
  for (size_t i = 0; i < in_src.size(); ++i)
    if (is_kept[i] == 0) {
      rest.push_back(i);
      rest_src.push_back(in_src[i]);
    }
  for (size_t k : GridSubsampleIndices(rest_src, options.correspondence_grid, options.holdout_correspondences))
    held->push_back(rest[k]);
}

// Fewer occupied cells than this (of a grid of 8 x 8 by default: inliers along a line) and an edge keeps its inliers
// instead of cell means. 8 moved the held-out RMS of brighton_beach 0.99 -> 1.31 px and of caliterra 0.85 -> 0.80:
// no clear gain; below 4 means an affine is barely fixed.
constexpr size_t kMinCellMeans = 4;

// A homography fitted to the inliers serves as the cells' reference only where it is a proper map of them: every
// source point well in front of its line at infinity (w = h20 x + h21 y + 1 within a factor of 2 over the points: no
// drone frame pair has more perspective than that) and every inlier within twice RANSAC's threshold of it (a
// least-squares fit to a narrow band of points can fold; the RANSAC affine then serves).
bool UsableReference(const Mat3& h, const std::vector<Vec2>& src, const std::vector<Vec2>& tgt,
                     const MatchOptions& options) {
  double lo = 1e300;
  double hi = -1e300;
  const double max_sq = 4.0 * options.ransac.max_error * options.ransac.max_error;
  for (size_t i = 0; i < src.size(); ++i) {
    const double w = h(2, 0) * src[i].x() + h(2, 1) * src[i].y() + h(2, 2);
    lo = std::min(lo, w);
    hi = std::max(hi, w);
    if (!(w > 0.0) || !((Apply(h, src[i]) - tgt[i]).squaredNorm() <= max_sq)) return false;
  }
  return hi <= 2.0 * lo;
}

// The adjustment's points: the kept sample of SplitInliers as it is, or (average_cells) every inlier not held out
// as its cell's mean (CellMeanCorrespondences), referred to the homography of those inliers (the RANSAC affine where
// they fix none, or none that UsableReference accepts). The held-out sample is the same either way.
void KeepCorrespondences(const std::vector<Vec2>& in_src, const std::vector<Vec2>& in_tgt, const Mat3& affine,
                         const MatchOptions& options, PairResult* result) {
  std::vector<size_t> kept;
  std::vector<size_t> held;
  SplitInliers(in_src, options, &kept, &held);
  for (size_t i : held) {
    result->holdout_src_points.push_back(in_src[i]);
    result->holdout_tgt_points.push_back(in_tgt[i]);
  }
  const auto keep_inliers = [&] {
    for (size_t i : kept) {
      result->src_points.push_back(in_src[i]);
      result->tgt_points.push_back(in_tgt[i]);
    }
  };
  if (!options.average_cells) return keep_inliers();
  std::vector<char> is_held(in_src.size(), 0);
  for (size_t i : held) is_held[i] = 1;
  std::vector<Vec2> src;
  std::vector<Vec2> tgt;
  for (size_t i = 0; i < in_src.size(); ++i)
    if (is_held[i] == 0) {
      src.push_back(in_src[i]);
      tgt.push_back(in_tgt[i]);
    }
  Mat3 reference = affine;
  if (Mat3 h; HomographyEstimator::Fit(src, tgt, &h) && UsableReference(h, src, tgt, options)) reference = h;
  int grid = options.correspondence_grid;  // at most max_edge_correspondences cells
  while (grid > 1 && grid * grid > options.max_edge_correspondences) --grid;
  std::vector<Vec2> cell_src;
  std::vector<Vec2> cell_tgt;
  CellMeanCorrespondences(src, tgt, reference, grid, &cell_src, &cell_tgt);
  // Inliers along a band fill few cells: then the inliers themselves, as many as the old sample had.
  if (cell_src.size() < std::min<size_t>(kept.size(), kMinCellMeans)) return keep_inliers();
  result->src_points = std::move(cell_src);
  result->tgt_points = std::move(cell_tgt);
}

}  // namespace

PairResult MatchPair(const DescriptorIndex& tgt_index, const Features& tgt, const Features& src,
                     const MatchOptions& options, const MatchGuide* guide) {
  PairResult result;
  if (tgt_index.empty() || src.size() < 3) {
    result.failure = "too few features";
    return result;
  }
  std::vector<cv::DMatch> matches;
  if (guide == nullptr) {
    matches = tgt_index.Match(src.descriptors);
  } else {
    const double mx = guide->margin * guide->tgt_size.width;
    const double my = guide->margin * guide->tgt_size.height;
    std::vector<int> rows;
    rows.reserve(src.size());
    for (size_t i = 0; i < src.size(); ++i) {
      const Vec2 p = Apply(guide->tgt_from_src, Vec2(src.points[i].x, src.points[i].y));
      if (p.x() >= -mx && p.y() >= -my && p.x() <= guide->tgt_size.width + mx && p.y() <= guide->tgt_size.height + my)
        rows.push_back(static_cast<int>(i));
    }
    if (static_cast<int>(rows.size()) < options.min_inliers) {
      result.failure = "predicted overlap too small";
      return result;
    }
    if (options.max_guided_queries > 0 && static_cast<int>(rows.size()) > options.max_guided_queries) {
      std::vector<Vec2> inside;
      inside.reserve(rows.size());
      for (int r : rows)
        inside.emplace_back(src.points[static_cast<size_t>(r)].x, src.points[static_cast<size_t>(r)].y);
      constexpr int kQueryGrid = 16;
      std::vector<int> spread;
      for (size_t k : GridSubsampleIndices(inside, kQueryGrid, options.max_guided_queries)) spread.push_back(rows[k]);
      rows = std::move(spread);
    }
    cv::Mat query(static_cast<int>(rows.size()), src.descriptors.cols, src.descriptors.type());
    for (size_t k = 0; k < rows.size(); ++k) src.descriptors.row(rows[k]).copyTo(query.row(static_cast<int>(k)));
    matches = tgt_index.Match(query);
    for (auto& m : matches) m.queryIdx = rows[static_cast<size_t>(m.queryIdx)];
  }
  result.num_matches = static_cast<int>(matches.size());
  if (result.num_matches < options.min_inliers) {
    result.failure = "too few descriptor matches";
    return result;
  }
  std::vector<Vec2> xs;
  std::vector<Vec2> ys;
  xs.reserve(matches.size());
  ys.reserve(matches.size());
  for (const auto& m : matches) {
    const cv::Point2f& a = src.points[static_cast<size_t>(m.queryIdx)];
    const cv::Point2f& b = tgt.points[static_cast<size_t>(m.trainIdx)];
    xs.emplace_back(a.x, a.y);
    ys.emplace_back(b.x, b.y);
  }
  RANSAC<AffineEstimator> ransac(options.ransac);
  const auto report = ransac.Estimate(xs, ys, [&options](const Mat3& m) { return PlausibleRelative(m, options); });
  result.num_inliers = static_cast<int>(report.num_inliers);
  if (!report.success || result.num_inliers < options.min_inliers) {
    result.failure = "too few RANSAC inliers (of a plausible relative affine)";
    return result;
  }
  // RANSAC let only plausible models compete: report.model is one (PlausibleRelative).
  std::vector<Vec2> in_src;
  std::vector<Vec2> in_tgt;
  for (size_t i = 0; i < xs.size(); ++i) {
    if (report.inlier_mask[i] == 0) continue;
    in_src.push_back(xs[i]);
    in_tgt.push_back(ys[i]);
  }
  KeepCorrespondences(in_src, in_tgt, report.model, options, &result);
  result.tgt_from_src = report.model;
  result.ok = true;
  return result;
}

}  // namespace uavm
