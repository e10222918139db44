// The end of the flight after the engine's solve: radiometry, canvas, tables, mosaic, products and report.json.
#include "core/pipeline/end_of_flight.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <future>

#include "core/mosaic/gdal_writer.h"
#include "core/pipeline/session_tables.h"
#include "core/util/clock.h"
#include "core/util/id_set.h"
#include "core/util/memory.h"

namespace uavm {

EndOfFlight::EndOfFlight(const PipelineOptions& options, SessionPaths paths, Inputs inputs)
    : options_(options),
      paths_(std::move(paths)),
      in_(std::move(inputs)),
      placement_(options, in_.record, in_.solution) {}

bool EndOfFlight::Run(std::string* error) {
  const std::vector<int>& component = in_.solution->component;
  in_.session->EnterPhase("radiometry");
  radiometry_ = SolveEndRadiometry(*in_.record, component, options_.radiometry, paths_);
  in_.session->EnterPhase("outputs");
  placement_.Place();
  if (!WriteTables(error)) return false;
  CompositeResult composite;
  in_.session->EnterPhase("compose");
  if (!placement_.placed().empty() && !CompositeMosaic(&composite, error)) return false;
  in_.session->EnterPhase("products");
  nlohmann::json products = MakeProducts();
  if (in_.live != nullptr) {
    in_.live->WriteLastPreview();
    in_.live->FinalTiles(nullptr, SolvedFrames());  // when no products were made (no-op after MakeProducts)
  }
  return WriteReport(composite, std::move(products), error);
}

bool EndOfFlight::WriteTables(std::string* error) {
  const std::vector<int>& component = in_.solution->component;
  const IdSet in_component(component);
  const IdSet in_map(placement_.placed());
  const std::string camera_yaml = CameraYaml(*in_.lens, in_.solution->lens);
  const bool written = WriteTransformsCsv(paths_.Join("transforms.csv"), *in_.record, in_map,
                                          placement_.canvas_from_original(), placement_.placed_by_telemetry(), error) &&
                       in_.session->WriteEdgeTables(in_component, error) &&
                       WriteFramesCsv(paths_.Join("frames.csv"), *in_.record, in_map, error) &&
                       (camera_yaml.empty() || WriteFileAtomic(paths_.Join("camera.yaml"), camera_yaml, error)) &&
                       WriteFileAtomic(paths_.Join("config.yaml"), ToYaml(options_) + in_.additions.config_yaml, error);
  if (!written) return false;
  // The edges are in edges.bin and graph.csv now: the map page keeps what it draws of them, and compositing gets the
  // records' memory.
  const RegistrationEngine& engine = in_.record->engine();
  if (options_.write_products) {
    map_edges_.reserve(engine.edges().size());
    for (const Edge& e : engine.edges())
      map_edges_.push_back(
          {e.src, e.tgt, e.num_inliers, in_map.contains(e.src) && in_map.contains(e.tgt) && engine.EdgeCounts(e)});
  }
  in_.session->DropEdgeRecords();
  return true;
}

// The mosaic, tile by tile: mosaic.tiled.tif (MakeProducts() turns it into the COG mosaic.tif) and mosaic.png.
bool EndOfFlight::CompositeMosaic(CompositeResult* composite, std::string* error) {
  const std::vector<Mat3>& canvas_from_original = placement_.canvas_from_original();
  const cv::Size canvas = placement_.canvas();
  const double scale = placement_.scale();
  const GeorefFit& georef = placement_.georef();
  std::vector<CompositeInput> inputs;
  inputs.reserve(placement_.placed().size());
  // By frame id (ids are dense): no node a frame.
  std::vector<CanvasLoad> load_of(in_.record->size());
  for (int id : placement_.placed()) {
    const SessionFrame& f = in_.record->frame(id);
    const Mat3& c = canvas_from_original[static_cast<size_t>(id)];
    // Canvas pixels per original pixel; the frame is loaded at that sampling (never above its own resolution).
    const double local_scale =
        LocalScale(c, Vec2(0.5 * (f.original_size.width - 1), 0.5 * (f.original_size.height - 1)));
    const CanvasLoad how = PlanCanvasLoad(f.stored_file, f.original_size, std::min(1.0, local_scale));
    load_of[static_cast<size_t>(id)] = how;
    CompositeInput in;
    in.id = id;
    in.image_size = how.size;
    in.load_bytes = how.peak_bytes;
    in.region_loads = how.jpeg;
    in.canvas_from_image = c * ResizeMap(static_cast<double>(how.size.width) / f.original_size.width,
                                         static_cast<double>(how.size.height) / f.original_size.height)
                                   .inverse();
    const AvoidDisc avoid = HotspotDisc(radiometry_.model, HeadingOf(id), how.size);
    in.avoid_centre = avoid.centre;
    in.avoid_radius = avoid.radius;
    inputs.push_back(in);
  }
  auto load = [&](int id, const cv::Rect& need) {
    const CanvasLoad& how = load_of.at(static_cast<size_t>(id));
    FramePart part = LoadIdealPart(id, how, need);
    CorrectRadiometry(radiometry_.model, id, HeadingOf(id), how.size, part.origin, &part.image);
    return part;
  };
  GdalTiffWriter tiff;
  const bool write_tiff = options_.write_tiff;
  // The compositor writes a tiled GeoTIFF; MakeProducts() copies it into the COG mosaic.tif.
  if (write_tiff &&
      !tiff.Open(paths_.Join("mosaic.tiled.tif"), canvas, options_.mosaic.tiff_block, options_.mosaic.tile_size,
                 options_.mosaic.build_overviews, options_.mosaic.gdal_cache_mib, error))
    return false;
  CompositorOptions mosaic = options_.mosaic;
  mosaic.quicklook_path = paths_.Join("mosaic.png");
  *composite = Composite(std::move(inputs), canvas, load, mosaic, write_tiff ? &tiff : nullptr);
  if (!composite->ok) {
    *error = "composite failed: " + composite->error;
    return false;
  }
  if (write_tiff && georef.ok) tiff.SetGeoreference(GdalGeoTransform(georef.world_from_pixel), georef.crs_wkt);
  if (write_tiff && !tiff.Close(error)) return false;
  in_.session->ComposeEnd();
  spdlog::info(
      "mosaic {}x{} px (scale {:.3f}), {} frames blended, {} dropped by overlap, {} tiles, {} frame loads ({:.0f} ms), "
      "{} parts again from memory, {:.0f} ms",
      canvas.width, canvas.height, scale, composite->frames_used, composite->frames_dropped_by_overlap,
      composite->tiles_written, composite->image_loads, composite->load_ms, composite->reloads_from_memory,
      composite->ms);
  return true;
}

double EndOfFlight::HeadingOf(int id) const {
  return uavm::HeadingOf(in_.record->engine().mosaic_from_work(id), in_.record->frame(id).work_size);
}

FramePart EndOfFlight::LoadIdealPart(int id, const CanvasLoad& how, const cv::Rect& need) const {
  const SessionFrame& f = in_.record->frame(id);
  PinholeCamera lens = FinalCamera(*in_.lens, in_.solution->lens);
  if (lens.distortion.IsZero() || f.original_size != in_.lens->original_size())
    return LoadCanvasPart(f.stored_file, how, need);
  // The recorded pixels the ideal part needs, decoded and resampled onto the ideal grid.
  lens = lens.Resized(how.size.width, how.size.height);
  const cv::Rect want = need & cv::Rect(cv::Point(0, 0), how.size);
  FramePart recorded = LoadCanvasPart(f.stored_file, how, RecordedRectFor(lens, want));
  if (recorded.image.empty() || want.empty()) return recorded;
  return {UndistortPart(lens, recorded.image, recorded.origin, want), cv::Point2d(want.x, want.y)};
}

nlohmann::json EndOfFlight::MakeProducts() {
  const GeorefFit& georef = placement_.georef();
  const bool have_tiff = options_.write_tiff && !placement_.placed().empty();
  namespace fs = std::filesystem;
  nlohmann::json j;
  const std::string tiled = paths_.Join("mosaic.tiled.tif");
  const std::string tif = paths_.Join("mosaic.tif");
  if (!have_tiff) return j;
  StageTimer timer;
  std::string err;
  // The web tiles are read from the compositor's tiled GeoTIFF (its overviews were built while compositing) on their
  // own workers while the COG copy, one thread, runs beside them: the two cores share the end of the flight.
  TileSet tiles;
  std::string tiles_err;
  double tiles_ms = 0.0;
  std::future<bool> tiles_job;
  const TileOptions tile_options = in_.live != nullptr ? in_.live->FinalTileOptions(georef.ok) : options_.tiles;
  if (options_.write_products)
    tiles_job = std::async(std::launch::async, [&] {
      StageTimer t;
      const bool ok =
          WriteTiles(tiled, paths_.Join("tiles"), georef.ok, georef.gsd_m, tile_options, &tiles, &tiles_err);
      tiles_ms = t.ElapsedMs();
      return ok;
    });
  // The COG; if GDAL cannot make it, the tiled GeoTIFF (still valid, just not cloud-optimised) takes its name.
  const bool cog = WriteCog(tiled, tif, &err);
  j["cog_ms"] = timer.ElapsedMs();
  const bool tiles_ok = tiles_job.valid() && tiles_job.get();
  if (!cog) {
    spdlog::warn("mosaic.tif: COG copy failed ({}); the tiled GeoTIFF is kept", err);
    std::error_code ec;
    fs::rename(tiled, tif, ec);
  } else {
    std::error_code ec;
    fs::remove(tiled, ec);
  }
  j["cog"] = cog;
  if (!options_.write_products) {
    if (in_.live != nullptr) in_.live->FinalTiles(nullptr, SolvedFrames());
    return j;
  }
  if (!tiles_ok) spdlog::warn("tiles: {}", tiles_err);
  if (in_.live != nullptr) in_.live->FinalTiles(tiles_ok ? &tiles : nullptr, SolvedFrames());
  if (georef.ok) {  // the KMZ is made of the tiles just written
    StageTimer tk;
    const bool kmz = tiles_ok && WriteKmz(paths_.Join("tiles"), tiles, paths_.Join("mosaic.kmz"), &err);
    if (!kmz) spdlog::warn("mosaic.kmz: {}", tiles_ok ? err : "no tiles");
    j["kmz"] = kmz;
    j["kmz_ms"] = tk.ElapsedMs();
  }
  j["tiles"] = {{"ok", tiles_ok},
                {"crs", georef.ok ? "EPSG:3857" : "local"},
                {"min_zoom", tiles.min_zoom},
                {"max_zoom", tiles.max_zoom},
                {"count", tiles.tiles},
                {"empty_skipped", tiles.tiles_empty},
                {"ms", tiles_ms}};
  if (tiles_ok) j["web_page"] = WriteMapPage(tiles);
  j["ms"] = timer.ElapsedMs();
  j["peak_rss_mib"] = HighWaterRssMiB();
  spdlog::info("products: COG {}, tiles z{}-{} ({}), {:.0f} ms", cog ? "ok" : "failed", tiles.min_zoom, tiles.max_zoom,
               tiles.tiles, timer.ElapsedMs());
  return j;
}

// index.html: the tiles, the frames' footprints and the match graph on an offline map page.
bool EndOfFlight::WriteMapPage(const TileSet& tiles) const {
  const std::vector<Mat3>& canvas_from_original = placement_.canvas_from_original();
  const IdSet in(placement_.placed());
  std::vector<MapFrame> frames;
  for (const auto& f : in_.record->frames()) {
    MapFrame m;
    m.id = f.id;
    m.name = f.name;
    m.registered = in.contains(f.id);
    m.mosaic_from_frame = canvas_from_original[static_cast<size_t>(f.id)];
    m.width = f.original_size.width;
    m.height = f.original_size.height;
    frames.push_back(m);
  }
  std::string err;
  const bool page =
      WriteWebPage(paths_.root, options_.leaflet_dir, tiles, placement_.georef(), frames, map_edges_, &err);
  if (!page) spdlog::warn("index.html: {}", err);
  return page;
}

bool EndOfFlight::WriteReport(const CompositeResult& composite, nlohmann::json products, std::string* error) const {
  const std::vector<int>& placed = placement_.placed();
  const cv::Size canvas = placement_.canvas();
  nlohmann::json report = in_.session->Report(*in_.solution, composite);
  report["version"] = UAVM_VERSION;
  // Frames in the map: placed by images or, where no image linked them, by telemetry.
  report["registered"] = placed.size();
  report["placed_by_image"] = placed.size() - placement_.placed_by_telemetry().size();
  report["placed_by_telemetry"] = placement_.placed_by_telemetry().size();
  report["bridge"] = placement_.bridge_report();
  report["live_tiles"] = in_.live != nullptr ? in_.live->Report() : nlohmann::json{{"enabled", false}};
  report["reference_frame"] = placed.empty() ? -1 : placed.front();
  const IdSet in_map(placed);
  nlohmann::json unregistered = nlohmann::json::array();
  for (const auto& f : in_.record->frames())
    if (!in_map.contains(f.id))
      unregistered.push_back({{"index", f.id}, {"file", f.name}, {"reason", in_.record->engine().frame(f.id).failure}});
  report["unregistered"] = unregistered;
  report["composite_ms"] = composite.ms;
  report["mosaic"] = {{"width", canvas.width},
                      {"height", canvas.height},
                      {"scale", options_.mosaic_scale},  // canvas px per original px of the median frame
                      {"canvas_px_per_reference_px", placement_.scale()},
                      {"frames_blended", composite.frames_used},
                      {"frames_dropped_by_overlap", composite.frames_dropped_by_overlap},
                      {"frames_unreadable", composite.frames_unreadable},
                      {"tiles", composite.tiles_written},
                      {"image_loads", composite.image_loads},
                      {"reloads_from_memory", composite.reloads_from_memory},
                      {"parts_released", composite.parts_released},
                      {"frame_cache_peak_mib", static_cast<double>(composite.cache_peak_bytes) / kMiB},
                      {"image_load_ms", composite.load_ms}};
  report["radiometry"] = RadiometryJson(radiometry_, options_.radiometry);
  report["lens"] = LensJson(*in_.lens, in_.solution->lens);
  report["georef"] = placement_.GeorefJson();
  report["products"] = products;
  for (const auto& [key, value] : in_.additions.report_sections.items()) report[key] = value;
  return WriteFileAtomic(paths_.Join("report.json"), report.dump(2) + "\n", error);
}

}  // namespace uavm
