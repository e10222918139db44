#pragma once
#include <cstdint>
#include <deque>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <unordered_map>
#include <unordered_set>
#include <utility>
#include <vector>

#include "core/adjust/affine_adjuster.h"
#include "core/adjust/global_refiner.h"
#include "core/adjust/lens_calibration.h"
#include "core/features/sift.h"
#include "core/geometry/footprint_grid.h"
#include "core/graph/components.h"
#include "core/graph/match_graph.h"
#include "core/matching/global_index.h"
#include "core/matching/pair_matcher.h"
#include "core/matching/subpixel_refiner.h"
#include "core/util/clock.h"

namespace uavm {

// What the engine needs of the frames it registers. Defaults are the onboard program's (core/pipeline/options.h maps
// its flat YAML keys onto these).
struct RegistrationOptions {
  int recent_candidates = 2;               // K: the last K frames in the graph are always candidates
  int overlap_candidates = 3;              // M: plus up to M frames whose footprint overlaps the first estimate
  double min_overlap_fraction = 0.15;      // of the new frame's area, for an overlap candidate
  double relative_inlier_fraction = 0.05;  // an edge needs this share of the best pair's inliers (seed method: 5 %)
  int relocalization_candidates = 4;       // global-index look-alikes tried when the recent frames gave nothing
  int bridge_candidates = 2;               // while the flight is in pieces: frames of other components per frame
  int retry_list_size = 16;                // frames that matched nothing, retried against later frames
  int retry_per_frame = 2;
  int retry_max_attempts = 60;
  int full_solve_every = 10;  // full adjustment every max(N, size/20) registered frames, and on a merge
  int solve_window = 300;     // frames those solves move (the newest); 0 = the whole component
  // Points the end-of-flight solves hold (each edge's inliers; held-out points besides, a quarter of it): beyond it,
  // every edge keeps an evenly strided share (at least min_end_points), the rest stays in edges.bin. Set from the
  // memory budget; 0 = every point.
  int end_correspondences = 0;
  int min_end_points = 12;
  MatchOptions matching;
  GlobalIndexOptions relocalization;
  AdjustOptions adjust;
  RefineOptions refine;
  // Self-calibration of the lens at the end of the flight (needs SetCamera()).
  LensCalibrationOptions lens_calibration;
  // Edges' points refined at the working resolution (SetRefiner; the product keeps the images).
  SubpixelOptions subpixel;

