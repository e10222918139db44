#pragma once
#include <vector>

#include "core/graph/match_graph.h"

namespace uavm {

// Connected components of the frames of a flight, kept as they grow: union-find gives a frame's component, and each
// component keeps its members in ascending id order, so that a component's members (or its newest N) cost their own
// number, never a scan of the whole flight.
class Components {
 public:
  // A new frame, a component of its own. Ids are dense (0, 1, 2, ...) in the order of the calls; returns the id.
  int Add();
  [[nodiscard]] int Find(int id) { return sets_.Find(id); }
  [[nodiscard]] int SizeOf(int id) { return sets_.SizeOf(id); }
  // Unites the components of `a` and `b` and returns the new root. Costs the smaller component's size when all its
  // frames are newer than the larger's (a frame joining during the flight: O(1)), the two sizes otherwise.
  int Unite(int a, int b);
  // The members of `id`'s component, ascending. Valid until the next Unite.
  [[nodiscard]] const std::vector<int>& MembersOf(int id);
  [[nodiscard]] size_t size() const { return sets_.size(); }

 private:
  UnionFind sets_;
  std::vector<std::vector<int>> members_;  // by root; empty for frames that are not a root
};

}  // namespace uavm
