#pragma once
#include <array>
#include <deque>
#include <memory>
#include <mutex>
#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <string>
#include <unordered_set>
#include <vector>

#include "core/georef/georef.h"
#include "core/georef/live_georef.h"
#include "core/georef/products.h"
#include "core/pipeline/flight_record.h"
#include "core/pipeline/options.h"
#include "core/pipeline/work_lens.h"
#include "core/radiometry/radiometry.h"
#include "core/session/session_dir.h"
#include "core/tiles/live_tile_pyramid.h"
#include "core/tiles/tile_set.h"
#include "core/util/signal.h"

namespace uavm {

// The live tile pyramid during the flight (core/tiles/live_tile_pyramid.h): which grid it is on (local until the live
// georeference holds, then web mercator), which piece of the flight it shows (the largest), each registered frame
// and each frame a solve moved handed to its worker, the frame footprints for the live page, and at the end the
// switch to the end-of-flight tiles/. Reads the flight through its record and the live georeference (both borrowed).
class LiveTiles {
 public:
  LiveTiles(const PipelineOptions& options, SessionPaths paths, const FlightRecord* record, const WorkLens* lens,
            const LiveGeoref* georef);
  ~LiveTiles();
  LiveTiles(const LiveTiles&) = delete;
  LiveTiles& operator=(const LiveTiles&) = delete;

  // Frame `id` registered (its ideal working copy `work_bgr`); `moved`: frames a solve or a merge moved meanwhile.
  void Update(int id, const cv::Mat& work_bgr, const std::vector<int>& moved);
  // The live radiometry from now on (frames redrawn from frames/ are corrected with it; new frames come corrected).
  void SetRadiometry(std::shared_ptr<const RadiometryModel> model);
  // The newest frames' outlines as GeoJSON to the footprint subscribers (with each live.jpg).
  void PublishFootprints();

  // The state after each batch of tiles (called on the pyramid's worker) and the footprints; both must not block.
  [[nodiscard]] Connection OnTiles(std::function<void(std::shared_ptr<const TileSetInfo>)> slot) {
    return tiles_published_.Connect(std::move(slot));
  }
  [[nodiscard]] Connection OnFootprints(std::function<void(std::shared_ptr<const std::string>)> slot) {
    return footprints_published_.Connect(std::move(slot));
  }

  // The end of the flight: the queue given up when final tiles will replace the live ones; their options on the live
  // grid's zooms (so that a client keeps its URLs); the worker stopped, the report written and the server handed the
  // final tiles (null: none were made, the live pyramid stays the map served).
  void StopForFinalTiles();
  [[nodiscard]] TileOptions FinalTileOptions(bool georeferenced) const;
  void Finish(const TileSet* final_tiles, int frames);
  [[nodiscard]] const nlohmann::json& report() const { return report_; }

 private:
  // Which grid the pyramid draws on and what it has drawn.
  struct Grid {
    bool started = false;
    TileGrid grid;
    int anchor = -1;  // a frame of the piece shown (its component's root changes with merges)
    // Geographic: the live georeference the tiles were drawn with and lat/lon from its CRS.
    int refits_seen = -1;
    GeorefFit fit;
    mutable ProjectedConverter to_latlon;  // mutable: GridFromWork (const) converts through it
    Vec2 local_offset = Vec2::Zero();      // local: max_zoom pixels = mosaic pixels + offset
    cv::Rect2d drawn_mosaic;               // what has been drawn, mosaic pixels (the refit's shift is measured on it)
    std::unordered_set<int> drawn;
    std::deque<std::pair<int, std::array<Vec2, 4>>> outlines;  // max_zoom pixels, newest last
  };

  [[nodiscard]] const RegistrationEngine& engine() const { return record_->engine(); }
  [[nodiscard]] bool GridStale(int id);
  [[nodiscard]] bool StartGrid(int id);
  [[nodiscard]] double TilesGsd(int id) const;
  [[nodiscard]] Mat3 GridFromWork(int id) const;  // zero when it cannot be computed
  void Draw(int id, std::shared_ptr<const cv::Mat> image);

  PipelineOptions options_;
  SessionPaths paths_;
  const FlightRecord* record_;  // borrowed
  const LiveGeoref* georef_;    // borrowed
  Grid grid_;
  nlohmann::json report_ = {{"enabled", false}};
  Signal<std::shared_ptr<const TileSetInfo>> tiles_published_;
  Signal<std::shared_ptr<const std::string>> footprints_published_;
  // The live radiometry (LiveView's, replaced at each fit): frames read back from frames/ are corrected like new ones.
  mutable std::mutex radiometry_mutex_;
  std::shared_ptr<const RadiometryModel> radiometry_;
  std::unique_ptr<LiveTilePyramid> pyramid_;  // its worker publishes through tiles_published_; stopped first
};

}  // namespace uavm