  [[nodiscard]] bool Check(std::string* why) const;
};

// Earlier frames' features, borrowed by the engine for each candidate pair (the product keeps them in a bounded
// cache over the session's features/; tests in a map). Null when a frame's features cannot be had.
class FeatureProvider {
 public:
  virtual ~FeatureProvider() = default;
  [[nodiscard]] virtual std::shared_ptr<const Features> Get(int id) = 0;
  // As Get, once ReleaseAll() was called: read for one use, not kept (the end of the flight's memory is the solves').
  [[nodiscard]] virtual std::shared_ptr<const Features> Load(int id) { return Get(id); }
  // Called once no more features will be asked for (end of flight): their memory can go.
  virtual void ReleaseAll() {}
};

// Where an edge's points go once its frames leave the solve window, so that memory stays flat in a long flight
// (edges.bin in the product). Without one, every edge keeps its points in memory.
class EdgeSpill {
 public:
  virtual ~EdgeSpill() = default;
  [[nodiscard]] virtual bool Append(Edge* edge, std::string* error) = 0;  // keeps the points resident
  [[nodiscard]] virtual bool Load(Edge* edge, std::string* error) = 0;    // makes them resident again
  virtual size_t Release(Edge* edge) = 0;                                 // bytes given back (0 if not stored)
};

// Outcome of one frame.
enum class FrameOutcome { kRegistered, kNewComponent, kFailed };

// The engine's record of one frame (ids are dense, 0..frames()-1, in arrival order).
struct FrameRecord {
  cv::Size work_size;
  double half_diagonal = 1.0;
  bool has_features = false;
  bool in_graph = false;  // has at least one edge or anchors its own component
  bool keyframe = false;  // in the global (relocalisation) index
  std::string failure;    // why it is not registered (so far)
};

// What the engine did during the flight (report.json), counted, never scanned for.
struct RegistrationCounters {
  int relocalized = 0;
  int joined_on_retry = 0;
  int component_merges = 0;
  int components = 0;  // during the flight
  int edges_added_at_end = 0;
  size_t frames_not_indexed = 0;  // registered over ground the index already has
  size_t edges_released = 0;      // edges whose points were given to the spill during the flight
  size_t edge_bytes_released = 0;
  size_t edges_reloaded = 0;       // points taken back during the flight (a solve needed a cold edge)
  size_t end_points_thinned = 0;   // points the end-of-flight solves left in edges.bin (end_correspondences)
  size_t end_points_per_edge = 0;  // at most, then; 0 = all
  int relocalization_thinnings = 0;
  int joined_where_telemetry_placed = 0;  // frames whose first match came from a PositionHint's candidates
};

// The end-of-flight solution: the largest component solved and refined.
struct Solution {
  bool ok = false;
  std::string failure;
  std::vector<int> component;  // ascending; the first is the reference (identity)
  // The flight's other image-linked pieces (largest first, members ascending), each in its own coordinates
  // (mosaic_from_work of its members; not solved again): what bridging by telemetry may place.
  std::vector<std::vector<int>> other_components;
  double rms_px = 0.0;
  double median_px = 0.0;
  RefineResult refine;
  MotionModel model = MotionModel::kAffine;
  // With refine.choose_model: the held-out RMS of the model not kept (0: only one was refined).
  double holdout_other_model_rms = 0.0;
  TransferStats holdout_linear;  // held-out correspondences under the linear solution, then the final one
  TransferStats holdout_final;
  TransferStats holdout_inliers;  // of those, the ones within refine.outlier_px
  double adjust_ms = 0.0;         // from the start of Finish() to the linear solution
  double refine_ms = 0.0;
  // The lens's self-calibration; when accepted, every edge's points and the maps are in its ideal pixels.
  LensCalibration lens;
};

// The frames the end of the flight calibrates the lens on (the anchor and the variable ones) and the edges among them.
struct LensWindow {
  std::vector<const Edge*> edges;
  std::unordered_set<int> variable;
  int anchor = -1;
};

// Where telemetry says a new frame is: its centre in the mosaic coordinates of the component holding frame `anchor`
// (e.g. its GPS position through the live georeference). When the recent frames fail (a gap, a turn), the frames
// around that point are tried before the relocalisation index.
struct PositionHint {
  int anchor = -1;
  Vec2 centre = Vec2::Zero();
};

// Per-frame timings of Register(), for the stage statistics.
struct RegisterTiming {
  double matching_ms = 0.0;
  double adjust_ms = 0.0;
};

// Pose-free registration of a stream of frames: features in, maps (mosaic_from_work per frame) and edges out. Each
// frame is matched against a bounded candidate set (the last K frames in the graph, the relocalisation index when
// those fail, the M frames whose footprints overlap its first estimate), verified by RANSAC, solved locally, and every
// few frames in a windowed full adjustment; frames that matched nothing are retried, pieces of the flight bridged.
// Finish() keeps the largest component and solves it fully. Knows nothing of session files, reports or products.
//
// Per-frame cost does not grow with the flight: candidates come from a footprint grid, component membership is kept
// incrementally, a full solve moves at most solve_window frames and reads only the edges touching them.
class RegistrationEngine {
 public:
  // Borrows `features` (required) and `spill` (may be null); both must outlive the engine. Throws
  // std::invalid_argument on options that fail Check() (start-up only).
  RegistrationEngine(const RegistrationOptions& options, FeatureProvider* features, EdgeSpill* spill);

