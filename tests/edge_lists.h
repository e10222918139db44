#pragma once
#include <vector>

#include "core/graph/match_graph.h"

namespace uavm::test {

// An edge's points as four lists, for tests that build or change them point by point; EdgePoints holds them in one
// block.
struct EdgeLists {
  std::vector<Vec2f> src, tgt, holdout_src, holdout_tgt;

  [[nodiscard]] EdgePoints Build() const { return EdgePoints(src, tgt, holdout_src, holdout_tgt); }
};

inline EdgeLists ListsOf(const EdgePoints& points) {
  EdgeLists lists;
  for (size_t k = 0; k < points.size(); ++k) {
    lists.src.push_back(points.src(k));
    lists.tgt.push_back(points.tgt(k));
  }
  for (size_t k = 0; k < points.holdout_size(); ++k) {
    lists.holdout_src.push_back(points.holdout_src(k));
    lists.holdout_tgt.push_back(points.holdout_tgt(k));
  }
  return lists;
}

}  // namespace uavm::test
