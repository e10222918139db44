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
  edges_.push_back(std::move(edge));
}

int MatchGraph::MaxInliers() const {
  int best = 0;
  for (const auto& e : edges_) best = std::max(best, e.num_inliers);
  return best;
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

EdgePoints EdgePoints::Combine(const EdgePoints& pairs, const EdgePoints& holdout) {
  EdgePoints out;
  const auto first = pairs.block_.begin();
  const auto held = holdout.block_.begin() + 2 * static_cast<std::ptrdiff_t>(holdout.pairs_);
  out.block_.reserve(2 * pairs.pairs_ + (holdout.block_.end() - held));
  out.block_.insert(out.block_.end(), first, first + 2 * static_cast<std::ptrdiff_t>(pairs.pairs_));
  out.block_.insert(out.block_.end(), held, holdout.block_.end());
  out.pairs_ = pairs.pairs_;
  return out;
}

float* EdgePoints::Reset(size_t pairs, size_t holdout) {
  std::vector<Vec2f> block(2 * (pairs + holdout));
  block_.swap(block);
  pairs_ = static_cast<uint32_t>(pairs);
  return reinterpret_cast<float*>(block_.data());
}

size_t EdgePoints::Thin(size_t max_pairs, size_t max_holdout) {
  const size_t n = size();
  const size_t m = holdout_size();
  const size_t keep_n = std::min(n, max_pairs);
  const size_t keep_m = std::min(m, max_holdout);
  if (keep_n == n && keep_m == m) return 0;
  std::vector<Vec2f> kept;
  kept.reserve(2 * (keep_n + keep_m));
  // `keep` of the `count` pairs from pair `first` on, evenly spread over the whole list.
  const auto keep_strided = [&](size_t first, size_t count, size_t keep) {
    for (size_t k = 0; k < keep; ++k) {
      const size_t i = first + k * count / keep;
      kept.push_back(block_[2 * i]);
      kept.push_back(block_[2 * i + 1]);
    }
  };
  keep_strided(0, n, keep_n);
  keep_strided(n, m, keep_m);
  block_.swap(kept);
  pairs_ = static_cast<uint32_t>(keep_n);
  return (n - keep_n) + (m - keep_m);
}

void EdgePoints::Free() {
  std::vector<Vec2f>().swap(block_);
  pairs_ = 0;
}

}  // namespace uavm