  // A new frame of `work_size` pixels; returns its id. It takes part once Register() is called for it.
  int AddFrame(cv::Size work_size);
  // Registers frame `id` (the newest) with its features (descriptors as the provider will give them later).
  // `hint`: where telemetry places it (may be null).
  [[nodiscard]] FrameOutcome Register(int id, const Features& features, RegisterTiming* timing = nullptr,
                                      const PositionHint* hint = nullptr);
  // The camera the frames' features were made ideal with (work pixels; every frame of that size): what the end of
  // the flight calibrates the lens from. Without one, the lens is not calibrated.
  // `verified`: the lens is the operator's (configured); a database lens is not, and is dropped (the recorded pixels
  // used) when the end of the flight cannot solve with it and its self-calibration.
  void SetCamera(const PinholeCamera& work_camera, bool verified) {
    camera_ = work_camera;
    camera_verified_ = verified;
  }
  [[nodiscard]] bool has_camera() const { return camera_.has_value(); }
  // Refines every new edge's points at the working resolution where it holds both frames' images (borrowed, may be
  // null; must outlive the engine).
  void SetRefiner(SubpixelRefiner* refiner) { refiner_ = refiner; }
  // Frame `id` will not be registered (e.g. it could not be stored); `why` ends in the report.
  void SetFailure(int id, std::string why);
  // Final solve of the largest component; the features are not needed afterwards. `enter_phase` (may be empty) hears
  // each of its steps begin ("end_match", "end_load", "adjust", "lens", "refine"), e.g. for a MemoryWatch.
  using PhaseListener = std::function<void(const std::string&)>;
  [[nodiscard]] Solution Finish(const PhaseListener& enter_phase = {});

  [[nodiscard]] int frames() const { return static_cast<int>(frames_.size()); }
  [[nodiscard]] const FrameRecord& frame(int id) const { return frames_.at(static_cast<size_t>(id)); }
  // Frame `id`'s map into its component's mosaic (after Finish(): the reference frame's, for the component).
  [[nodiscard]] const Mat3& mosaic_from_work(int id) const { return mosaic_from_work_.at(id); }
  [[nodiscard]] bool placed(int id) const { return mosaic_from_work_.count(id) != 0; }
  // Frame `id`'s component during the flight (its root: frames of one component share it) and that component's size.
  [[nodiscard]] int ComponentOf(int id) const { return components_.Find(id); }
  [[nodiscard]] int ComponentSize(int id) const { return components_.SizeOf(id); }
  // The frames of the component rooted at `root`, ascending.
  [[nodiscard]] const std::vector<int>& MembersOf(int root) const;
  // Frames placed or moved (a solve, a merge) since the last call, for a follower such as the live tiles; only
  // recorded after TrackMoves(true), so that nobody's unread log grows.
  void TrackMoves(bool on) { track_moves_ = on; }
  [[nodiscard]] std::vector<int> TakeMoved() { return std::exchange(moved_, {}); }
  [[nodiscard]] const std::deque<Edge>& edges() const { return graph_.edges(); }
  // For writers after Finish(): they load an edge's points through the spill, AsSolved(), and give them back.
  [[nodiscard]] std::deque<Edge>& mutable_edges() { return graph_.mutable_edges(); }
  // Frees the edge records and the frames' edge lists once nothing reads them again (the end of the flight, after its
  // tables): a 128-byte record and two adjacency entries an edge, 3-4 MiB at 5000 frames, that compositing can use.
  // edges() is empty after.
  void ReleaseEdgeRecords() {
    graph_.ReleaseEdges();
    std::vector<std::vector<uint32_t>>().swap(adjacency_);
  }
  // An edge read back from the spill after Finish(), in the pixels of the final solution (the self-calibrated lens's
  // ideal pixels when it was accepted or the prepared lens dropped; else as stored).
  void AsSolved(Edge* edge) const;
  // Whether an edge is one of the final solution's (both frames in `component`, inliers above both thresholds).
  [[nodiscard]] bool EdgeCounts(const Edge& e) const {
    return graph_.EdgeCounts(e, options_.relative_inlier_fraction, options_.matching.min_inliers);
  }
  [[nodiscard]] RegistrationCounters counters() const;
  [[nodiscard]] int best_inliers() const { return best_inliers_; }
  [[nodiscard]] const RegistrationOptions& options() const { return options_; }

