#include "core/graph/match_graph.h"

#include <gtest/gtest.h>

namespace uavm {
namespace {

Edge MakeEdge(int a, int b, int inliers) {
  Edge e;
  e.src = a;
  e.tgt = b;
  e.num_inliers = inliers;
  return e;
}

TEST(MatchGraphTest, LargestComponentUsesRelativeThreshold) {
  MatchGraph g;
  for (int i = 0; i < 6; ++i) g.AddNode(i);
  g.AddEdge(MakeEdge(0, 1, 400));
  g.AddEdge(MakeEdge(1, 2, 300));
  g.AddEdge(MakeEdge(3, 4, 500));
  g.AddEdge(MakeEdge(2, 3, 22));  // above the floor (20) but below 5 % of 500 = 25: does not count
  const auto c = g.LargestComponent(0.05, 20);
  EXPECT_EQ(c, (std::vector<int>{0, 1, 2}));
  // With a lower relative threshold the weak edge joins everything but the isolated frame 5.
  EXPECT_EQ(g.LargestComponent(0.04, 20), (std::vector<int>{0, 1, 2, 3, 4}));
}

TEST(MatchGraphTest, UnionFindMergesAndCounts) {
  UnionFind uf;
  for (int i = 0; i < 5; ++i) uf.Add();
  uf.Unite(0, 1);
  uf.Unite(3, 4);
  uf.Unite(1, 4);
  EXPECT_EQ(uf.Find(0), uf.Find(3));
  EXPECT_EQ(uf.SizeOf(0), 4);
  EXPECT_NE(uf.Find(2), uf.Find(0));
}

// An edge's points in one block, as edges.bin lays them out: the pairs, then the held-out pairs, each (src, tgt).
std::vector<Vec2f> Line(size_t n, float offset) {
  std::vector<Vec2f> out;
  for (size_t k = 0; k < n; ++k) out.emplace_back(static_cast<float>(k) + offset, 2.0f * static_cast<float>(k));
  return out;
}

TEST(EdgePointsTest, KeepsPairsAndHeldOutPairsInTheLayoutOfEdgesBin) {
  const EdgePoints p(Line(3, 0.0f), Line(3, 100.0f), Line(2, 500.0f), Line(2, 600.0f));
  ASSERT_EQ(p.size(), 3u);
  ASSERT_EQ(p.holdout_size(), 2u);
  EXPECT_EQ(p.src(2), Vec2f(2.0f, 4.0f));
  EXPECT_EQ(p.tgt(1), Vec2f(101.0f, 2.0f));
  EXPECT_EQ(p.holdout_src(1), Vec2f(501.0f, 2.0f));
  EXPECT_EQ(p.holdout_tgt(0), Vec2f(600.0f, 0.0f));
  ASSERT_EQ(p.float_count(), 4u * 5u);
  // {x_src, y_src, x_tgt, y_tgt} per pair: the second pair, then the first held-out pair.
  const std::vector<float> second(p.floats() + 4, p.floats() + 8);
  EXPECT_EQ(second, (std::vector<float>{1.0f, 2.0f, 101.0f, 2.0f}));
  const std::vector<float> held(p.floats() + 12, p.floats() + 16);
  EXPECT_EQ(held, (std::vector<float>{500.0f, 0.0f, 600.0f, 0.0f}));
  // Lists of unequal length keep the shorter's count of pairs.
  const EdgePoints uneven(Line(4, 0.0f), Line(3, 0.0f), Line(1, 0.0f), {});
  EXPECT_EQ(uneven.size(), 3u);
  EXPECT_EQ(uneven.holdout_size(), 0u);
}

TEST(EdgePointsTest, ThinKeepsAnEvenStrideOfEachListAndFreesTheRest) {
  Edge e;
  e.points = EdgePoints(Line(100, 0.0f), Line(100, 1000.0f), Line(10, 5000.0f), Line(10, 6000.0f));
  const size_t before = e.points.bytes();
  EXPECT_EQ(e.points.Thin(10, 4), 90u + 6u);
  ASSERT_EQ(e.points.size(), 10u);
  ASSERT_EQ(e.points.holdout_size(), 4u);
  for (size_t k = 0; k < 10; ++k) {
    EXPECT_EQ(e.points.src(k).x(), static_cast<float>(10 * k));  // every tenth pair, spread over the whole list
    EXPECT_EQ(e.points.tgt(k).x(), static_cast<float>(10 * k) + 1000.0f);
  }
  EXPECT_EQ(e.points.holdout_src(3).x(), 5007.0f);  // 3 * 10 / 4
  EXPECT_EQ(e.points.holdout_tgt(3).x(), 6007.0f);
  EXPECT_LT(e.points.bytes(), before / 5);
  EXPECT_EQ(e.points.Thin(10, 4), 0u);  // already within: nothing dropped
}

TEST(EdgePointsTest, CombineTakesOnesPairsAndTheOthersHeldOutPairs) {
  const EdgePoints fit(Line(3, 0.0f), Line(3, 10.0f), Line(5, 20.0f), Line(5, 30.0f));
  const EdgePoints held(Line(7, 40.0f), Line(7, 50.0f), Line(2, 60.0f), Line(2, 70.0f));
  const EdgePoints both = EdgePoints::Combine(fit, held);
  ASSERT_EQ(both.size(), 3u);
  ASSERT_EQ(both.holdout_size(), 2u);
  EXPECT_EQ(both.tgt(2), fit.tgt(2));
  EXPECT_EQ(both.holdout_src(1), held.holdout_src(1));
  EXPECT_EQ(both.holdout_tgt(0), held.holdout_tgt(0));
}

TEST(EdgePointsTest, AnEdgeHoldsItsPointsInOneBlock) {
  // Four vectors were 96 bytes of every edge record and four allocations; the block is one of each.
  EXPECT_LE(sizeof(EdgePoints), sizeof(std::vector<Vec2f>) + 8);
  EXPECT_LE(sizeof(Edge), 144u);
  Edge e;
  e.points = EdgePoints(Line(5, 0.0f), Line(5, 0.0f), Line(1, 0.0f), Line(1, 0.0f));
  EXPECT_EQ(e.points.bytes(), 12u * sizeof(Vec2f));
  e.points.Free();
  EXPECT_EQ(e.points.bytes(), 0u);
  EXPECT_EQ(e.points.size() + e.points.holdout_size(), 0u);
}

}  // namespace
}  // namespace uavm
