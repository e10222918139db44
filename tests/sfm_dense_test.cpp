// Stereo pair selection on a synthetic flight and the cross-pair consistency of the cloud fusion.
#include <gtest/gtest.h>

#include <set>

#include "core/sfm/dense.h"
#include "sfm_synthetic.h"

namespace uavm::sfm {
namespace {

TEST(SfmDense, PairSelectionRespectsBaselineAndOverlap) {
  const Reconstruction rec = testing::MakeScene(0.0, 9);
  DenseOptions o;
  o.min_baseline_ratio = 0.1;
  o.max_baseline_ratio = 0.3;
  o.pairs_per_image = 2;
  const auto pairs = SelectStereoPairs(rec, o);
  ASSERT_GE(pairs.size(), 8u);
  std::set<std::pair<int, int>> seen;
  for (const auto& p : pairs) {
    EXPECT_TRUE(seen.insert(std::minmax(p.image1, p.image2)).second) << "duplicate pair";
    const double b =
        (rec.images[static_cast<size_t>(p.image1)].pose.c - rec.images[static_cast<size_t>(p.image2)].pose.c).norm();
    EXPECT_NEAR(p.baseline_ratio, b / 61.0, 0.03);  // depth ~60 m over ground near z = 0
    EXPECT_GE(p.baseline_ratio, 0.1);
    EXPECT_LE(p.baseline_ratio, 0.3);
    EXPECT_GE(p.overlap, o.min_overlap);
    EXPECT_LT(p.min_depth, 55.0);
    EXPECT_GT(p.max_depth, 65.0);
  }
}

TEST(SfmDense, FusionKeepsOnlyHeightsTwoPairsAgreeOn) {
  std::vector<CloudPoint> pts;
  std::vector<int> pair;
  auto add = [&](float x, float y, float z, int p) {
    pts.push_back({{x, y, z}, {10, 20, 30}});
    pair.push_back(p);
  };
  // Cell (0,0): pairs 0 and 1 agree on z ~ 1.4 (one voxel: z in [1, 2)); pair 2 has an outlier at z = 9.
  add(0.2f, 0.2f, 1.40f, 0);
  add(0.3f, 0.4f, 1.45f, 1);
  add(0.6f, 0.7f, 1.35f, 1);
  add(0.5f, 0.5f, 9.0f, 2);
  // Cell (3,0): only pair 0 -> no consistency, dropped.
  add(3.5f, 0.5f, 2.0f, 0);
  add(3.6f, 0.4f, 2.0f, 0);
  FusionReport rep;
  const auto out = FuseClouds(pts, pair, 1.0, 0.5, 2, &rep);
  EXPECT_EQ(rep.input, 6u);
  EXPECT_EQ(rep.cells, 2u);
  EXPECT_EQ(rep.cells_consistent, 1u);
  EXPECT_EQ(rep.kept_points, 3u);
  ASSERT_EQ(out.size(), 1u);  // one voxel: the three agreeing points averaged
  EXPECT_NEAR(out[0].xyz[2], 1.4, 1e-5);
  EXPECT_NEAR(out[0].xyz[0], (0.2 + 0.3 + 0.6) / 3, 1e-5);
  EXPECT_EQ(out[0].bgr, cv::Vec3b(10, 20, 30));
  // With min_pairs = 1 the single-pair cell stays.
  const auto loose = FuseClouds(pts, pair, 1.0, 0.5, 1, &rep);
  EXPECT_EQ(loose.size(), 2u);
}

}  // namespace
}  // namespace uavm::sfm
