#pragma once
#include <memory>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "core/frame/frame.h"
#include "core/registration/registration_engine.h"
#include "core/session/edge_store.h"
#include "core/session/feature_store.h"
#include "core/session/session_dir.h"

namespace uavm {

// What the session keeps on disk for each frame, and the engine's views of it: the frame's bytes (frames/), its
// features (features/ behind a bounded memory cache), its edges' points (edges.bin) and its thumbnail (thumbs/, for
// the radiometry). One owner for the files a resumed run reads back.
class SessionStores {
 public:
  // Opens edges.bin (without it, edge points stay in memory: slower to grow flat, nothing lost).
  SessionStores(const SessionPaths& paths, size_t feature_cache_bytes);
  ~SessionStores();
  SessionStores(const SessionStores&) = delete;
  SessionStores& operator=(const SessionStores&) = delete;

  // The frame's bytes in frames/ as `stored_file` (the source's file copied, EXIF included, else `encoded`).
  [[nodiscard]] bool StoreFrameBytes(const Frame& frame, const std::vector<uchar>& encoded,
                                     const std::string& stored_file, std::string* error) const;
  // The frame's thumbnail in thumbs/ (radiometry: a thumbnail per frame on disk rather than in memory keeps the
  // flight's memory flat; the end-of-flight solve reads each back a few times, ~30 KB each). Returns it.
  [[nodiscard]] cv::Mat StoreThumbnail(int id, const cv::Mat& work_bgr, int thumb_long_side);
  [[nodiscard]] static std::string ThumbPath(const std::string& thumbs_dir, int id);

  [[nodiscard]] FeatureStore& features() { return feature_store_; }
  [[nodiscard]] const FeatureStore& features() const { return feature_store_; }
  [[nodiscard]] EdgeStore& edges() { return edge_store_; }
  [[nodiscard]] const EdgeStore& edges() const { return edge_store_; }
  // The engine's views: the feature cache, and edges.bin (null when it could not be opened).
  [[nodiscard]] FeatureProvider* feature_provider();
  [[nodiscard]] EdgeSpill* edge_spill();

 private:
  class FeatureView;
  class EdgeView;

  std::string thumbs_dir_;
  bool thumbs_dir_made_ = false;
  FeatureStore feature_store_;
  EdgeStore edge_store_;
  std::unique_ptr<FeatureView> feature_view_;
  std::unique_ptr<EdgeView> edge_view_;
};

// The name of frame `id` in frames/: its id, then the source's name made safe for a path.
[[nodiscard]] std::string StoredName(int id, const std::string& name);

}  // namespace uavm
