#pragma once
// Cells of a grid in the order of a Hilbert curve: consecutive cells are neighbours and every aligned 2^k x 2^k block
// is visited in one run, so work done cell by cell reuses what its neighbours read (the compositor's frames, the web
// tiles' blocks of the mosaic).

#include <algorithm>
#include <utility>
#include <vector>

namespace uavm {

// The position along a Hilbert curve over a side x side grid (side a power of two) of cell (x, y): the curve starts at
// (0, 0) and ends at (side - 1, 0). Cells are ordered by it rather than by walking the square, which for a long, narrow
// range of cells (a corridor's web tiles) would cost the square of its length.
inline long HilbertIndex(int side, int x, int y) {
  long d = 0;
  for (int s = side / 2; s > 0; s /= 2) {
    const int rx = (x & s) != 0 ? 1 : 0;
    const int ry = (y & s) != 0 ? 1 : 0;
    d += static_cast<long>(s) * s * ((3 * rx) ^ ry);
    if (ry == 0) {  // rotate the quadrant so that the sub-curves join end to start
      if (rx == 1) {
        x = side - 1 - x;
        y = side - 1 - y;
      }
      std::swap(x, y);
    }
  }
  return d;
}

// The cells (x, y) of a cols x rows grid in the curve's order (over the smallest power-of-two square that holds it).
inline std::vector<std::pair<int, int>> CellsAlongHilbertCurve(int cols, int rows) {
  int side = 1;
  while (side < std::max(cols, rows)) side *= 2;
  std::vector<std::pair<long, std::pair<int, int>>> order;
  order.reserve(static_cast<size_t>(std::max(0, cols)) * static_cast<size_t>(std::max(0, rows)));
  for (int y = 0; y < rows; ++y)
    for (int x = 0; x < cols; ++x) order.push_back({HilbertIndex(side, x, y), {x, y}});
  std::sort(order.begin(), order.end(), [](const auto& a, const auto& b) { return a.first < b.first; });
  std::vector<std::pair<int, int>> cells;
  cells.reserve(order.size());
  for (const auto& entry : order) cells.push_back(entry.second);
  return cells;
}

}  // namespace uavm
