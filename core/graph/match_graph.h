#pragma once
#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <deque>
#include <memory>
#include <span>
#include <utility>
#include <vector>

#include "core/geometry/transform.h"

namespace uavm {

// An edge's correspondences in one block, laid out as edges.bin stores them: the pairs the adjustment uses, then the
// held-out pairs, each pair its source point then its target point, at working resolution, in float. One allocation
// an edge instead of four: the edges are a long flight's largest state, and the end of the flight holds them all.
class EdgePoints {
 public:
  EdgePoints() = default;
  // The pairs (src[k], tgt[k]) and the held-out pairs (holdout_src[k], holdout_tgt[k]); each list of a pair of lists
  // as long as the other (the shorter one's length is taken).
  template <typename Point>
  EdgePoints(const std::vector<Point>& src, const std::vector<Point>& tgt, const std::vector<Point>& holdout_src,
             const std::vector<Point>& holdout_tgt) {
    const size_t n = std::min(src.size(), tgt.size());
    const size_t m = std::min(holdout_src.size(), holdout_tgt.size());
    (void)Reset(n, m);
    for (size_t k = 0; k < n; ++k) Set(k, src[k], tgt[k]);
    for (size_t k = 0; k < m; ++k) Set(n + k, holdout_src[k], holdout_tgt[k]);
  }
  EdgePoints(const EdgePoints& other);
  EdgePoints& operator=(const EdgePoints& other);
  EdgePoints(EdgePoints&& other) noexcept
      : block_(std::move(other.block_)),
        points_(std::exchange(other.points_, 0)),
        pairs_(std::exchange(other.pairs_, 0)) {}
  EdgePoints& operator=(EdgePoints&& other) noexcept {
    block_ = std::move(other.block_);
    points_ = std::exchange(other.points_, 0);
    pairs_ = std::exchange(other.pairs_, 0);
    return *this;
  }
  ~EdgePoints() = default;
  // `pairs`' adjustment pairs with `holdout`'s held-out pairs.
  [[nodiscard]] static EdgePoints Combine(const EdgePoints& pairs, const EdgePoints& holdout);

  [[nodiscard]] size_t size() const { return pairs_; }  // pairs the adjustment uses
  [[nodiscard]] size_t holdout_size() const { return points_ / 2 - pairs_; }
  [[nodiscard]] const Vec2f& src(size_t k) const { return block_[2 * k]; }
  [[nodiscard]] const Vec2f& tgt(size_t k) const { return block_[2 * k + 1]; }
  [[nodiscard]] const Vec2f& holdout_src(size_t k) const { return block_[2 * (pairs_ + k)]; }
  [[nodiscard]] const Vec2f& holdout_tgt(size_t k) const { return block_[2 * (pairs_ + k) + 1]; }
  // Every point, pairs and held-out pairs alike (to move them all, e.g. into another lens).
  [[nodiscard]] std::span<Vec2f> all() { return {block_.get(), points_}; }

  // The block as edges.bin's payload: (size() + holdout_size()) x {x_src, y_src, x_tgt, y_tgt}.
  [[nodiscard]] const float* floats() const { return reinterpret_cast<const float*>(block_.get()); }
  [[nodiscard]] size_t float_count() const { return 2 * size_t{points_}; }
  // Room for `pairs` and `holdout` pairs, returned to be filled in that layout.
  [[nodiscard]] float* Reset(size_t pairs, size_t holdout);

  // Keeps at most `max_pairs` pairs and `max_holdout` held-out pairs, evenly strided (the points are grid-spread, so a
  // stride keeps their spread); frees what it drops. Returns the pairs dropped.
  size_t Thin(size_t max_pairs, size_t max_holdout);
  void Free();
  [[nodiscard]] size_t bytes() const { return size_t{points_} * sizeof(Vec2f); }

 private:
  template <typename Point>
  void Set(size_t pair, const Point& a, const Point& b) {
    block_[2 * pair] = a.template cast<float>();
    block_[2 * pair + 1] = b.template cast<float>();
  }