 private:
  struct Candidates;

  [[nodiscard]] FrameRecord& Record(int id) { return frames_.at(static_cast<size_t>(id)); }
  // Checked access to a placed frame's map; SetMap() places a frame (or moves it).
  [[nodiscard]] Mat3& Map(int id) { return mosaic_from_work_.at(id); }
  void SetMap(int id, const Mat3& m) { mosaic_from_work_.insert_or_assign(id, m); }
  [[nodiscard]] std::vector<const Edge*> EdgesTouching(const std::unordered_set<int>& ids, int root);
  void AddEdge(Edge edge);
  void ReleaseColdEdges();
  // Makes `edges`' points resident, thinned to max_points / max_holdout (0: all); the pairs thinned are added to
  // `dropped` when given. False when some could not be read (the others are loaded).
  bool LoadEdgePoints(const std::vector<const Edge*>& edges, size_t max_points = 0, size_t max_holdout = 0,
                      size_t* dropped = nullptr);
  // Gives every edge's points back to the spill (after the final solves; writers reload them one by one).
  void ReleaseAllEdges();
  [[nodiscard]] std::pair<size_t, size_t> EndPointsPerEdge(const std::vector<const Edge*>& edges) const;
  void MergeInto(int keep_root, int other_root, const Mat3& other_fix);
  void FullSolve(int root);
  void Densify();
  [[nodiscard]] bool Acceptable(const PairResult& r) const;
  // The edge of a verified pair, its points refined when the refiner can.
  [[nodiscard]] Edge MakeEdge(int src, int tgt, PairResult&& r);
  void TryCandidate(int cand, Candidates* c);
  // Map(id) if the flight keeps the motion between its two previous frames; empty when they are not both placed.
  [[nodiscard]] std::optional<Mat3> PredictFromMotion(int id);
  void FindCandidates(int id, Candidates* c);
  void TryWhereTelemetryPlaces(int id, Candidates* c);
  void Join(int id, Candidates* c);
  void StartComponent(int id, const Candidates& c);
  [[nodiscard]] std::vector<int> OverlapCandidates(int id, int root, const std::unordered_set<int>& exclude);
  void TryRetries(int new_id, const DescriptorIndex& index, const Features& feats);
  bool TryJoin(int new_id, int other, const DescriptorIndex& index, const Features& feats);
  void Bridge(int new_id, const DescriptorIndex& index, const Features& feats);
  [[nodiscard]] bool IsNewGround(int id);
  void Place(int id);
  [[nodiscard]] Solution FinishSolve();
  // The final solves over `edges`, whose points come from `points` (null: the edges' own).
  void SolveFinal(const std::vector<const Edge*>& edges, EdgePointSource* points, const StageTimer& since_finish,
                  Solution* s);
  RefineResult RefineAndChooseModel(const std::vector<const Edge*>& edges, EdgePointSource* points,
                                    const std::unordered_set<int>& variable, int anchor,
                                    const std::unordered_map<int, double>& half_diag, Solution* s);
  void EnterPhase(const char* name) const {
    if (enter_phase_) enter_phase_(name);
  }
  // After the linear solve: the lens self-calibration; when accepted, the edges' points move to its ideal pixels and
  // the linear solve runs again on them. False when that solve fails.
  [[nodiscard]] bool CalibrateLensAndResolve(const std::vector<const Edge*>& edges, EdgePointSource* points,
                                             const std::unordered_set<int>& variable,
                                             const std::unordered_map<int, double>& half_diag, AdjustResult* linear,
                                             Solution* s);

