#pragma once
#include <deque>
#include <functional>
#include <memory>
#include <mutex>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <unordered_map>
#include <unordered_set>
#include <vector>

#include "core/frame/frame.h"
#include "core/georef/live_georef.h"
#include "core/lens/camera_setup.h"
#include "core/mosaic/live_preview.h"
#include "core/pipeline/canvas_load.h"
#include "core/pipeline/memory_budget.h"
#include "core/pipeline/options.h"
#include "core/pipeline/resource_log.h"
#include "core/registration/registration_engine.h"
#include "core/session/edge_store.h"
#include "core/session/feature_store.h"
#include "core/session/journal.h"
#include "core/session/session_dir.h"
#include "core/tiles/live_tile_pyramid.h"
#include "core/util/memory.h"
#include "core/util/stats.h"

namespace uavm {

struct SkippedInput {
  std::string file;
  std::string reason;
};

// The onboard session around the registration engine: each frame is prepared (working copy, features), stored in the
// session (frames/, features/, journal) and handed to the RegistrationEngine; the live preview follows. Finish() has
// the engine solve the largest component, then writes the session files, composites the mosaic and makes the
// products and the report.
class Mosaicker {
 public:
  Mosaicker(const PipelineOptions& options, SessionPaths paths);
  ~Mosaicker();

  // A frame made ready for registration: working copy and features. Prepare() touches no Mosaicker state, so the
  // load and detect threads run it while the previous frame is being matched (PrepareImages, then DetectFeatures).
  struct Prepared {
    Frame frame;
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
  [[nodiscard]] Prepared Prepare(Frame frame) const;        // PrepareImages, then DetectFeatures
  [[nodiscard]] Prepared PrepareImages(Frame frame) const;  // working copies, no features
  // The features of a frame PrepareImages made (a stage of its own: the next frame's decode overlaps this one's SIFT).
  void DetectFeatures(Prepared* p) const;
  // The working grey image the features' coordinates refer to (undistorted when a lens is corrected).
  [[nodiscard]] cv::Mat IdealGray(const Prepared& p) const;
  // A frame of the journal being resumed: `frame` decoded from frames/, features read from features/ (computed again
  // only if their file is unreadable). AddFrame then registers it exactly as the interrupted run did.
  [[nodiscard]] Prepared PrepareStored(Frame frame, int id, const std::string& stored_name) const;
  // Starts the session journal (journal.jsonl): new, or appended after `valid_bytes` of a resumed one.
  [[nodiscard]] bool StartJournal(bool append, uint64_t valid_bytes, std::string* error);
  [[nodiscard]] FrameOutcome AddFrame(Prepared prepared);
  [[nodiscard]] FrameOutcome AddFrame(Frame frame) { return AddFrame(Prepare(std::move(frame))); }
  // An input the source could not turn into a frame (corrupt, empty, not an image).
  void RecordSkipped(const std::string& file, const std::string& reason, bool journal = true);
  void RecordDropped(size_t count) { dropped_frames_ = count; }
  // A live camera's counters (captured, dropped in its own queue, driver gaps, reconnects): report.json "camera".
  void RecordCapture(const CaptureCounters& counters) { capture_ = counters; }
  // A section of report.json that a unit around the pipeline fills (e.g. "telemetry"); replaces one of that name.
  void SetReportSection(const std::string& key, nlohmann::json value) { report_sections_[key] = std::move(value); }
  // The memory plan the options were sized with (reported in report.json).
  void SetMemoryPlan(const MemoryPlan& plan) { memory_plan_ = plan; }
  // Final solve, session files and mosaic. Returns false on an output failure (message in `error`).
  [[nodiscard]] bool Finish(std::string* error);

  [[nodiscard]] size_t frames_in() const { return frames_.size(); }
  [[nodiscard]] int registered_count() const { return final_registered_; }
  // Why the session could not store an accepted frame (disk full, storage gone); empty while all is well. Once set,
  // the caller stops taking frames: what is already in the session stays whole and a resumed run continues it.
  [[nodiscard]] const std::string& storage_failure() const { return storage_failure_; }
  [[nodiscard]] double residual_rms_px() const { return solution_.rms_px; }
  [[nodiscard]] const StageStats& stage_stats() const { return stats_; }

  // Called from the frame loop with each new live.jpg's bytes and its georeference (LiveGeorefView::ToJson), e.g. by
  // the live HTTP server; must not block.
  using PreviewListener =
      std::function<void(std::shared_ptr<const std::string> jpeg, std::shared_ptr<const nlohmann::json> georef)>;
  void SetPreviewListener(PreviewListener listener) { preview_listener_ = std::move(listener); }
  // The live tile pyramid's state after each batch of tiles (called on its worker thread) and the newest frames'
  // outlines as GeoJSON (frame loop, with each live.jpg); both must not block. No-op unless live_tiles.enabled.
  using TilesListener = std::function<void(std::shared_ptr<const TileSetInfo>)>;
  using FootprintsListener = std::function<void(std::shared_ptr<const std::string>)>;
  void SetTilesListeners(TilesListener tiles, FootprintsListener footprints);

