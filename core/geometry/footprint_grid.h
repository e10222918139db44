#pragma once
#include <cstdint>
#include <opencv2/core.hpp>
#include <unordered_map>
#include <vector>

namespace uavm {

// Where frames lie on the mosaic plane: each frame's bounding box, bucketed in a uniform grid, so that the frames
// near a box cost the cells it covers instead of a scan of the whole flight. The first box sets the cell size (its
// longer side: a frame then covers ~4 cells). A box that would cover more than kMaxCellsPerSide cells per side (a
// wild transform) is kept on a list every query returns, so a bad frame cannot blow up memory or time.
class FootprintGrid {
 public:
  static constexpr int kMaxCellsPerSide = 64;

  // Places frame `id` (ids are small non-negative integers) at `box`, moving it if it was placed before.
  void Set(int id, const cv::Rect2d& box);
  void Remove(int id);
  // The frames whose boxes may meet `box`: every frame whose box does, and some whose box only shares a cell with
  // it (callers test the real overlap). Ascending, each once.
  [[nodiscard]] std::vector<int> Query(const cv::Rect2d& box) const;
  [[nodiscard]] size_t size() const { return placed_count_; }

 private:
  struct CellRange {
    int x0 = 0, y0 = 0, x1 = -1, y1 = -1;  // inclusive; x1 < x0: not placed
    bool oversize = false;
    [[nodiscard]] bool placed() const { return oversize || x1 >= x0; }
  };
  // false for a box that does not fit in kMaxCellsPerSide cells per side (or is not finite).
  [[nodiscard]] bool RangeOf(const cv::Rect2d& box, CellRange* range) const;
  [[nodiscard]] static int64_t Key(int cx, int cy) {
    return (static_cast<int64_t>(cx) << 32) ^ static_cast<int64_t>(static_cast<uint32_t>(cy));
  }

  double cell_ = 0.0;
  std::unordered_map<int64_t, std::vector<int>> cells_;
  std::vector<int> oversize_;
  std::vector<CellRange> placed_;  // by id
  size_t placed_count_ = 0;
};

}  // namespace uavm
