#pragma once
#include <Eigen/Core>
#include <cstdint>
#include <functional>
#include <opencv2/core.hpp>
#include <vector>

// A synthetic scene with relief and known truth, for the ground tool's tests and benches: a textured height field
// (a sloped ground, box buildings, trees with rounded crowns) that cameras see by ray casting, and the truth a
// surveyor's products are checked against (the true orthophoto, the DSM and the DTM, all rendered from above).
namespace uavm::eval {

struct ReliefScene {
  struct Building {
    double x0 = 0, y0 = 0, x1 = 0, y1 = 0;  // footprint, metres
    double height = 10.0;                   // above the ground at its centre (flat roof)
  };
  // A crown: a paraboloid cap of this radius reaching `height`, on a solid of the same radius from the ground up to
  // kCrownBase x height (its overhanging sides; the trunk beneath is not modelled).
  struct Tree {
    double x = 0, y = 0, radius = 3.0, height = 8.0;
  };
  static constexpr double kCrownBase = 0.45;
  double half_extent = 60.0;            // the scene covers [-half_extent, half_extent]^2 metres
  double slope_x = 0.0, slope_y = 0.0;  // the ground plane's gradient
  // The textures' finest wavelength, metres: a scene seen at GSD g needs texture_scale >= ~3 g to have no detail
  // finer than the frames can hold (which no resampling could render the same).
  double texture_scale = 0.3;
  std::vector<Building> buildings;
  std::vector<Tree> trees;

  [[nodiscard]] double Ground(double x, double y) const { return slope_x * x + slope_y * y; }
  // The top surface (what a DSM holds).
  [[nodiscard]] double Surface(double x, double y) const;
  [[nodiscard]] double MaxSurface() const;
  // The surface's colour seen from above (what the true orthophoto holds).
  [[nodiscard]] cv::Vec3b TopColour(double x, double y) const;
  // A building wall's colour (saturated red stripes: what a leaning wall puts into an orthophoto is easy to find).
  [[nodiscard]] static cv::Vec3b WallColour(double z);
  // What covers (x, y): 0 ground, 1 building, 2 tree.
  [[nodiscard]] int CoverAt(double x, double y) const;
};

// A scene of `buildings` boxes (8-25 m) and `trees` (6-14 m) on a gentle slope, placed from `seed` without overlap.
[[nodiscard]] ReliefScene MakeReliefScene(uint32_t seed, double half_extent, int buildings, int trees);

// Renders a camera's view by ray casting: `ray` gives the world direction of the ray through pixel (u, v)
// (pixel-centre convention) from `centre`. BGR8 of `size`; rays that hit nothing within the scene are black.
using RayOfPixel = std::function<Eigen::Vector3d(double u, double v)>;
[[nodiscard]] cv::Mat RenderView(const ReliefScene& scene, cv::Size size, const Eigen::Vector3d& centre,
                                 const RayOfPixel& ray);

// Whether the point `to` is seen from `from` (nothing of the scene between them; 5 cm of tolerance at `to`).
[[nodiscard]] bool Sees(const ReliefScene& scene, const Eigen::Vector3d& from, const Eigen::Vector3d& to);

// The truth from above on a north-up grid: pixel (c, r) is at x = x0 + (c + 0.5) * gsd, y = y0 - (r + 0.5) * gsd.
struct TruthGrid {
  double x0 = 0, y0 = 0, gsd = 0.1;
  int width = 0, height = 0;
};
[[nodiscard]] cv::Mat RenderTrueOrtho(const ReliefScene& scene, const TruthGrid& grid);  // BGR8
[[nodiscard]] cv::Mat1f RenderTrueSurface(const ReliefScene& scene, const TruthGrid& grid);
[[nodiscard]] cv::Mat1f RenderTrueGround(const ReliefScene& scene, const TruthGrid& grid);
[[nodiscard]] cv::Mat1b RenderCover(const ReliefScene& scene, const TruthGrid& grid);  // 0 ground, 1 building, 2 tree

}  // namespace uavm::eval