 private:
  // The session's record of one frame (the engine keeps the registration's, under the same id).
  struct FrameState {
    int id = -1;
    std::string name;
    std::string stored_file;  // path inside the session's frames/
    cv::Size original_size;
    int64_t timestamp_ns = 0;
    Mat3 work_from_original = Mat3::Identity();
    cv::Size work_size;
    FrameMetadata metadata;
  };
  class StoreFeatures;
  class StoreEdges;

  [[nodiscard]] bool StoreFrameBytes(int id, const Frame& frame, const std::vector<uchar>& encoded, FrameState* state,
                                     std::string* error);
  // Stores the frame's bytes and features and journals it; false (frame failed, maybe the storage) otherwise.
  [[nodiscard]] bool StoreFrame(int id, const Prepared& prepared, FrameState* st);
  void UpdatePreview(int id, const cv::Mat& work_bgr);
  // Radiometry (mosaicker_radiometry.cpp): each frame's thumbnail in the session (thumbs/), the gains and vignetting
  // solved over the component's edges at the end of the flight, and report.json's "radiometry".
  // Returns the thumbnail (empty when radiometry is off), which the live view reuses.
  [[nodiscard]] cv::Mat StoreThumbnail(int id, const cv::Mat& work_bgr);
  // The frame as the live view draws it: with the vignetting fitted over the recent frames divided out, once there
  // is one (LiveRadiometry); `edges_before` = the engine's edge count before the frame was registered.
  [[nodiscard]] cv::Mat LiveViewImage(int id, const cv::Mat& work_bgr, const cv::Mat& thumb, size_t edges_before);
  void SolveFrameRadiometry(const std::vector<int>& component);
  [[nodiscard]] nlohmann::json RadiometryJson() const;
  // The lens (mosaicker_lens.cpp). WorkLens: chosen on the first frame (configuration, lensfun's database, none)
  // and the working copies' undistortion; thread-safe (the capture thread prepares). The engine gets the camera on
  // the frame loop. FinalCamera: the calibrated one when the end of the flight accepted a calibration.
  [[nodiscard]] const Undistorter& WorkLens(const Frame& frame, cv::Size work_size) const;
  void HandEngineTheCamera(cv::Size work_size);
  [[nodiscard]] PinholeCamera FinalCamera() const;  // original pixels
  [[nodiscard]] bool WriteCameraYaml(std::string* error) const;
  [[nodiscard]] nlohmann::json LensJson() const;
  // Part `need` of frame `id`'s ideal (undistorted) image on the load's grid.
  [[nodiscard]] FramePart LoadIdealPart(int id, const CanvasLoad& how, const cv::Rect& need) const;
  // Where the frame's position puts it on the live georeference (mosaicker_hint.cpp); none before a fit.
  [[nodiscard]] std::optional<PositionHint> PositionHintFor(const FrameMetadata& metadata) const;
  // The live picture's georeference (mosaicker_live.cpp): a drawn frame's point; after a live.jpg write the refit when
  // due, the sidecars beside live.jpg and the status' "georef".
  void AddLiveGeorefPoint(int id);
  [[nodiscard]] std::shared_ptr<const nlohmann::json> UpdateLiveGeoref();
  void WriteLiveSidecars(const LiveGeorefView& view);
  // The live tile pyramid (mosaicker_tiles.cpp).
  struct LiveTiles;
  void StartLiveTiles();
  void UpdateLiveTiles(int id, const cv::Mat& work_bgr);
  [[nodiscard]] bool TileGridStale(int id);
  [[nodiscard]] bool StartTileGrid(int id);
  [[nodiscard]] double LiveTilesGsd(int id) const;
  [[nodiscard]] Mat3 GridFromWork(int id) const;  // zero when it cannot be computed
  void DrawTile(int id, std::shared_ptr<const cv::Mat> image);
  void PublishLiveFootprints();
  [[nodiscard]] TileOptions FinalTileOptions() const;
  void StopLiveTilesForFinalTiles();
  // Waits for the pyramid, reports it, and hands the tile server the end-of-flight tiles (null: none were written).
  void FinishLiveTiles(const TileSet* final_tiles);
  // Session files, mosaic, products and report of the solved `component` (mosaicker_output.cpp, _report.cpp).
  [[nodiscard]] bool WriteOutputs(const std::vector<int>& component, std::string* error);
  [[nodiscard]] double PlaceCanvas(const std::vector<int>& component, std::vector<Mat3>* canvas_from_original,
                                   cv::Size* canvas);
  [[nodiscard]] bool WriteTransformsCsv(const std::unordered_set<int>& in_component,
                                        const std::vector<Mat3>& canvas_from_original, std::string* error) const;
  [[nodiscard]] bool WriteEdgeTables(const std::unordered_set<int>& in_component, std::string* error);
  [[nodiscard]] bool WriteFramesCsv(const std::unordered_set<int>& in_component, std::string* error) const;
  [[nodiscard]] bool CompositeMosaic(const std::vector<int>& component, const std::vector<Mat3>& canvas_from_original,
                                     cv::Size canvas, double scale, CompositeResult* composite, std::string* error);
  [[nodiscard]] bool WriteReport(const std::vector<int>& component, const CompositeResult& composite, cv::Size canvas,
                                 double scale, nlohmann::json products, std::string* error) const;
  void ReportRegistration(nlohmann::json* report) const;
  [[nodiscard]] nlohmann::json ReportMemory(const CompositeResult& composite) const;
  // Fits the georeference to the component's frame centres and EXIF GPS; when it succeeds the canvas is placed again
  // through `place` turned north-up (canvas_from_original updated), so that mosaic.tif needs no warp.
  [[nodiscard]] GeorefFit GeorefCanvas(const std::vector<int>& component, std::vector<Mat3>* canvas_from_original,
                                       const std::function<void(const Mat3&)>& place);
  // mosaic.tiled.tif -> COG mosaic.tif, then mosaic.kmz, tiles/, index.html. Returns the report's "products" block.
  [[nodiscard]] nlohmann::json MakeProducts(const std::vector<int>& component,
                                            const std::vector<Mat3>& canvas_from_original, bool have_tiff);
  [[nodiscard]] nlohmann::json GeorefJson() const;
  // Bridging (mosaicker_bridge.cpp): frames no image links, placed by telemetry on the georeferenced canvas and
  // appended to `placed`; the canvas grows to hold them.
  void BridgeFrames(std::vector<int>* placed, std::vector<Mat3>* canvas_from_original, cv::Size* canvas);
  [[nodiscard]] std::vector<BridgeFrame> BridgeInputs(const std::vector<int>& placed,
                                                      const std::vector<Mat3>& canvas_from_original, int* candidates);
  [[nodiscard]] bool GrowCanvas(const std::vector<int>& placed, std::vector<Mat3>* canvas_from_original,
                                cv::Size* canvas);
  [[nodiscard]] nlohmann::json BridgeJson(const BridgeResult& r, int candidates) const;

