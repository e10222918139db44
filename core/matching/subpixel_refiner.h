#pragma once
#include <cstddef>
#include <deque>
#include <opencv2/core.hpp>
#include <string>
#include <utility>
#include <vector>

#include "core/geometry/transform.h"

namespace uavm {

struct SubpixelOptions {
  // Refine a verified pair's inliers at the working resolution: each source point's neighbourhood, warped into the
  // target by the pair's affine, is tracked there by Lucas-Kanade from the matched keypoint. The correspondence then
  // no longer depends on where either detector put its keypoint, only on the image content; what makes detection on a
  // half-size copy (features.half_size) as accurate as detection at full size.
  bool enabled = false;
  int window = 15;                 // LK window side (odd), working px
  int cache_frames = 16;           // grey working images kept for it (the newest; the memory plan may lower it)
  double max_shift_px = 2.0;       // a refined point further than this from its keypoint is a failed track: dropped
  double min_kept_fraction = 0.5;  // when fewer tracks succeed, the pair keeps its keypoints unrefined

  [[nodiscard]] bool Check(std::string* why) const;
};

// What the refinement did over the flight (report.json "subpixel").
struct SubpixelCounters {
  long edges_refined = 0;
  long edges_not_cached = 0;      // a frame's image had left the cache (an old frame: loops, end-of-flight edges)
  long edges_kept_unrefined = 0;  // too few tracks succeeded
  long points_refined = 0;
  long points_dropped = 0;
};

// A bounded cache of the newest frames' grey working images and the refinement of pairs between them.
// Single-threaded (the registration loop's).
class SubpixelRefiner {
 public:
  explicit SubpixelRefiner(const SubpixelOptions& options);

  // Frame `id`'s grey working image (CV_8UC1, the pixels its features' coordinates refer to); shared, not copied. The
  // oldest image leaves once cache_frames are held.
  void Put(int id, cv::Mat gray);
  // Refines `tgt` (points in frame tgt_id) of the correspondences src[i] (frame src_id) <-> tgt[i], dropping failed
  // tracks from both lists. False (lists unchanged) when an image is not cached or too few tracks succeed.
  [[nodiscard]] bool Refine(int src_id, int tgt_id, const Mat3& tgt_from_src, std::vector<Vec2>* src,
                            std::vector<Vec2>* tgt);
  // As Refine, over two sets of one pair at once (the adjustment's points and the held-out ones), which stay
  // disjoint; both are refined or neither.
  [[nodiscard]] bool RefinePair(int src_id, int tgt_id, const Mat3& tgt_from_src,
                                std::pair<std::vector<Vec2>*, std::vector<Vec2>*> used,
                                std::pair<std::vector<Vec2>*, std::vector<Vec2>*> holdout);

  [[nodiscard]] const SubpixelCounters& counters() const { return counters_; }
  [[nodiscard]] size_t MemoryBytes() const;
  [[nodiscard]] const SubpixelOptions& options() const { return options_; }

 private:
  [[nodiscard]] const cv::Mat* Find(int id) const;
  // Tracks each src_pts[i], warped into the target, from tgt_pts[i]; ok[i] says whether tgt_pts[i] was refined.
  void Track(const cv::Mat& src, const cv::Mat& tgt, const Mat3& tgt_from_src, const std::vector<Vec2>& src_pts,
             std::vector<Vec2>* tgt_pts, std::vector<unsigned char>* ok) const;

  SubpixelOptions options_;
  std::deque<std::pair<int, cv::Mat>> images_;  // oldest first
  SubpixelCounters counters_;
};

}  // namespace uavm
