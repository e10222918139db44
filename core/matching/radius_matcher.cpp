#include "core/matching/radius_matcher.h"

#include <algorithm>
#include <cmath>

namespace uavm {

namespace {

// Point indices of a frame in square cells of `cell` pixels: the candidates of a prediction are in its 3 x 3 cells.
struct PointGrid {
  PointGrid(const std::vector<Vec2>& points, double cell_px, cv::Size size)
      : cell(cell_px),
        gw(static_cast<int>(size.width / cell_px) + 1),
        gh(static_cast<int>(size.height / cell_px) + 1),
        cells(static_cast<size_t>(gw * gh)) {
    for (size_t j = 0; j < points.size(); ++j) {
      const int gx = std::clamp(static_cast<int>(points[j].x() / cell), 0, gw - 1);
      const int gy = std::clamp(static_cast<int>(points[j].y() / cell), 0, gh - 1);
      cells[static_cast<size_t>(gy * gw + gx)].push_back(static_cast<int>(j));
    }
  }
  double cell;
  int gw, gh;
  std::vector<std::vector<int>> cells;
};

// Best and second-best candidate per point of A; best per point of B (for the mutual check).
struct Neighbours {
  std::vector<int> best_a;
  std::vector<float> d1_a, d2_a;
  std::vector<int> best_b;
  std::vector<float> d1_b;
};

Neighbours SearchWithinRadius(const std::vector<Vec2>& points_a, const cv::Mat& descriptors_a,
                              const std::vector<Vec2>& points_b, const cv::Mat& descriptors_b, const Mat3& b_from_a,
                              const PointGrid& grid, double radius) {
  Neighbours n{std::vector<int>(points_a.size(), -1), std::vector<float>(points_a.size(), 1e30f),
               std::vector<float>(points_a.size(), 1e30f), std::vector<int>(points_b.size(), -1),
               std::vector<float>(points_b.size(), 1e30f)};
  const double cell = grid.cell;
  for (size_t i = 0; i < points_a.size(); ++i) {
    const Vec2 q = Apply(b_from_a, points_a[i]);
    const int gx = static_cast<int>(std::floor(q.x() / cell)), gy = static_cast<int>(std::floor(q.y() / cell));
    const cv::Mat da = descriptors_a.row(static_cast<int>(i));
    for (int y = gy - 1; y <= gy + 1; ++y) {
      for (int x = gx - 1; x <= gx + 1; ++x) {
        if (x < 0 || y < 0 || x >= grid.gw || y >= grid.gh) continue;
        for (int j : grid.cells[static_cast<size_t>(y * grid.gw + x)]) {
          if ((points_b[static_cast<size_t>(j)] - q).norm() > radius) continue;
          const float d = static_cast<float>(cv::norm(da, descriptors_b.row(j), cv::NORM_L2SQR));
          if (d < n.d1_a[i]) {
            n.d2_a[i] = n.d1_a[i];
            n.d1_a[i] = d;
            n.best_a[i] = j;
          } else if (d < n.d2_a[i]) {
            n.d2_a[i] = d;
          }
          if (d < n.d1_b[static_cast<size_t>(j)]) {
            n.d1_b[static_cast<size_t>(j)] = d;
            n.best_b[static_cast<size_t>(j)] = static_cast<int>(i);
          }
        }
      }
    }
  }
  return n;
}

}  // namespace

std::vector<RadiusMatch> MatchWithinRadius(const std::vector<Vec2>& points_a, const cv::Mat& descriptors_a,
                                           const std::vector<Vec2>& points_b, const cv::Mat& descriptors_b,
                                           cv::Size size_b, const Mat3& b_from_a, const RadiusMatchOptions& options) {
  // The cell is the radius: a prediction's candidates all lie in its cell and the 8 around it.
  const PointGrid grid(points_b, options.radius_px, size_b);
  const Neighbours n =
      SearchWithinRadius(points_a, descriptors_a, points_b, descriptors_b, b_from_a, grid, options.radius_px);
  std::vector<RadiusMatch> out;
  const float r2 = static_cast<float>(options.ratio * options.ratio);  // squared distances
  for (size_t i = 0; i < points_a.size(); ++i) {
    const int j = n.best_a[i];
    if (j < 0 || n.d1_a[i] > r2 * n.d2_a[i]) continue;
    if (n.best_b[static_cast<size_t>(j)] != static_cast<int>(i)) continue;  // mutual best
    out.push_back({static_cast<int>(i), j, n.d1_a[i]});
  }
  return out;
}

}  // namespace uavm
