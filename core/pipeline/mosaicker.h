#pragma once
#include <deque>
#include <functional>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <unordered_map>
#include <unordered_set>
#include <vector>

#include "core/geometry/footprint_grid.h"
#include "core/graph/components.h"
#include "core/graph/match_graph.h"
#include "core/matching/global_index.h"
#include "core/mosaic/live_preview.h"
#include "core/pipeline/memory_budget.h"
#include "core/pipeline/options.h"
#include "core/session/edge_store.h"
#include "core/session/feature_store.h"
#include "core/session/journal.h"
#include "core/session/session_dir.h"
#include "core/util/memory.h"
#include "core/util/stats.h"
#include "hal/common/frame_source.h"

namespace uavm {

// Outcome of one frame in the loop.
enum class FrameOutcome { kRegistered, kNewComponent, kFailed };

struct SkippedInput {
  std::string file;
  std::string reason;
};

// The onboard registration: each frame is registered as it arrives (features -> bounded candidate matching ->
// RANSAC affine -> match graph -> local / periodic full adjustment); Finish() keeps the largest connected component,
// solves it fully, writes the session files and composites the mosaic.
class Mosaicker {
 public:
  Mosaicker(const PipelineOptions& options, SessionPaths paths);
  ~Mosaicker();

  // A frame made ready for registration: working copy and features. Prepare() touches no Mosaicker state, so the
  // capture thread runs it while the previous frame is being matched (two cores, two stages).
  struct Prepared {
    hal::Frame frame;
    cv::Mat work_bgr;
    cv::Mat work_gray;
    Features features;
    std::vector<uchar> encoded;  // JPEG of the frame when the source has no file to copy
    double decode_ms = 0.0;      // measured by the caller around the source's Next()
    double prepare_ms = 0.0;
    double features_ms = 0.0;
    bool resumed = false;     // already in the session (frames/, features/, journal): registered again, not stored
    std::string stored_name;  // its file in frames/ when resumed
  };
  [[nodiscard]] Prepared Prepare(hal::Frame frame) const;
  [[nodiscard]] Prepared PrepareImages(hal::Frame frame) const;  // working copies, no features
  // A frame of the journal being resumed: `frame` decoded from frames/, features read from features/ (computed again
  // only if their file is unreadable). AddFrame then registers it exactly as the interrupted run did.
  [[nodiscard]] Prepared PrepareStored(hal::Frame frame, int id, const std::string& stored_name) const;
  // Starts the session journal (journal.jsonl): new, or appended after `valid_bytes` of a resumed one.
  [[nodiscard]] bool StartJournal(bool append, uint64_t valid_bytes, std::string* error);
  [[nodiscard]] FrameOutcome AddFrame(Prepared prepared);
  [[nodiscard]] FrameOutcome AddFrame(hal::Frame frame) { return AddFrame(Prepare(std::move(frame))); }
  // An input the source could not turn into a frame (corrupt, empty, not an image).
  void RecordSkipped(const std::string& file, const std::string& reason, bool journal = true);
  void RecordDropped(size_t count) { dropped_frames_ = count; }
  // A live camera's counters (captured, dropped in its own queue, driver gaps, reconnects): report.json "camera".
  void RecordCapture(const hal::CaptureCounters& counters) { capture_ = counters; }
  // The memory plan the options were sized with (reported in report.json).
  void SetMemoryPlan(const MemoryPlan& plan) { memory_plan_ = plan; }
  // Final solve, session files and mosaic. Returns false on an output failure (message in `error`).
  [[nodiscard]] bool Finish(std::string* error);

  [[nodiscard]] size_t frames_in() const { return frames_.size(); }
  [[nodiscard]] int registered_count() const { return final_registered_; }
  // Why the session could not store an accepted frame (disk full, storage gone); empty while all is well. Once set,
  // the caller stops taking frames: what is already in the session stays whole and a resumed run continues it.
  [[nodiscard]] const std::string& storage_failure() const { return storage_failure_; }
  [[nodiscard]] double residual_rms_px() const { return final_rms_; }
  [[nodiscard]] const StageStats& stage_stats() const { return stats_; }

  // Called from the frame loop with each new live.jpg's bytes (e.g. the live HTTP server); must not block.
  void SetPreviewListener(std::function<void(std::shared_ptr<const std::string>)> listener) {
    preview_listener_ = std::move(listener);
  }

 private:
  struct FrameState {
    int id = -1;
    std::string name;
    std::string stored_file;  // path inside the session's frames/
    cv::Size original_size;
    int64_t timestamp_ns = 0;
    cv::Size work_size;
    Mat3 work_from_original = Mat3::Identity();
    double half_diagonal = 1.0;
    bool has_features = false;
    bool in_graph = false;  // has at least one edge or anchors its own component
    bool keyframe = false;  // in the global (relocalisation) index
    std::string failure;    // why it is not registered (so far)
    hal::FrameMetadata metadata;
  };

