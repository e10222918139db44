#include "core/geometry/footprint_grid.h"

#include <algorithm>
#include <cmath>

namespace uavm {

bool FootprintGrid::RangeOf(const cv::Rect2d& box, CellRange* range) const {
  const double x0 = std::floor(box.x / cell_);
  const double y0 = std::floor(box.y / cell_);
  const double x1 = std::floor((box.x + box.width) / cell_);
  const double y1 = std::floor((box.y + box.height) / cell_);
  if (!std::isfinite(x0) || !std::isfinite(y0) || !std::isfinite(x1) || !std::isfinite(y1)) return false;
  if (x1 - x0 >= kMaxCellsPerSide || y1 - y0 >= kMaxCellsPerSide) return false;
  // Far from the origin the cell index would not fit an int: such a box is as wild as an oversize one.
  constexpr double kLimit = 1e9;
  if (std::abs(x0) > kLimit || std::abs(y0) > kLimit || std::abs(x1) > kLimit || std::abs(y1) > kLimit) return false;
  *range = {static_cast<int>(x0), static_cast<int>(y0), static_cast<int>(x1), static_cast<int>(y1), false};
  return true;
}

void FootprintGrid::Set(int id, const cv::Rect2d& box) {
  Remove(id);
  // The first box with a size sets the cells; until then a frame waits on the oversize list.
  const double side = std::max(box.width, box.height);
  if (cell_ <= 0.0 && side > 0.0 && std::isfinite(side)) cell_ = side;
  if (placed_.size() <= static_cast<size_t>(id)) placed_.resize(static_cast<size_t>(id) + 1);
  CellRange& range = placed_[static_cast<size_t>(id)];
  ++placed_count_;
  if (cell_ <= 0.0 || !RangeOf(box, &range)) {
    range = CellRange{};
    range.oversize = true;
    oversize_.push_back(id);
    return;
  }
  for (int cy = range.y0; cy <= range.y1; ++cy)
    for (int cx = range.x0; cx <= range.x1; ++cx) cells_[Key(cx, cy)].push_back(id);
}

void FootprintGrid::Remove(int id) {
  if (id < 0 || static_cast<size_t>(id) >= placed_.size() || !placed_[static_cast<size_t>(id)].placed()) return;
  CellRange& range = placed_[static_cast<size_t>(id)];
  const auto drop = [id](std::vector<int>& ids) {
    const auto it = std::find(ids.begin(), ids.end(), id);
    if (it != ids.end()) {
      *it = ids.back();
      ids.pop_back();
    }
  };
  if (range.oversize) {
    drop(oversize_);
  } else {
    for (int cy = range.y0; cy <= range.y1; ++cy)
      for (int cx = range.x0; cx <= range.x1; ++cx) {
        const auto cell = cells_.find(Key(cx, cy));
        if (cell == cells_.end()) continue;
        drop(cell->second);
        if (cell->second.empty()) cells_.erase(cell);
      }
  }
  range = CellRange{};
  --placed_count_;
}

std::vector<int> FootprintGrid::Query(const cv::Rect2d& box) const {
  std::vector<int> out = oversize_;
  CellRange range;
  if (cell_ > 0.0 && RangeOf(box, &range)) {
    for (int cy = range.y0; cy <= range.y1; ++cy)
      for (int cx = range.x0; cx <= range.x1; ++cx) {
        const auto cell = cells_.find(Key(cx, cy));
        if (cell != cells_.end()) out.insert(out.end(), cell->second.begin(), cell->second.end());
      }
  } else if (cell_ > 0.0) {
    // A query too large for the grid: every placed frame (what a scan would have looked at).
    for (size_t id = 0; id < placed_.size(); ++id)
      if (placed_[id].placed() && !placed_[id].oversize) out.push_back(static_cast<int>(id));
  }
  std::sort(out.begin(), out.end());
  out.erase(std::unique(out.begin(), out.end()), out.end());
  return out;
}

}  // namespace uavm
