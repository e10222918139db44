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

}  // namespace
}  // namespace uavm