  [[nodiscard]] bool StoreFrameBytes(const hal::Frame& frame, const std::vector<uchar>& encoded, FrameState* state,
                                     std::string* error);
  // The frames of `root`'s component, ascending (none when the frame registered nothing). Valid until a merge.
  [[nodiscard]] const std::vector<int>& MembersOf(int root);
  // The edges of `root`'s component that touch one of `ids`, in the graph's order.
  [[nodiscard]] std::vector<const Edge*> EdgesTouching(const std::unordered_set<int>& ids, int root);
  void AddEdge(Edge edge);
  // Gives back the points of edges whose frames have left the solve window (they stay in edges.bin).
  void ReleaseColdEdges();
  // Makes the points of `edges` resident again; false (and a logged reason) if one cannot be read.
  bool LoadEdgePoints(const std::vector<const Edge*>& edges);
  void MergeInto(int keep_root, int other_root, const Mat3& other_fix);
  void FullSolve(int root);
  void Densify();
  // Up to M frames of `root`'s component whose footprint overlaps frame `id` most (current transforms), not in
  // `exclude`.
  [[nodiscard]] std::vector<int> OverlapCandidates(int id, int root, const std::unordered_set<int>& exclude);
  void TryRetries(int new_id, const class DescriptorIndex& index, const Features& feats);
  // Tries to join `other` (a frame of another component) to the new frame; merges the components on success.
  bool TryJoin(int new_id, int other, const DescriptorIndex& index, const Features& feats);
  void Bridge(int new_id, const DescriptorIndex& index, const Features& feats);
  void UpdatePreview(int id, const cv::Mat& work_bgr);
  // Whether frame `id` adds new ground to the relocalisation index (see GlobalIndexOptions::keyframe_spacing).
  [[nodiscard]] bool IsNewGround(int id);
  // Puts frame `id` in the footprint grid where mosaic_from_work_ places it now (after every change of its map).
  void Place(int id);
  [[nodiscard]] bool WriteOutputs(const std::vector<int>& component, std::string* error);
  // Fits the georeference to the component's frame centres and EXIF GPS; when it succeeds the canvas is placed again
  // through `place` turned north-up (canvas_from_original updated), so that mosaic.tif needs no warp.
  [[nodiscard]] GeorefFit GeorefCanvas(const std::vector<int>& component, std::vector<Mat3>* canvas_from_original,
                                       const std::function<void(const Mat3&)>& place);
  // mosaic.tiled.tif -> COG mosaic.tif, then mosaic.kmz, tiles/, index.html. Returns the report's "products" block.
  [[nodiscard]] nlohmann::json MakeProducts(const std::vector<int>& component,
                                            const std::vector<Mat3>& canvas_from_original, bool have_tiff);
  [[nodiscard]] nlohmann::json GeorefJson() const;

  PipelineOptions options_;
  SessionPaths paths_;
  SiftExtractor extractor_;
  FeatureStore feature_store_;
  GlobalIndex global_index_;
  size_t frames_not_indexed_ = 0;  // registered over ground the index already has
  MatchGraph graph_;
  EdgeStore edge_store_;
  SessionJournal journal_;
  size_t resumed_frames_ = 0;
  int fds_at_start_ = -1;       // open file descriptors when the flight began and when it ended: a long flight must
  int fds_at_flight_end_ = -1;  // not leak any  // frames taken from the journal of an interrupted run
  size_t release_cursor_ = 0;   // edges before it have been considered by ReleaseColdEdges
  size_t edges_released_ = 0;   // edges whose points went to disk during the flight
  size_t edge_bytes_released_ = 0;
  size_t edges_reloaded_ = 0;  // points read back during the flight (a solve needed a cold edge)
  Components components_;
  FootprintGrid footprints_;       // in_graph frames' footprints, for overlap candidates and new-ground checks
  std::deque<FrameState> frames_;  // grows chunk by chunk: no doubling copy in a long flight
  std::vector<std::vector<size_t>> adjacency_;      // edge indices per frame
  std::unordered_map<int, Mat3> mosaic_from_work_;  // per frame, in its component's coordinates
  std::deque<std::pair<int, int>> retry_;           // (frame id, attempts)
  std::vector<SkippedInput> skipped_;
  LivePreview preview_;
  GeorefFit georef_;
  std::function<void(std::shared_ptr<const std::string>)> preview_listener_;
  double georef_rotation_removed_deg_ = 0;
  int georef_gps_frames_ = 0;
  StageStats stats_;
  int best_inliers_ = 0;
  int registered_since_full_ = 0;
  size_t dropped_frames_ = 0;
  hal::CaptureCounters capture_;
  std::string storage_failure_;
  int relocalized_ = 0;
  int retried_ok_ = 0;
  int merges_ = 0;
  int num_components_ = 0;
  int densified_edges_ = 0;
  int64_t start_ns_ = 0;
  int final_registered_ = 0;
  double final_rms_ = 0.0;
  double residual_median_ = 0.0;
  RefineResult refine_;
  MemoryPlan memory_plan_;
  double flight_peak_rss_mib_ = 0.0;   // peak RSS when the last frame was registered
  double flight_end_rss_mib_ = 0.0;    // RSS then
  double solve_peak_rss_mib_ = 0.0;    // peak of the end-of-flight solves (from flight end)
  double compose_peak_rss_mib_ = 0.0;  // peak of writing the session files and the mosaic (from the solves' end)
  HeapStats flight_end_heap_;
  MotionModel refined_model_ = MotionModel::kAffine;
  TransferStats holdout_linear_;  // held-out correspondences under the linear solution, then the final one
  TransferStats holdout_final_;
  TransferStats holdout_inliers_;  // of those, the ones within refine.outlier_px
  double composite_ms_ = 0.0;
};

}  // namespace uavm
