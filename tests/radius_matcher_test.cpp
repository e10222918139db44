// Guided matching within a radius (core/matching/radius_matcher.h): the prediction decides the candidates, the ratio
// test and the mutual check decide among them.
#include "core/matching/radius_matcher.h"

#include <gtest/gtest.h>

namespace uavm {
namespace {

// Frame A's points on a grid, B = A moved by (100, 0) with the same descriptors (distinct random rows).
struct Scene {
  std::vector<Vec2> a, b;
  cv::Mat desc_a, desc_b;
  Scene() {
    for (int y = 0; y < 5; ++y)
      for (int x = 0; x < 6; ++x) {
        a.emplace_back(40.0 + 60.0 * x, 40.0 + 60.0 * y);
        b.push_back(a.back() + Vec2(100, 0));
      }
    desc_a = cv::Mat(static_cast<int>(a.size()), 16, CV_32F);
    cv::RNG rng(7);
    rng.fill(desc_a, cv::RNG::UNIFORM, 0.0, 1.0);
    desc_b = desc_a.clone();
  }
};

TEST(RadiusMatcher, MatchesThePredictedPartners) {
  const Scene s;
  const auto m = MatchWithinRadius(s.a, s.desc_a, s.b, s.desc_b, cv::Size(600, 400), Translation(100, 0),
                                   {.radius_px = 25, .ratio = 0.8});
  ASSERT_EQ(m.size(), s.a.size());
  for (size_t k = 0; k < m.size(); ++k) {
    EXPECT_EQ(m[k].a, static_cast<int>(k));  // ascending in a
    EXPECT_EQ(m[k].b, static_cast<int>(k));
    EXPECT_EQ(m[k].distance_sq, 0.f);
  }
}

TEST(RadiusMatcher, NothingBeyondTheRadius) {
  const Scene s;
  // The prediction is 30 px off, half-way between two rows 60 px apart: nothing of B within 25 px of it.
  const auto m = MatchWithinRadius(s.a, s.desc_a, s.b, s.desc_b, cv::Size(600, 400), Translation(100, 30),
                                   {.radius_px = 25, .ratio = 0.8});
  EXPECT_TRUE(m.empty());
}

TEST(RadiusMatcher, AmbiguousCandidatesFailTheRatioTest) {
  Scene s;
  // A look-alike of B's point 0 right next to it: point 0 of A (not quite either) has two about equally good
  // candidates.
  s.b.push_back(s.b[0] + Vec2(5, 0));
  cv::Mat twin = s.desc_b.row(0).clone();
  twin.at<float>(0, 0) += 1e-3f;
  s.desc_b.push_back(twin);
  s.desc_a.at<float>(0, 1) += 0.01f;
  const auto m = MatchWithinRadius(s.a, s.desc_a, s.b, s.desc_b, cv::Size(600, 400), Translation(100, 0),
                                   {.radius_px = 25, .ratio = 0.8});
  ASSERT_EQ(m.size(), s.a.size() - 1);
  EXPECT_EQ(m[0].a, 1);
}

TEST(RadiusMatcher, OnlyMutualBest) {
  Scene s;
  // A second point of A near point 0, closer in descriptor to B's point 0 than A's own point 0 is: B's point 0
  // prefers it, so A's point 0 loses its match (and the newcomer, the best of both, keeps it).
  s.a.push_back(s.a[0] + Vec2(3, 0));
  cv::Mat copy = s.desc_a.row(0).clone();
  s.desc_a.push_back(copy);
  s.desc_a.at<float>(0, 0) += 0.05f;
  const auto m = MatchWithinRadius(s.a, s.desc_a, s.b, s.desc_b, cv::Size(600, 400), Translation(100, 0),
                                   {.radius_px = 25, .ratio = 0.8});
  ASSERT_EQ(m.size(), s.a.size() - 1);
  EXPECT_EQ(m.front().a, 1);
  EXPECT_EQ(m.back().a, static_cast<int>(s.a.size()) - 1);
  EXPECT_EQ(m.back().b, 0);
}

}  // namespace
}  // namespace uavm
