#include "core/geometry/footprint_grid.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <vector>

#include "core/util/portable_random.h"

namespace uavm {
namespace {

// The reference: every placed box tested against the query (the scan the grid replaces).
std::vector<int> ScanQuery(const std::map<int, cv::Rect2d>& boxes, const cv::Rect2d& q) {
  std::vector<int> out;
  for (const auto& [id, b] : boxes)
    if ((b & q).area() > 0) out.push_back(id);
  return out;
}

bool Contains(const std::vector<int>& sorted, int id) {
  return std::binary_search(sorted.begin(), sorted.end(), id);
}

TEST(FootprintGridTest, FindsOverlappingFramesAndForgetsMovedOnes) {
  FootprintGrid grid;
  grid.Set(0, {0, 0, 100, 80});
  grid.Set(1, {90, 0, 100, 80});    // overlaps 0
  grid.Set(2, {1000, 0, 100, 80});  // far away
  const auto near0 = grid.Query({10, 10, 50, 50});
  EXPECT_TRUE(Contains(near0, 0));
  EXPECT_FALSE(Contains(near0, 2));
  EXPECT_TRUE(Contains(grid.Query({150, 10, 20, 20}), 1));
  grid.Set(1, {1000, 100, 100, 80});  // moved next to 2
  EXPECT_FALSE(Contains(grid.Query({150, 10, 20, 20}), 1));
  EXPECT_TRUE(Contains(grid.Query({1050, 90, 20, 20}), 1));
  grid.Remove(2);
  EXPECT_FALSE(Contains(grid.Query({1000, 0, 100, 80}), 2));
  EXPECT_EQ(grid.size(), 2u);
}

TEST(FootprintGridTest, WildBoxesAreAlwaysCandidatesAndCostNoCells) {
  FootprintGrid grid;
  grid.Set(0, {0, 0, 100, 100});
  grid.Set(1, {-1e7, -1e7, 2e7, 2e7});  // a diverged transform: far more than 64 cells per side
  const double inf = std::numeric_limits<double>::infinity();
  grid.Set(2, {0, 0, inf, 10});
  const auto q = grid.Query({5000, 5000, 10, 10});
  EXPECT_TRUE(Contains(q, 1));
  EXPECT_TRUE(Contains(q, 2));
  EXPECT_FALSE(Contains(q, 0));
  grid.Set(1, {0, 0, 100, 100});  // back to a sane place
  EXPECT_FALSE(Contains(grid.Query({5000, 5000, 10, 10}), 1));
  // A query larger than the grid handles returns every frame (what a scan would look at).
  const auto all = grid.Query({-1e9, -1e9, 2e9, 2e9});
  EXPECT_EQ(all, (std::vector<int>{0, 1, 2}));
}

// A lawnmower flight's footprints, moved around by later solves: every frame a scan finds is found by the grid.
TEST(FootprintGridTest, NeverMissesWhatAScanFinds) {
  PortableRandom rng(7);
  FootprintGrid grid;
  std::map<int, cv::Rect2d> boxes;
  const auto frame_box = [&](int id) {
    const int strip = id / 40;
    const double x = (id % 40) * 60.0 * (strip % 2 == 0 ? 1 : -1) + rng.Symmetric() * 20;
    const double y = strip * 70.0 + rng.Symmetric() * 20;
    return cv::Rect2d(x, y, 100 + rng.Uniform(0, 30), 75 + rng.Uniform(0, 30));
  };
  for (int id = 0; id < 400; ++id) {
    boxes[id] = frame_box(id);
    grid.Set(id, boxes[id]);
    // A windowed solve moves the newest frames a little; sometimes a merge moves a whole old stretch.
    for (int k = std::max(0, id - 10); k < id; ++k) {
      boxes[k].x += rng.Symmetric() * 3;
      grid.Set(k, boxes[k]);
    }
    if (id % 97 == 96) {
      for (int k = 0; k < 30; ++k) {
        boxes[k].y += 500;
        grid.Set(k, boxes[k]);
      }
    }
    const cv::Rect2d q = frame_box(id + 1);
    const auto found = grid.Query(q);
    for (int expected : ScanQuery(boxes, q)) ASSERT_TRUE(Contains(found, expected)) << "frame " << id;
    // And the grid looks at a neighbourhood, not the flight.
    ASSERT_LT(found.size(), 60u);
  }
}

}  // namespace
}  // namespace uavm
