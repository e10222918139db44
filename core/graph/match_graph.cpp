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

namespace {

size_t ThinPair(std::vector<Vec2f>* a, std::vector<Vec2f>* b, size_t keep) {
  const size_t n = a->size();
  if (n <= keep) return 0;
  std::vector<Vec2f> ta, tb;
  ta.reserve(keep);
  tb.reserve(keep);
  for (size_t k = 0; k < keep; ++k) {
    const size_t i = k * n / keep;  // evenly spread over the whole list
    ta.push_back((*a)[i]);
    tb.push_back((*b)[i]);
  }
  a->swap(ta);
  b->swap(tb);
  return n - keep;
}

}  // namespace

size_t ThinPoints(Edge* edge, size_t max_points, size_t max_holdout) {
  return ThinPair(&edge->src_points, &edge->tgt_points, max_points) +
         ThinPair(&edge->holdout_src_points, &edge->holdout_tgt_points, max_holdout);
}

std::vector<Vec2f> ToEdgePoints(std::vector<Vec2> points) {
  std::vector<Vec2f> out;
  out.reserve(points.size());
  for (const Vec2& p : points) out.push_back(p.cast<float>());
  return out;
}

}  // namespace uavm
