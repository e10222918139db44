#pragma once
// Cells of a grid in the order of a Hilbert curve: consecutive cells are neighbours and every aligned 2^k x 2^k block
// is visited in one run, so work done cell by cell reuses what its neighbours read (the compositor's frames, the web
// tiles' blocks of the mosaic).

#include <utility>

namespace uavm {

// (x, y) of cell `d` along a Hilbert curve over a side x side grid (side a power of two).
inline std::pair<int, int> HilbertCell(int side, long d) {
  int x = 0, y = 0;
  for (int s = 1; s < side; s *= 2) {
    const int rx = static_cast<int>(1 & (d / 2));
    const int ry = static_cast<int>(1 & (d ^ rx));
    if (ry == 0) {  // rotate the quadrant so that the sub-curves join end to start
      if (rx == 1) {
        x = s - 1 - x;
        y = s - 1 - y;
      }
      std::swap(x, y);
    }
    x += s * rx;
    y += s * ry;
    d /= 4;
  }
  return {x, y};
}

}  // namespace uavm
