// Feature tracks by union-find, with tracks that would hold two features of one image split at the weakest link.
#include <gtest/gtest.h>

#include <algorithm>

#include "core/sfm/tracks.h"

namespace uavm::sfm {
namespace {

bool HasObs(const Track& t, int image, int feature) {
  return std::find(t.begin(), t.end(), Observation{image, feature}) != t.end();
}

TEST(SfmTracks, ChainsMergeAcrossPairs) {
  // 0:5 - 1:7 - 2:3 - 3:1 and a separate pair 0:9 - 2:4.
  std::vector<FeatureMatch> m = {{0, 5, 1, 7, 1.f}, {1, 7, 2, 3, 1.f}, {2, 3, 3, 1, 1.f}, {0, 9, 2, 4, 1.f}};
  TrackStats st;
  const auto tracks = BuildTracks(m, 2, &st);
  ASSERT_EQ(tracks.size(), 2u);
  const Track& a = tracks[0].size() == 4 ? tracks[0] : tracks[1];
  const Track& b = tracks[0].size() == 4 ? tracks[1] : tracks[0];
  EXPECT_EQ(a, (Track{{0, 5}, {1, 7}, {2, 3}, {3, 1}}));
  EXPECT_EQ(b, (Track{{0, 9}, {2, 4}}));
  EXPECT_EQ(st.conflicts_refused, 0);
}

TEST(SfmTracks, ConflictIsSplitAtTheWeakestLink) {
  // 0:1 - 1:1 - 2:1 - 0:2 would put features 1 and 2 of image 0 into one track. The 2:1 - 0:2 match is the worst
  // (largest cost), so it is the link that gets refused.
  std::vector<FeatureMatch> m = {{0, 1, 1, 1, 0.1f}, {1, 1, 2, 1, 0.2f}, {2, 1, 0, 2, 0.9f}, {0, 2, 3, 5, 0.3f}};
  TrackStats st;
  const auto tracks = BuildTracks(m, 2, &st);
  EXPECT_EQ(st.conflicts_refused, 1);
  ASSERT_EQ(tracks.size(), 2u);
  for (const auto& t : tracks) {
    // No image twice in a track.
    for (size_t i = 1; i < t.size(); ++i) EXPECT_NE(t[i].image, t[i - 1].image);
  }
  const Track& a = HasObs(tracks[0], 0, 1) ? tracks[0] : tracks[1];
  const Track& b = HasObs(tracks[0], 0, 1) ? tracks[1] : tracks[0];
  EXPECT_EQ(a, (Track{{0, 1}, {1, 1}, {2, 1}}));
  EXPECT_EQ(b, (Track{{0, 2}, {3, 5}}));
}

TEST(SfmTracks, MinLengthDropsShortTracks) {
  std::vector<FeatureMatch> m = {{0, 1, 1, 1, 0.f}, {1, 1, 2, 1, 0.f}, {0, 4, 1, 4, 0.f}};
  const auto tracks = BuildTracks(m, 3);
  ASSERT_EQ(tracks.size(), 1u);
  EXPECT_EQ(tracks[0].size(), 3u);
}

}  // namespace
}  // namespace uavm::sfm
