#pragma once
#include <functional>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "core/georef/georef.h"
#include "core/georef/live_georef.h"
#include "core/mosaic/live_preview.h"
#include "core/pipeline/end_of_flight.h"
#include "core/pipeline/flight_session.h"
#include "core/pipeline/live_tiles.h"
#include "core/radiometry/radiometry.h"
#include "core/util/signal.h"
#include "core/util/stats.h"

namespace uavm {

// What the flight shows of itself while it flies: the live preview (live.jpg and its georeference sidecars), the live
// georeference (and the position hints it gives the registration), the live vignetting correction and the live tile
// pyramid. A follower of the FlightSession (Follow): it reads the flight through its record and hears each frame.
class LiveView final : public FinalMapListener {
 public:
  // Borrows `record`, `lens` and `stats` (the session's; the view adds its stages to it).
  LiveView(const PipelineOptions& options, SessionPaths paths, const FlightRecord* record, const WorkLens* lens,
           StageStats* stats);
  ~LiveView() override;
  LiveView(const LiveView&) = delete;
  LiveView& operator=(const LiveView&) = delete;

  // Hears `session`'s frames and answers its hint requests until the view goes (the connections are its own). Once
  // per session: a second call would hear every frame twice.
  void Follow(FlightSession* session);
  void FrameRegistered(const RegisteredFrame& frame);
  // Where the frame's position puts it on the live georeference, for the engine's candidates when the recent frames
  // fail; none before a fit.
  [[nodiscard]] std::optional<PositionHint> HintFor(const FrameMetadata& metadata) const;

  // Each new live.jpg's bytes and its georeference (LiveGeorefView::ToJson), from the frame loop; must not block.
  using PreviewSlot =
      std::function<void(std::shared_ptr<const std::string> jpeg, std::shared_ptr<const nlohmann::json> georef)>;
  [[nodiscard]] Connection OnPreview(PreviewSlot slot) { return preview_published_.Connect(std::move(slot)); }
  // The live tiles' state after each batch (their worker) and the newest frames' outlines as GeoJSON (with each
  // live.jpg); both must not block. Never called unless live_tiles.enabled.
  [[nodiscard]] Connection OnTiles(std::function<void(std::shared_ptr<const TileSetInfo>)> slot);
  [[nodiscard]] Connection OnFootprints(std::function<void(std::shared_ptr<const std::string>)> slot);

  // The end of the flight (FinalMapListener), and before its solve: the live tiles' queue given up when final tiles
  // will replace them.
  void StopForFinalTiles();
  [[nodiscard]] TileOptions FinalTileOptions(bool georeferenced) const override;
  void FinalTiles(const TileSet* tiles, int frames) override;
  void WriteLastPreview() override;
  [[nodiscard]] nlohmann::json Report() const override;

 private:
  // The frame as the view draws it: with the vignetting fitted over the recent frames divided out, once there is one.
  [[nodiscard]] cv::Mat CorrectedImage(const RegisteredFrame& frame);
  void UpdatePreview(int id, const cv::Mat& work_bgr);
  void AddGeorefPoint(int id);
  [[nodiscard]] std::shared_ptr<const nlohmann::json> UpdateGeoref();
  void WriteSidecars(const LiveGeorefView& view);

  PipelineOptions options_;
  SessionPaths paths_;
  const FlightRecord* record_;  // borrowed
  StageStats* stats_;           // borrowed
  LivePreview preview_;
  LiveGeoref georef_;
  mutable ProjectedConverter hint_projection_;  // HintFor(): lat/lon -> the live georeference's CRS
  int sidecar_epsg_ = -1;  // the CRS live.jpg.aux.xml names; 0: no sidecars; -1: unknown (a previous run's?)
  std::optional<LiveRadiometry> radiometry_;
  std::unique_ptr<LiveTiles> tiles_;  // null unless live_tiles.enabled
  Signal<std::shared_ptr<const std::string>, std::shared_ptr<const nlohmann::json>> preview_published_;
  std::vector<Connection> following_;  // to the session: dropped first when the view goes
};

}  // namespace uavm
