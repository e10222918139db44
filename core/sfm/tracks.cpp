#include "core/sfm/tracks.h"

#include <algorithm>
#include <map>
#include <numeric>
#include <unordered_map>

namespace uavm::sfm {

std::vector<Track> BuildTracks(std::vector<FeatureMatch> matches, int min_length, TrackStats* stats) {
  TrackStats st;
  st.matches_in = static_cast<int>(matches.size());
  std::stable_sort(matches.begin(), matches.end(),
                   [](const FeatureMatch& a, const FeatureMatch& b) { return a.cost < b.cost; });
  // Node ids for (image, feature).
  std::map<std::pair<int, int>, int> id_of;
  std::vector<Observation> nodes;
  auto node = [&](int image, int feature) {
    const auto [it, inserted] = id_of.emplace(std::make_pair(image, feature), static_cast<int>(nodes.size()));
    if (inserted) nodes.push_back({image, feature});
    return it->second;
  };
  std::vector<std::pair<int, int>> edges;
  edges.reserve(matches.size());
  for (const auto& m : matches) {
    if (m.image1 == m.image2) continue;
    edges.emplace_back(node(m.image1, m.feature1), node(m.image2, m.feature2));
  }
  std::vector<int> parent(nodes.size());
  std::iota(parent.begin(), parent.end(), 0);
  // Images present in each root's set, sorted (tracks are short: a vector is cheaper than a set).
  std::vector<std::vector<int>> images(nodes.size());
  for (size_t i = 0; i < nodes.size(); ++i) images[i] = {nodes[i].image};
  auto find = [&](int x) {
    while (parent[static_cast<size_t>(x)] != x) {
      parent[static_cast<size_t>(x)] = parent[static_cast<size_t>(parent[static_cast<size_t>(x)])];
      x = parent[static_cast<size_t>(x)];
    }
    return x;
  };
  for (const auto& [a0, b0] : edges) {
    int a = find(a0), b = find(b0);
    if (a == b) continue;
    auto& ia = images[static_cast<size_t>(a)];
    auto& ib = images[static_cast<size_t>(b)];
    std::vector<int> common;
    std::set_intersection(ia.begin(), ia.end(), ib.begin(), ib.end(), std::back_inserter(common));
    if (!common.empty()) {
      ++st.conflicts_refused;
      continue;
    }
    if (ia.size() < ib.size()) std::swap(a, b);
    std::vector<int> merged;
    std::merge(images[static_cast<size_t>(a)].begin(), images[static_cast<size_t>(a)].end(),
               images[static_cast<size_t>(b)].begin(), images[static_cast<size_t>(b)].end(),
               std::back_inserter(merged));
    images[static_cast<size_t>(a)] = std::move(merged);
    images[static_cast<size_t>(b)].clear();
    parent[static_cast<size_t>(b)] = a;
    ++st.unions;
  }
  std::unordered_map<int, size_t> track_of_root;
  std::vector<Track> tracks;
  for (size_t i = 0; i < nodes.size(); ++i) {
    const int r = find(static_cast<int>(i));
    auto [it, inserted] = track_of_root.emplace(r, tracks.size());
    if (inserted) tracks.emplace_back();
    tracks[it->second].push_back(nodes[i]);
  }
  std::vector<Track> out;
  for (auto& t : tracks) {
    if (static_cast<int>(t.size()) < min_length) continue;
    std::sort(t.begin(), t.end(), [](const Observation& a, const Observation& b) { return a.image < b.image; });
    out.push_back(std::move(t));
  }
  if (stats) *stats = st;
  return out;
}

}  // namespace uavm::sfm
