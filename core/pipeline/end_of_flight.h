#pragma once
#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "core/georef/products.h"
#include "core/mosaic/compositor.h"
#include "core/pipeline/canvas_load.h"
#include "core/pipeline/canvas_placement.h"
#include "core/pipeline/end_radiometry.h"
#include "core/pipeline/flight_record.h"
#include "core/pipeline/options.h"
#include "core/pipeline/work_lens.h"
#include "core/session/session_dir.h"
#include "core/util/id_set.h"

namespace uavm {

// The session's side of the end of the flight (FlightSession; a fake in tests): the memory phases, the
// registration's own tables (its edges' points are the session's) and its keys of report.json.
class SessionEnd {
 public:
  virtual ~SessionEnd() = default;
  virtual void EnterPhase(const std::string& name) = 0;
  virtual void ComposeEnd() = 0;
  [[nodiscard]] virtual bool WriteEdgeTables(const IdSet& in_component, std::string* error) = 0;
  // Once the tables are written nothing reads the edge records again: they are freed and their pages given back.
  virtual void DropEdgeRecords() = 0;
  [[nodiscard]] virtual nlohmann::json Report(const Solution& solution, const CompositeResult& composite) const = 0;
};

// What the end of the flight tells the live view (LiveView), which keeps serving the map: the final tiles on its
// grid's zooms, the final tiles themselves (null: none were made), the last live.jpg, and report.json "live_tiles".
class FinalMapListener {
 public:
  virtual ~FinalMapListener() = default;
  [[nodiscard]] virtual TileOptions FinalTileOptions(bool georeferenced) const = 0;
  virtual void FinalTiles(const TileSet* tiles, int frames) = 0;
  virtual void WriteLastPreview() = 0;
  [[nodiscard]] virtual nlohmann::json Report() const = 0;
};

// What the program adds to the session's outputs from units outside core (e.g. hal's telemetry): keys of
// report.json, and of config.yaml (YAML text appended to core's).
struct OutputAdditions {
  nlohmann::json report_sections = nlohmann::json::object();
  std::string config_yaml;
};

// The end of the flight after the engine's solve: record + solution + options -> the session's outputs. In order:
// radiometry (gains and vignetting), the canvas (placement, georeference, bridging), the tables (transforms.csv,
// graph.csv, correspondences.csv, frames.csv, camera.yaml, config.yaml), the mosaic (mosaic.tiled.tif, mosaic.png),
// the products (COG mosaic.tif, tiles/, mosaic.kmz, index.html) and report.json. Needs no flight: a record and a
// solution are enough (tests make them).
class EndOfFlight {
 public:
  struct Inputs {
    const FlightRecord* record = nullptr;  // required
    const Solution* solution = nullptr;    // required, ok
    const WorkLens* lens = nullptr;        // required
    SessionEnd* session = nullptr;         // required
    FinalMapListener* live = nullptr;      // may be null (no live view)
    OutputAdditions additions;
  };
  // Borrows what `inputs` points to, which must outlive Run().
  EndOfFlight(const PipelineOptions& options, SessionPaths paths, Inputs inputs);

  // False on an output failure (message in `error`).
  [[nodiscard]] bool Run(std::string* error);

 private:
  // The solved component's frames (the live tiles' final count).
  [[nodiscard]] int SolvedFrames() const { return static_cast<int>(in_.solution->component.size()); }
  [[nodiscard]] bool WriteTables(std::string* error);
  [[nodiscard]] bool CompositeMosaic(CompositeResult* composite, std::string* error);
  // The frame's heading in the registration (the radiometry's hotspot turns with it).
  [[nodiscard]] double HeadingOf(int id) const;
  // Part `need` of frame `id`'s ideal (undistorted) image on the load's grid.
  [[nodiscard]] FramePart LoadIdealPart(int id, const CanvasLoad& how, const cv::Rect& need) const;
  // mosaic.tiled.tif -> COG mosaic.tif, then mosaic.kmz, tiles/, index.html. Returns the report's "products" block.
  [[nodiscard]] nlohmann::json MakeProducts();
  [[nodiscard]] bool WriteMapPage(const TileSet& tiles) const;
  [[nodiscard]] bool WriteReport(const CompositeResult& composite, nlohmann::json products, std::string* error) const;

  const PipelineOptions& options_;  // borrowed
  SessionPaths paths_;
  Inputs in_;
  EndRadiometry radiometry_;
  CanvasPlacement placement_;
  // The match graph as index.html draws it, kept from the edge records before they are dropped (16 bytes an edge).
  std::vector<MapEdge> map_edges_;
};

}  // namespace uavm