  // The block and two counts, not a std::vector: 16 bytes an edge instead of 32 (an edge record is 120 bytes, so a
  // std::deque node of 512 holds four edges instead of three), and no spare capacity.
  std::unique_ptr<Vec2f[]> block_;
  uint32_t points_ = 0;  // in the block: 2 x (pairs + held-out pairs)
  uint32_t pairs_ = 0;
};
static_assert(sizeof(EdgePoints) == 16, "an edge's points are a pointer and two counts");
static_assert(sizeof(Vec2f) == 2 * sizeof(float), "EdgePoints reads its block as floats");

// A verified pair. Its points are in float: float is what edges.bin keeps (an edge read back gives the same solution as
// one never spilled).
struct Edge {
  int src = -1;
  int tgt = -1;
  int num_matches = 0;
  int num_inliers = 0;
  Mat3 tgt_from_src = Mat3::Identity();
  EdgePoints points;
  // Where the points live: an edge whose frames no longer move during the flight keeps them only on disk
  // (EdgeStore, edges.bin at byte stored_at) until the end of the flight reads them back.
  int64_t stored_at = -1;
  bool points_resident = true;
};
// A long flight holds every edge's record to its end, in a std::deque whose nodes are 512 bytes: four records a node.
static_assert(sizeof(Edge) <= 128, "an edge record grew past a quarter of a deque node");

// Where a solve reads each edge's points. Without one (null) a solve reads the edges' own, resident points; the end of
// a long flight passes one that reads them back from edges.bin an edge at a time, so that the solves hold no edge's
// points beyond the one they are reading (RegistrationEngine's EndPointReader). Used from one thread.
class EdgePointSource {
 public:
  virtual ~EdgePointSource() = default;
  // `edge`'s points as the solve takes them, valid until the next call; empty when they cannot be read.
  [[nodiscard]] virtual const EdgePoints& Points(const Edge& edge) = 0;
};

[[nodiscard]] inline const EdgePoints& PointsOf(const Edge& edge, EdgePointSource* source) {
  return source != nullptr ? source->Points(edge) : edge.points;
}

class UnionFind {
 public:
  int Add();  // returns the new element's id (ids are dense, 0..n-1)
  [[nodiscard]] int Find(int x);
  // Returns the root of the merged set.
  int Unite(int a, int b);
  [[nodiscard]] int SizeOf(int x) { return size_[static_cast<size_t>(Find(x))]; }
  [[nodiscard]] size_t size() const { return parent_.size(); }

 private:
  std::vector<int> parent_;
  std::vector<int> size_;
};

class MatchGraph {
 public:
  void AddNode(int id);
  void AddEdge(Edge edge);
  // A deque: edges are never moved once added (no doubling copy of every record as a long flight grows them).
  [[nodiscard]] const std::deque<Edge>& edges() const { return edges_; }
  // For the edges' points and transforms; an edge's num_inliers stays as it was added (MaxInliers is kept as edges
  // come).
  [[nodiscard]] std::deque<Edge>& mutable_edges() { return edges_; }
  [[nodiscard]] const std::vector<int>& nodes() const { return nodes_; }
  [[nodiscard]] int MaxInliers() const { return max_inliers_; }
  // An edge counts when its inliers reach both the absolute floor and `relative` x the best edge's count
  // (the seed method's 5 % rule). Returns the node ids of the largest connected component over counting edges,
  // sorted ascending; ties go to the component with the smallest frame id.
  [[nodiscard]] std::vector<int> LargestComponent(double relative, int absolute_floor) const;
  // Every connected component over the edges that count, largest first (ties: lowest first id), members ascending.
  [[nodiscard]] std::vector<std::vector<int>> ComponentsBySize(double relative, int absolute_floor) const;
  [[nodiscard]] bool EdgeCounts(const Edge& e, double relative, int absolute_floor) const;
  // Frees every edge record (the end of the flight, once its tables are written: edges.bin and graph.csv keep them).
  void ReleaseEdges() { std::deque<Edge>().swap(edges_); }

 private:
  std::vector<int> nodes_;
  std::deque<Edge> edges_;
  // Kept as edges are added: EdgeCounts asks it once per edge, and scanning every edge each time made the end's
  // edge lists and tables quadratic in the flight's edges.
  int max_inliers_ = 0;
};

}  // namespace uavm