  // The pairs of `edges` matched again with every keypoint at `lens`'s ideal pixels (RANSAC judges them under the
  // lens); their points are replaced, at `lens`'s ideal pixels, when the pair verifies (`at_lens`[i] set for edges[i]).
  // Returns how many were.
  [[nodiscard]] size_t RematchUnderLens(const std::vector<const Edge*>& edges, const LensDistortion& lens,
                                        std::vector<char>* at_lens);
  // After an accepted lens: its pairs matched again under it, then a correction of it estimated on their points at
  // its ideal pixels, composed with it when the held-out points agree better. `resident`: the camera at whose ideal
  // pixels the edges' resident points are (the prepared one, or no lens once the prepared lens was dropped).
  void CorrectLensAfterRematch(const std::vector<const Edge*>& edges, const std::unordered_set<int>& variable,
                               int anchor, const std::unordered_map<int, double>& half_diag,
                               const PinholeCamera& resident, LensCalibration* lens);
  // After the correction: the edges keep the rematched points or get the flight's (`own`) back.
  void KeepBetterPoints(const std::vector<const Edge*>& edges, std::vector<Edge>* own,
                        const std::unordered_set<int>& variable, int anchor,
                        const std::unordered_map<int, double>& half_diag, const PinholeCamera& resident,
                        LensCalibration* lens);
  // After an accepted lens: (with lens_calibration.rematch) its window's pairs matched again and the lens corrected,
  // then the edges' points moved to its ideal pixels and solved linearly.
  [[nodiscard]] bool ResolveAtAcceptedLens(const std::vector<const Edge*>& edges, EdgePointSource* points,
                                           const LensWindow& w, const PinholeCamera& resident,
                                           const std::unordered_set<int>& variable,
                                           const std::unordered_map<int, double>& half_diag, AdjustResult* linear,
                                           Solution* s);
  // The edges' points moved from `resident`'s ideal pixels to `lens`'s (the resident ones now, the others as they are
  // read), and the linear solve run again on them. False when it fails.
  [[nodiscard]] bool ResolveAtLens(const std::vector<const Edge*>& edges, EdgePointSource* points,
                                   const PinholeCamera& resident, const LensDistortion& lens,
                                   const std::unordered_set<int>& variable,
                                   const std::unordered_map<int, double>& half_diag, AdjustResult* linear, Solution* s);

  RegistrationOptions options_;
  std::optional<PinholeCamera> camera_;  // SetCamera()
  bool camera_verified_ = false;
  FeatureProvider* features_;           // borrowed
  SubpixelRefiner* refiner_ = nullptr;  // borrowed, may be null
  EdgeSpill* spill_;                    // borrowed, may be null
  GlobalIndex global_index_;
  MatchGraph graph_;
  // Mutable: a lookup compresses the union-find's paths (the flight's followers read components through a const view).
  mutable Components components_;
  FootprintGrid footprints_;        // in_graph frames' footprints, for overlap candidates and new-ground checks
  std::deque<FrameRecord> frames_;  // grows chunk by chunk: no doubling copy in a long flight
  std::vector<std::vector<uint32_t>> adjacency_;  // edge indices per frame (4 bytes: a flight has < 4e9 edges)
  bool track_moves_ = false;
  std::vector<int> moved_;
  std::unordered_map<int, Mat3> mosaic_from_work_;  // per placed frame, in its component's coordinates
  std::deque<std::pair<int, int>> retry_;           // (frame id, attempts)
  RegistrationCounters counters_;
  int best_inliers_ = 0;
  int registered_since_full_ = 0;
  size_t release_cursor_ = 0;  // edges before it have been considered by ReleaseColdEdges
  PhaseListener enter_phase_;  // during Finish() only
  bool thinned_ = false;       // the end's solves held a share of some edges' points (end_correspondences)
  std::optional<LensDistortion> solved_lens_;  // the lens the final solves moved the edges' points to
};

}  // namespace uavm
