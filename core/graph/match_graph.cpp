#include "core/graph/match_graph.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <unordered_map>

namespace uavm {

int UnionFind::Add() {
  parent_.push_back(static_cast<int>(parent_.size()));
  size_.push_back(1);
  return parent_.back();
}

int UnionFind::Find(int x) {
  auto ux = static_cast<size_t>(x);
  while (parent_[ux] != static_cast<int>(ux)) {
    parent_[ux] = parent_[static_cast<size_t>(parent_[ux])];  // path halving
    ux = static_cast<size_t>(parent_[ux]);
  }
  return static_cast<int>(ux);
}

int UnionFind::Unite(int a, int b) {
  int ra = Find(a);
  int rb = Find(b);
  if (ra == rb) return ra;
  if (size_[static_cast<size_t>(ra)] < size_[static_cast<size_t>(rb)]) std::swap(ra, rb);
  parent_[static_cast<size_t>(rb)] = ra;
  size_[static_cast<size_t>(ra)] += size_[static_cast<size_t>(rb)];
  return ra;
}

void MatchGraph::AddNode(int id) {
  nodes_.push_back(id);
}

void MatchGraph::AddEdge(Edge edge) {
  max_inliers_ = std::max(max_inliers_, edge.num_inliers);
  edges_.push_back(std::move(edge));
}

bool MatchGraph::EdgeCounts(const Edge& e, double relative, int absolute_floor) const {
  const double threshold = std::max(static_cast<double>(absolute_floor), relative * MaxInliers());
  return e.num_inliers >= threshold;
}

std::vector<int> MatchGraph::LargestComponent(double relative, int absolute_floor) const {
  auto all = ComponentsBySize(relative, absolute_floor);
  return all.empty() ? std::vector<int>{} : std::move(all.front());
}

std::vector<std::vector<int>> MatchGraph::ComponentsBySize(double relative, int absolute_floor) const {
  std::unordered_map<int, int> dense;
  for (int id : nodes_) dense.emplace(id, static_cast<int>(dense.size()));
  UnionFind uf;
  for (size_t i = 0; i < dense.size(); ++i) uf.Add();
  const double threshold = std::max(static_cast<double>(absolute_floor), relative * MaxInliers());
  for (const auto& e : edges_) {
    if (e.num_inliers < threshold) continue;
    auto a = dense.find(e.src);
    auto b = dense.find(e.tgt);
    if (a != dense.end() && b != dense.end()) uf.Unite(a->second, b->second);
  }
  std::map<int, std::vector<int>> groups;
  for (int id : nodes_) groups[uf.Find(dense[id])].push_back(id);
  std::vector<std::vector<int>> out;
  for (auto& [root, members] : groups) {
    std::sort(members.begin(), members.end());
    out.push_back(std::move(members));
  }
  std::sort(out.begin(), out.end(), [](const std::vector<int>& a, const std::vector<int>& b) {
    return a.size() != b.size() ? a.size() > b.size() : a.front() < b.front();
  });
  return out;
}

EdgePoints::EdgePoints(const EdgePoints& other) {
  *this = other;
}

EdgePoints& EdgePoints::operator=(const EdgePoints& other) {
  if (this == &other) return *this;
  const size_t pairs = other.pairs_;
  (void)Reset(pairs, other.holdout_size());
  std::copy_n(other.block_.get(), other.points_, block_.get());
  return *this;
}

EdgePoints EdgePoints::Combine(const EdgePoints& pairs, const EdgePoints& holdout) {
  EdgePoints out;
  const size_t n = pairs.pairs_;
  (void)out.Reset(n, holdout.holdout_size());
  std::copy_n(pairs.block_.get(), 2 * n, out.block_.get());
  std::copy_n(holdout.block_.get() + 2 * size_t{holdout.pairs_}, 2 * holdout.holdout_size(), out.block_.get() + 2 * n);
  return out;
}

float* EdgePoints::Reset(size_t pairs, size_t holdout) {
  const size_t points = 2 * (pairs + holdout);
  block_ = points > 0 ? std::make_unique_for_overwrite<Vec2f[]>(points) : nullptr;
  points_ = static_cast<uint32_t>(points);
  pairs_ = static_cast<uint32_t>(pairs);
  return reinterpret_cast<float*>(block_.get());
}

size_t EdgePoints::Thin(size_t max_pairs, size_t max_holdout) {
  const size_t n = size();
  const size_t m = holdout_size();
  const size_t keep_n = std::min(n, max_pairs);
  const size_t keep_m = std::min(m, max_holdout);
  if (keep_n == n && keep_m == m) return 0;
  EdgePoints kept;
  (void)kept.Reset(keep_n, keep_m);
  // `keep` of the `count` pairs from pair `first` on, evenly spread over the whole list, to pair `to` on.
  const auto keep_strided = [&](size_t first, size_t count, size_t keep, size_t to) {
    for (size_t k = 0; k < keep; ++k) {
      const size_t i = first + k * count / keep;
      kept.block_[2 * (to + k)] = block_[2 * i];
      kept.block_[2 * (to + k) + 1] = block_[2 * i + 1];
    }
  };
  keep_strided(0, n, keep_n, 0);
  keep_strided(n, m, keep_m, keep_n);
  *this = std::move(kept);
  return (n - keep_n) + (m - keep_m);
}

void EdgePoints::Free() {
  block_.reset();
  points_ = 0;
  pairs_ = 0;
}

}  // namespace uavm
