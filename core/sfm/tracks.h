#pragma once
#include <vector>

namespace uavm::sfm {

// One verified feature correspondence between two images. Lower `cost` = better (descriptor distance).
struct FeatureMatch {
  int image1 = -1, feature1 = -1;
  int image2 = -1, feature2 = -1;
  float cost = 0.0f;
};

struct Observation {
  int image = -1;
  int feature = -1;
  bool operator==(const Observation&) const = default;
};

using Track = std::vector<Observation>;

struct TrackStats {
  int matches_in = 0;
  int unions = 0;
  int conflicts_refused = 0;  // unions that would have put two features of one image into a track
};

// Tracks by union-find over pairwise matches. Matches are merged best first; a merge that would give a track two
// different features of the same image is refused, which splits such a track at its weakest link. Tracks shorter
// than `min_length` observations are dropped. Observations in each track are sorted by image.
[[nodiscard]] std::vector<Track> BuildTracks(std::vector<FeatureMatch> matches, int min_length = 2,
                                             TrackStats* stats = nullptr);

}  // namespace uavm::sfm
