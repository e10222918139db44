// The terrain model (core/sfm/terrain.h) on a synthetic scene with known ground (core/eval/relief_scene.h): buildings
// of 8-25 m and trees of 6-14 m on a slope, the DSM their surface with noise and holes.
#include <gtest/gtest.h>

#include <cmath>
#include <opencv2/imgproc.hpp>

#include "core/eval/relief_scene.h"
#include "core/sfm/terrain.h"
#include "core/util/portable_random.h"

namespace uavm::sfm {
namespace {

struct TerrainCase {
  eval::ReliefScene scene;
  eval::TruthGrid grid;
  cv::Mat1f dsm;
  cv::Mat1f truth;  // ground
  cv::Mat1b cover;
};

TerrainCase MakeCase(uint32_t seed, double cell, double noise_m) {
  TerrainCase t;
  t.scene = eval::MakeReliefScene(seed, 60.0, 8, 20);
  t.grid = {-60.0, 60.0, cell, static_cast<int>(120.0 / cell), static_cast<int>(120.0 / cell)};
  t.dsm = eval::RenderTrueSurface(t.scene, t.grid);
  t.truth = eval::RenderTrueGround(t.scene, t.grid);
  t.cover = eval::RenderCover(t.scene, t.grid);
  PortableRandom rng(seed);
  for (int r = 0; r < t.dsm.rows; ++r)
    for (int c = 0; c < t.dsm.cols; ++c) t.dsm(r, c) += static_cast<float>(rng.Normal(noise_m));
  // Holes, as dense matching leaves them: a few patches of no height.
  for (int k = 0; k < 6; ++k) {
    const int x = static_cast<int>(rng.Uniform(0, t.dsm.cols - 20));
    const int y = static_cast<int>(rng.Uniform(0, t.dsm.rows - 20));
    t.dsm(cv::Rect(x, y, 12, 12)).setTo(-9999.0f);
  }
  return t;
}

// RMS of dtm - truth over `where`.
double Rms(const cv::Mat1f& dtm, const cv::Mat1f& truth, const cv::Mat& where) {
  const cv::Mat d = dtm - truth;
  const cv::Mat sq = d.mul(d);
  return std::sqrt(cv::mean(sq, where)[0]);
}

TEST(Terrain, GroundUnderBuildingsAndTreesOfASlopedScene) {
  const TerrainCase t = MakeCase(3, 0.5, 0.08);
  TerrainOptions options;
  TerrainReport report;
  cv::Mat1b ground;
  const cv::Mat1f dtm = TerrainFromDsm(t.dsm, -9999.0f, t.grid.gsd, options, &ground, &report);
  const cv::Mat valid = t.dsm != -9999.0f;
  const cv::Mat under_buildings = (t.cover == 1) & valid, under_trees = (t.cover == 2) & valid;
  const cv::Mat open_ground = (t.cover == 0) & valid;
  const double rms_buildings = Rms(dtm, t.truth, under_buildings), rms_trees = Rms(dtm, t.truth, under_trees);
  const double rms_ground = Rms(dtm, t.truth, open_ground);
  // Classification: most of the open ground is ground, almost no roof or crown is.
  const double ground_kept =
      cv::countNonZero(ground & open_ground) / static_cast<double>(cv::countNonZero(open_ground));
  const double roofs_kept =
      cv::countNonZero(ground & under_buildings) / static_cast<double>(cv::countNonZero(under_buildings));
  const double crowns_kept =
      cv::countNonZero(ground & under_trees) / static_cast<double>(cv::countNonZero(under_trees));
  std::printf(
      "DTM RMS: under buildings %.3f m, under trees %.3f m, open ground %.3f m; ground kept %.3f, roofs %.4f, crowns "
      "%.4f (%d openings)\n",
      rms_buildings, rms_trees, rms_ground, ground_kept, roofs_kept, crowns_kept, report.windows);
  EXPECT_GT(ground_kept, 0.9);
  EXPECT_LT(roofs_kept, 0.01);
  EXPECT_LT(crowns_kept, 0.05);
  // 3 GSD of the bench flight (0.089 m) under what stands on the ground; the noise level on the open ground.
  EXPECT_LT(rms_buildings, 0.27);
  EXPECT_LT(rms_trees, 0.27);
  EXPECT_LT(rms_ground, 0.12);
  // The DSM itself under the same objects is metres off: the test can fail.
  EXPECT_GT(Rms(t.dsm, t.truth, under_buildings), 5.0);
  // Nodata stays nodata.
  EXPECT_EQ(cv::countNonZero(dtm == -9999.0f), cv::countNonZero(valid == 0));
}

TEST(Terrain, FlatGroundWithoutObjectsIsAllGround) {
  cv::Mat1f dsm(100, 100, 12.0f);
  for (int r = 0; r < 100; ++r)
    for (int c = 0; c < 100; ++c) dsm(r, c) += 0.03f * static_cast<float>(c);  // a 6 % slope
  cv::Mat1b ground;
  TerrainReport report;
  const cv::Mat1f dtm = TerrainFromDsm(dsm, -9999.0f, 0.5, TerrainOptions{}, &ground, &report);
  EXPECT_EQ(report.ground_cells, 100 * 100);
  EXPECT_LT(cv::norm(dtm, dsm, cv::NORM_INF), 1e-4);
  std::string why;
  TerrainOptions bad;
  bad.max_window_m = 0.0;
  EXPECT_FALSE(bad.Check(&why));
}

}  // namespace
}  // namespace uavm::sfm
