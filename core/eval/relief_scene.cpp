#include "core/eval/relief_scene.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>

#include "core/util/portable_random.h"

namespace uavm::eval {

namespace {

// Texture: value noise (random heights on a lattice, smoothly interpolated) summed over seven octaves, the finest one
// unit long. Not periodic: a patch matches only where it came from (plane waves made phase correlation lock onto their
// period).
double LatticeValue(int64_t i, int64_t j, uint32_t seed) {
  uint64_t h = static_cast<uint64_t>(i) * 0x9E3779B97F4A7C15ull ^ static_cast<uint64_t>(j) * 0xC2B2AE3D27D4EB4Full ^
               (static_cast<uint64_t>(seed) + 1) * 0x165667B19E3779F9ull;
  h ^= h >> 31;
  h *= 0xD6E8FEB86659FD93ull;
  h ^= h >> 32;
  return static_cast<double>(h >> 11) * 0x1.0p-53 * 2.0 - 1.0;  // [-1, 1)
}

double ValueNoise(double x, double y, uint32_t seed) {
  const double fx = std::floor(x), fy = std::floor(y);
  const auto i = static_cast<int64_t>(fx), j = static_cast<int64_t>(fy);
  const double u = x - fx, v = y - fy;
  const double su = u * u * (3.0 - 2.0 * u), sv = v * v * (3.0 - 2.0 * v);  // smoothstep: no creases at the lattice
  const double a = LatticeValue(i, j, seed), b = LatticeValue(i + 1, j, seed);
  const double c = LatticeValue(i, j + 1, seed), d = LatticeValue(i + 1, j + 1, seed);
  return (a + (b - a) * su) * (1.0 - sv) + (c + (d - c) * su) * sv;
}

double Pattern(double x, double y, double seed) {
  double v = 0.0, amplitude = 1.0, total = 0.0;
  double scale = 1.0;
  for (int octave = 0; octave < 7; ++octave) {
    // Each octave rotated a little so that no lattice direction dominates.
    const double angle = 0.7 * octave + seed;
    const double ca = std::cos(angle), sa = std::sin(angle);
    v += amplitude * ValueNoise((ca * x - sa * y) * scale, (sa * x + ca * y) * scale,
                                static_cast<uint32_t>(octave + 17 * static_cast<int>(seed)));
    total += amplitude;
    scale *= 0.5;
    amplitude *= 0.85;  // fine detail as strong as coarse: what matching and phase correlation lock onto
  }
  return std::clamp(1.6 * v / total, -1.0, 1.0);
}

cv::Vec3b Tint(double pattern, const cv::Vec3d& base, double amplitude) {
  cv::Vec3b out;
  for (int c = 0; c < 3; ++c) out[c] = cv::saturate_cast<uchar>(base[c] * (1.0 + amplitude * pattern));
  return out;
}

double Dome(const ReliefScene::Tree& tree, double x, double y) {  // crown height above the ground, < 0 outside
  const double r2 = ((x - tree.x) * (x - tree.x) + (y - tree.y) * (y - tree.y)) / (tree.radius * tree.radius);
  const double base = ReliefScene::kCrownBase * tree.height;
  return r2 <= 1.0 ? base + (tree.height - base) * (1.0 - r2) : -1.0;
}

bool InBuilding(const ReliefScene::Building& b, double x, double y) {
  return x >= b.x0 && x <= b.x1 && y >= b.y0 && y <= b.y1;
}

double RoofOf(const ReliefScene& s, const ReliefScene::Building& b) {
  return s.Ground(0.5 * (b.x0 + b.x1), 0.5 * (b.y0 + b.y1)) + b.height;
}

}  // namespace

double ReliefScene::Surface(double x, double y) const {
  double z = Ground(x, y);
  for (const auto& b : buildings)
    if (InBuilding(b, x, y)) z = std::max(z, RoofOf(*this, b));
  for (const auto& t : trees) {
    const double d = Dome(t, x, y);
    if (d >= 0.0) z = std::max(z, Ground(x, y) + d);
  }
  return z;
}

double ReliefScene::MaxSurface() const {
  double z = std::max({Ground(-half_extent, -half_extent), Ground(half_extent, -half_extent),
                       Ground(-half_extent, half_extent), Ground(half_extent, half_extent)});
  for (const auto& b : buildings) z = std::max(z, RoofOf(*this, b));
  for (const auto& t : trees) z = std::max(z, Ground(t.x, t.y) + t.height + std::abs(slope_x) * t.radius);
  return z;
}

int ReliefScene::CoverAt(double x, double y) const {
  int cover = 0;
  double z = Ground(x, y);
  for (const auto& b : buildings)
    if (InBuilding(b, x, y) && RoofOf(*this, b) > z) {
      z = RoofOf(*this, b);
      cover = 1;
    }
  for (const auto& t : trees) {
    const double d = Dome(t, x, y);
    if (d >= 0.0 && Ground(x, y) + d > z) {
      z = Ground(x, y) + d;
      cover = 2;
    }
  }
  return cover;
}

cv::Vec3b ReliefScene::TopColour(double x_m, double y_m) const {
  const double x = x_m / texture_scale, y = y_m / texture_scale;
  switch (CoverAt(x_m, y_m)) {
    case 1:
      return Tint(Pattern(0.8 * x, 0.8 * y, 2.0), {150, 140, 135}, 0.45);  // roofs: grey
    case 2:
      return Tint(Pattern(0.7 * x, 0.7 * y, 5.0), {40, 120, 60}, 0.6);  // crowns: green
    default:
      return Tint(Pattern(x, y, 0.0), {90, 130, 140}, 0.5);  // ground: earth and grass
  }
}

cv::Vec3b ReliefScene::WallColour(double z) {
  return std::fmod(std::abs(z), 1.0) < 0.5 ? cv::Vec3b(20, 20, 230) : cv::Vec3b(60, 40, 180);
}

ReliefScene MakeReliefScene(uint32_t seed, double half_extent, int buildings, int trees) {
  ReliefScene s;
  s.half_extent = half_extent;
  PortableRandom rng(seed);
  s.slope_x = rng.Uniform(-0.06, 0.06);
  s.slope_y = rng.Uniform(-0.06, 0.06);
  const auto free_at = [&](double x0, double y0, double x1, double y1) {
    for (const auto& b : s.buildings)
      if (x0 < b.x1 + 4 && x1 > b.x0 - 4 && y0 < b.y1 + 4 && y1 > b.y0 - 4) return false;
    for (const auto& t : s.trees)
      if (x0 < t.x + t.radius + 2 && x1 > t.x - t.radius - 2 && y0 < t.y + t.radius + 2 && y1 > t.y - t.radius - 2)
        return false;
    return true;
  };
  const double inner = 0.8 * half_extent;
  for (int tries = 0; static_cast<int>(s.buildings.size()) < buildings && tries < 1000; ++tries) {
    const double w = rng.Uniform(6, 16), h = rng.Uniform(6, 16);
    const double x = rng.Uniform(-inner, inner - w), y = rng.Uniform(-inner, inner - h);
    if (!free_at(x, y, x + w, y + h)) continue;
    s.buildings.push_back({x, y, x + w, y + h, rng.Uniform(8, 25)});
  }
  for (int tries = 0; static_cast<int>(s.trees.size()) < trees && tries < 1000; ++tries) {
    const double r = rng.Uniform(2.5, 5.0);
    const double x = rng.Uniform(-inner, inner), y = rng.Uniform(-inner, inner);
    if (!free_at(x - r, y - r, x + r, y + r)) continue;
    s.trees.push_back({x, y, r, rng.Uniform(6, 14)});
  }
  return s;
}

namespace {

// The nearest surface along the ray c + t d (d unit): t, or infinity; *side_out 0 seen from above, 1 a building's
// wall, 2 a crown's side.
double FirstHit(const ReliefScene& scene, const Eigen::Vector3d& c, const Eigen::Vector3d& d, int* side_out) {
  constexpr double kInf = std::numeric_limits<double>::infinity();
  // Nearest hit among the ground plane, the buildings' boxes (roof or wall) and the crowns.
  double best = kInf;
  int side = 0;  // 0 seen from above, 1 a building's wall, 2 a crown's side
  const double denom = d.z() - scene.slope_x * d.x() - scene.slope_y * d.y();
  if (std::abs(denom) > 1e-12) {
    const double t = (scene.slope_x * c.x() + scene.slope_y * c.y() - c.z()) / denom;
    if (t > 0) best = t;
  }
  for (const auto& b : scene.buildings) {
    const double lo[3] = {b.x0, b.y0, scene.Ground(0.5 * (b.x0 + b.x1), 0.5 * (b.y0 + b.y1)) - 50.0};
    const double hi[3] = {b.x1, b.y1, RoofOf(scene, b)};
    double t0 = 0.0, t1 = kInf;
    int entry_axis = -1;
    bool hit = true;
    for (int a = 0; a < 3 && hit; ++a) {
      if (std::abs(d[a]) < 1e-12) {
        hit = c[a] >= lo[a] && c[a] <= hi[a];
        continue;
      }
      double ta = (lo[a] - c[a]) / d[a], tb = (hi[a] - c[a]) / d[a];
      if (ta > tb) std::swap(ta, tb);
      if (ta > t0) {
        t0 = ta;
        entry_axis = a;
      }
      t1 = std::min(t1, tb);
      hit = t0 <= t1;
    }
    if (hit && t0 > 0 && t0 < best) {
      best = t0;
      side = entry_axis != 2 ? 1 : 0;
    }
  }
  for (const auto& tr : scene.trees) {
    // The cap, c + t d on z = g(x, y) + base + cap (1 - r^2 / R^2): a quadratic in t.
    const double px = c.x() - tr.x, py = c.y() - tr.y;
    const double base = ReliefScene::kCrownBase * tr.height, cap = tr.height - base;
    const double k = cap / (tr.radius * tr.radius);
    const double slope_d = scene.slope_x * d.x() + scene.slope_y * d.y();
    const double qa = k * (d.x() * d.x() + d.y() * d.y());
    const double qb = 2.0 * k * (px * d.x() + py * d.y()) + d.z() - slope_d;
    const double qc = k * (px * px + py * py) - tr.height + c.z() - scene.Ground(c.x(), c.y());
    const double disc = qb * qb - 4.0 * qa * qc;
    if (qa > 0 && disc >= 0) {
      const double t = (-qb - std::sqrt(disc)) / (2.0 * qa);
      const Eigen::Vector3d p = c + t * d;
      if (t > 0 && t < best && Dome(tr, p.x(), p.y()) >= 0.0) {
        best = t;
        side = 0;
      }
    }
    // The side: entering the vertical cylinder r = R between the ground and the cap's rim.
    const double ca = d.x() * d.x() + d.y() * d.y();
    const double cb = 2.0 * (px * d.x() + py * d.y());
    const double cc = px * px + py * py - tr.radius * tr.radius;
    const double cdisc = cb * cb - 4.0 * ca * cc;
    if (ca > 1e-12 && cdisc >= 0) {
      const double t = (-cb - std::sqrt(cdisc)) / (2.0 * ca);
      const Eigen::Vector3d p = c + t * d;
      const double above = p.z() - scene.Ground(p.x(), p.y());
      if (t > 0 && t < best && above >= 0.0 && above <= base) {
        best = t;
        side = 2;
      }
    }
  }
  *side_out = side;
  return best;
}

}  // namespace

bool Sees(const ReliefScene& scene, const Eigen::Vector3d& from, const Eigen::Vector3d& to) {
  const Eigen::Vector3d d = to - from;
  int side = 0;
  return FirstHit(scene, from, d.normalized(), &side) >= d.norm() - 0.05;
}

cv::Mat RenderView(const ReliefScene& scene, cv::Size size, const Eigen::Vector3d& c, const RayOfPixel& ray) {
  cv::Mat out(size, CV_8UC3, cv::Scalar::all(0));
  for (int v = 0; v < size.height; ++v) {
    auto* row = out.ptr<cv::Vec3b>(v);
    for (int u = 0; u < size.width; ++u) {
      const Eigen::Vector3d d = ray(u, v).normalized();
      int side = 0;
      const double best = FirstHit(scene, c, d, &side);
      if (!std::isfinite(best)) continue;
      const Eigen::Vector3d p = c + best * d;
      if (std::abs(p.x()) > scene.half_extent || std::abs(p.y()) > scene.half_extent) continue;
      if (side == 1)
        row[u] = ReliefScene::WallColour(p.z());
      else if (side == 2)
        row[u] = Tint(Pattern(p.x() / scene.texture_scale, 2.0 * p.z() / scene.texture_scale, 7.0), {30, 80, 40}, 0.5);
      else
        row[u] = scene.TopColour(p.x(), p.y());
    }
  }
  return out;
}

namespace {
template <typename T, typename Fn>
cv::Mat_<T> RenderGrid(const TruthGrid& g, const Fn& fn) {
  cv::Mat_<T> out(g.height, g.width);
  for (int r = 0; r < g.height; ++r)
    for (int c = 0; c < g.width; ++c) out(r, c) = fn(g.x0 + (c + 0.5) * g.gsd, g.y0 - (r + 0.5) * g.gsd);
  return out;
}
}  // namespace

cv::Mat RenderTrueOrtho(const ReliefScene& scene, const TruthGrid& grid) {
  return RenderGrid<cv::Vec3b>(grid, [&](double x, double y) { return scene.TopColour(x, y); });
}
cv::Mat1f RenderTrueSurface(const ReliefScene& scene, const TruthGrid& grid) {
  return RenderGrid<float>(grid, [&](double x, double y) { return static_cast<float>(scene.Surface(x, y)); });
}
cv::Mat1f RenderTrueGround(const ReliefScene& scene, const TruthGrid& grid) {
  return RenderGrid<float>(grid, [&](double x, double y) { return static_cast<float>(scene.Ground(x, y)); });
}
cv::Mat1b RenderCover(const ReliefScene& scene, const TruthGrid& grid) {
  return RenderGrid<uchar>(grid, [&](double x, double y) { return static_cast<uchar>(scene.CoverAt(x, y)); });
}

}  // namespace uavm::eval
