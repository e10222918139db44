#pragma once
#include <cstddef>
#include <cstdint>
#include <deque>
#include <vector>

#include "core/geometry/transform.h"

namespace uavm {

// A verified pair. Points are at working resolution of each frame, in float: the edges are the end of a long flight's
// largest state, and float is what edges.bin keeps (an edge read back gives the same solution as one never spilled).
struct Edge {
  int src = -1;
  int tgt = -1;
  int num_matches = 0;
  int num_inliers = 0;
  Mat3 tgt_from_src = Mat3::Identity();
  std::vector<Vec2f> src_points;
  std::vector<Vec2f> tgt_points;
  std::vector<Vec2f> holdout_src_points;  // inliers the adjustment does not use: a check of its result
  std::vector<Vec2f> holdout_tgt_points;
  // Where the points live: an edge whose frames no longer move during the flight keeps them only on disk
  // (EdgeStore, edges.bin at byte stored_at) until the end of the flight reads them back.
  int64_t stored_at = -1;
  bool points_resident = true;
};

// Points in an edge's precision; the double ones are freed (taken by value: pass them moved).
[[nodiscard]] std::vector<Vec2f> ToEdgePoints(std::vector<Vec2> points);

// Keeps at most `max_points` of the edge's points and `max_holdout` of its held-out points, evenly strided (the points
// are grid-spread, so a stride keeps their spread); frees what it drops. Returns the points dropped.
size_t ThinPoints(Edge* edge, size_t max_points, size_t max_holdout);

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
  [[nodiscard]] std::deque<Edge>& mutable_edges() { return edges_; }
  [[nodiscard]] const std::vector<int>& nodes() const { return nodes_; }
  [[nodiscard]] int MaxInliers() const;
  // An edge counts when its inliers reach both the absolute floor and `relative` x the best edge's count
  // (the seed method's 5 % rule). Returns the node ids of the largest connected component over counting edges,
  // sorted ascending; ties go to the component with the smallest frame id.
  [[nodiscard]] std::vector<int> LargestComponent(double relative, int absolute_floor) const;
  // Every connected component over the edges that count, largest first (ties: lowest first id), members ascending.
  [[nodiscard]] std::vector<std::vector<int>> ComponentsBySize(double relative, int absolute_floor) const;
  [[nodiscard]] bool EdgeCounts(const Edge& e, double relative, int absolute_floor) const;

 private:
  std::vector<int> nodes_;
  std::deque<Edge> edges_;
};

}  // namespace uavm
