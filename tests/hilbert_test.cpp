#include "core/util/hilbert.h"

#include <gtest/gtest.h>

#include <cstdlib>
#include <set>

namespace uavm {
namespace {

// Over whole squares the order is a Hilbert curve: every cell once, each step to a side neighbour, from (0, 0) to
// (side - 1, 0), and every aligned 2^k x 2^k block visited in one run.
TEST(HilbertTest, SquaresAreWalkedCellByCellThroughWholeBlocks) {
  for (int side = 1; side <= 64; side *= 2) {
    const auto cells = CellsAlongHilbertCurve(side, side);
    ASSERT_EQ(cells.size(), static_cast<size_t>(side * side));
    EXPECT_EQ(cells.front(), std::make_pair(0, 0));
    EXPECT_EQ(cells.back(), std::make_pair(side - 1, 0));
    std::set<std::pair<int, int>> seen(cells.begin(), cells.end());
    EXPECT_EQ(seen.size(), cells.size());
    for (size_t k = 1; k < cells.size(); ++k)
      EXPECT_EQ(std::abs(cells[k].first - cells[k - 1].first) + std::abs(cells[k].second - cells[k - 1].second), 1)
          << side << " step " << k;
    for (int block = 2; block < side; block *= 2)
      for (size_t k = 0; k < cells.size(); k += static_cast<size_t>(block * block)) {
        const int bx = cells[k].first / block;
        const int by = cells[k].second / block;
        for (size_t j = k; j < k + static_cast<size_t>(block * block); ++j)
          ASSERT_EQ(std::make_pair(cells[j].first / block, cells[j].second / block), std::make_pair(bx, by))
              << side << " block " << block;
      }
  }
}

// A long, narrow grid (a corridor's web tiles): every cell once, in the square curve's order, without walking the
// square (2 x 20000 cells here: a walk would visit 2^30).
TEST(HilbertTest, NarrowGridsKeepTheCurvesOrder) {
  const auto cells = CellsAlongHilbertCurve(2, 20000);
  ASSERT_EQ(cells.size(), 40000u);
  std::set<std::pair<int, int>> seen(cells.begin(), cells.end());
  EXPECT_EQ(seen.size(), cells.size());
  for (size_t k = 1; k < cells.size(); ++k)
    EXPECT_LT(HilbertIndex(32768, cells[k - 1].first, cells[k - 1].second),
              HilbertIndex(32768, cells[k].first, cells[k].second));
}

}  // namespace
}  // namespace uavm
