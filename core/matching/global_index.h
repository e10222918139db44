#pragma once
#include <memory>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "core/features/sift.h"
#include "core/matching/kd_forest.h"

namespace uavm {

struct GlobalIndexOptions {
  int descriptors_per_frame = 256;  // a spread sample of each frame's descriptors
  int max_descriptors = 131072;     // hard cap (8-bit storage: 16 MiB); when reached, every frame keeps half
  int min_votes = 8;
  double ratio = 0.85;
  int rebuild_every_frames = 10;
  // A registered frame joins the index only when no indexed frame of its part of the flight is centred closer than
  // keyframe_spacing x its half-diagonal: the index then grows with the ground covered, not with flight time, and a
  // place flown over six times keeps six times the descriptors per frame. 0 indexes every frame.
  double keyframe_spacing = 0.5;

  [[nodiscard]] bool Check(std::string* why) const;
};

// Bounded relocalisation index over all earlier frames: a lost frame's descriptors vote for the frames they resemble.
// Memory is fixed by max_descriptors; old frames are thinned, never forgotten.
class GlobalIndex {
 public:
  explicit GlobalIndex(const GlobalIndexOptions& options);
  void Add(int frame_id, const Features& features);
  // Frames ranked by votes (most first), at most `max_results`, each with at least min_votes. With `allow_stale`
  // the kd-tree is rebuilt only after `rebuild_every_frames` additions: a per-frame query then costs a search, not a
  // rebuild, and misses only the newest frames (which recency matching covers anyway).
  [[nodiscard]] std::vector<int> Query(const Features& features, int max_results, bool allow_stale = false);
  [[nodiscard]] size_t size() const { return static_cast<size_t>(rows_); }
  [[nodiscard]] int per_frame_quota() const { return quota_; }
  [[nodiscard]] int thinnings() const { return thinnings_; }  // times every frame's share was halved
  // Bytes of the search structure built by the last query (0 before the first); the rows it searches are not counted.
  [[nodiscard]] size_t forest_bytes() const { return index_ ? index_->bytes() : 0; }
  // Frees the index (the end of the flight does not relocalise).
  void Release();

 private:
  void Thin();

  int thinnings_ = 0;

  GlobalIndexOptions options_;
  int quota_;
  // The forest searches the 8-bit rows in place with integer distances (the same neighbours on every CPU), and every
  // buffer but its own is sized once for max_descriptors: building it late in a long flight adds only the forest
  // (80 bytes a descriptor reserved, ~60 used: 4 trees of row orders and leaves of up to 4 rows; cvflann's one-row
  // leaves took ~180).
  static constexpr int kDescriptorSize = 128;  // SIFT
  static constexpr KdForest::Options kForest{4, 4, 0x5eed};
  static constexpr int kChecks = 64;  // rows compared per query descriptor
  cv::Mat descriptors_;               // CV_8U, max_descriptors rows allocated once; the first rows_ are in use
  int rows_ = 0;
  std::vector<int> frame_of_row_;
  std::vector<int> rank_in_frame_;   // 0..quota-1, used to thin evenly
  std::unique_ptr<KdForest> index_;  // borrows descriptors_' rows [0, index_rows_): reset before they move
  int index_rows_ = 0;               // rows of the built forest
  std::vector<int> index_frame_of_row_;
  bool dirty_ = true;
  int added_since_build_ = 0;
};

}  // namespace uavm