  PipelineOptions options_;
  SessionPaths paths_;
  mutable std::once_flag lens_once_;
  mutable CameraChoice lens_choice_;  // written once, under lens_once_
  mutable Undistorter work_lens_;
  mutable cv::Size lens_original_size_;
  bool engine_has_camera_ = false;
  SiftExtractor extractor_;
  FeatureStore feature_store_;
  EdgeStore edge_store_;
  std::unique_ptr<StoreFeatures> store_features_;  // the engine's views of the two stores
  std::unique_ptr<StoreEdges> store_edges_;
  SubpixelRefiner refiner_;  // before engine_, which borrows it
  RegistrationEngine engine_;
  SessionJournal journal_;
  size_t resumed_frames_ = 0;  // frames taken from the journal of an interrupted run
  ResourceLog resources_;
  std::deque<FrameState> frames_;  // grows chunk by chunk: no doubling copy in a long flight
  std::vector<SkippedInput> skipped_;
  LivePreview preview_;
  GeorefFit georef_;
  std::unordered_set<int> placed_by_telemetry_;  // frames bridging placed (transforms.csv placed_by)
  nlohmann::json bridge_report_ = nlohmann::json::object();
  PreviewListener preview_listener_;
  LiveGeoref live_georef_{LiveGeorefOptions{.fit = options_.georef}};
  mutable ProjectedConverter hint_projection_;  // PositionHintFor(): lat/lon -> the live georeference's CRS
  int live_sidecar_epsg_ = -1;  // the CRS live.jpg.aux.xml names; 0: no sidecars; -1: unknown (a previous run's?)
  double georef_rotation_removed_deg_ = 0;
  int georef_gps_frames_ = 0;
  StageStats stats_;
  size_t dropped_frames_ = 0;
  CaptureCounters capture_;
  std::string storage_failure_;
  int64_t start_ns_ = 0;
  int final_registered_ = 0;
  Solution solution_;
  RadiometryModel radiometry_;
  std::optional<LiveRadiometry> live_radiometry_;
  bool thumbs_dir_made_ = false;  // while the live view (preview or tiles) is on
  double radiometry_ms_ = 0.0;
  MemoryPlan memory_plan_;
  nlohmann::json report_sections_ = nlohmann::json::object();
  std::shared_ptr<LiveTiles> live_tiles_;  // null unless live_tiles.enabled (shared_ptr: LiveTiles is incomplete here)
  nlohmann::json live_tiles_report_ = {{"enabled", false}};
};

}  // namespace uavm
