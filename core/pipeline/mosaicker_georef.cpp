// Georeferencing of the canvas and the map products (core/georef) at the end of the flight.
#include <spdlog/spdlog.h>

#include <cmath>
#include <filesystem>
#include <future>
#include <unordered_set>

#include "core/georef/georef.h"
#include "core/georef/products.h"
#include "core/pipeline/mosaicker.h"
#include "core/util/clock.h"
#include "core/util/memory.h"

namespace uavm {

GeorefFit Mosaicker::GeorefCanvas(const std::vector<int>& component, std::vector<Mat3>* canvas_from_original,
                                  const std::function<void(const Mat3&)>& place) {
  const auto centre = [&](int id) {
    const FrameState& f = frames_[static_cast<size_t>(id)];
    return Apply((*canvas_from_original)[static_cast<size_t>(id)],
                 Vec2(0.5 * (f.original_size.width - 1), 0.5 * (f.original_size.height - 1)));
  };
  std::vector<GeoPoint> points;
  for (int id : component) {
    const auto& m = frames_[static_cast<size_t>(id)].metadata;
    if (!m.latitude_deg || !m.longitude_deg) continue;
    if (*m.latitude_deg == 0 && *m.longitude_deg == 0) continue;  // "no fix" as some cameras write it
    points.push_back({id, centre(id), *m.latitude_deg, *m.longitude_deg});
  }
  georef_gps_frames_ = static_cast<int>(points.size());
  if (points.empty()) {
    GeorefFit none;
    none.failure = "no registered frame carries GPS";
    spdlog::info("georef: local pixel frame (no GPS in the frames)");
    return none;
  }
  GeorefFit fit = FitGeoref(points, options_.georef);
  if (!fit.ok) {
    spdlog::warn("georef: local pixel frame ({})", fit.failure);
    return fit;
  }
  // Turn the canvas north-up: its linear part in a y-down map frame (easting, -northing), divided by its scale.
  // Placing the frames again costs nothing, whereas warping the finished mosaic would need a second full pass.
  const int ref = component.front();
  const Mat3 old_from_ref = (*canvas_from_original)[static_cast<size_t>(ref)];
  Eigen::Matrix2d L;
  L << fit.world_from_pixel(0, 0), fit.world_from_pixel(0, 1), -fit.world_from_pixel(1, 0), -fit.world_from_pixel(1, 1);
  const double s = std::sqrt(std::abs(L.determinant()));
  Mat3 pre = Mat3::Identity();
  pre.topLeftCorner<2, 2>() = L / s;
  georef_rotation_removed_deg_ = fit.rotation_deg;
  place(pre);
  // new canvas = T * old canvas (an affine map: shift, turn, any shrink), T from the reference frame's maps.
  Mat3 T = (*canvas_from_original)[static_cast<size_t>(ref)] * old_from_ref.inverse();
  T /= T(2, 2);
  const Mat3 world_from_new = WorldFromPixel3(fit.world_from_pixel) * T.inverse();
  fit.world_from_pixel = world_from_new.topRows<2>();
  // North-up by construction: what is left off the diagonal is rounding.
  const double scale = std::abs(fit.world_from_pixel(0, 0));
  if (std::abs(fit.world_from_pixel(0, 1)) < 1e-9 * scale) fit.world_from_pixel(0, 1) = 0;
  if (std::abs(fit.world_from_pixel(1, 0)) < 1e-9 * scale) fit.world_from_pixel(1, 0) = 0;
  if (fit.model == "similarity") {  // square pixels, exactly (the two differ by rounding only)
    fit.world_from_pixel(0, 0) = scale;
    fit.world_from_pixel(1, 1) = -scale;
  }
  fit.gsd_m = std::sqrt(std::abs(fit.world_from_pixel.leftCols<2>().determinant()));
  fit.rotation_deg = std::atan2(-fit.world_from_pixel(1, 0), fit.world_from_pixel(0, 0)) * 180.0 / M_PI;
  spdlog::info(
      "georef: EPSG:{} {} fit, RMS {:.2f} m over {}/{} frames with GPS (max {:.1f} m), GSD {:.2f} cm/px, "
      "canvas turned {:.1f} deg to north-up",
      fit.epsg, fit.model, fit.rms_m, fit.inliers, fit.points, fit.max_inlier_m, fit.gsd_m * 100,
      georef_rotation_removed_deg_);
  return fit;
}

nlohmann::json Mosaicker::GeorefJson() const {
  const GeorefFit& g = georef_;
  nlohmann::json j;
  j["crs"] = g.ok ? "EPSG:" + std::to_string(g.epsg) : "local";
  j["georeferenced"] = g.ok;
  j["frames_with_gps"] = georef_gps_frames_;
  if (!g.ok) {
    j["reason"] = g.failure;
    j["units"] = "mosaic pixels";
    return j;
  }
  const auto gt = GdalGeoTransform(g.world_from_pixel);
  j["epsg"] = g.epsg;
  j["model"] = g.model;
  j["rms_m"] = g.rms_m;
  j["rms_all_m"] = g.rms_all_m;
  j["max_inlier_residual_m"] = g.max_inlier_m;
  j["inliers"] = g.inliers;
  j["points"] = g.points;
  j["gsd_cm_per_px"] = g.gsd_m * 100;
  j["rotation_removed_deg"] = georef_rotation_removed_deg_;
  j["geotransform"] = std::vector<double>(gt.begin(), gt.end());
  j["inlier_threshold_m"] = options_.georef.inlier_threshold_m;
  j["residual_units"] = "metres between each frame centre mapped through the fit and its EXIF GPS position";
  return j;
}

nlohmann::json Mosaicker::MakeProducts(const std::vector<int>& component, const std::vector<Mat3>& canvas_from_original,
                                       bool have_tiff) {
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
  if (options_.write_products)
    tiles_job = std::async(std::launch::async, [&] {
      StageTimer t;
      const bool ok =
          WriteTiles(tiled, paths_.Join("tiles"), georef_.ok, georef_.gsd_m, FinalTileOptions(), &tiles, &tiles_err);
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
    FinishLiveTiles(nullptr);
    return j;
  }
  if (!tiles_ok) spdlog::warn("tiles: {}", tiles_err);
  FinishLiveTiles(tiles_ok ? &tiles : nullptr);
  if (georef_.ok) {  // the KMZ is made of the tiles just written
    StageTimer tk;
    const bool kmz = tiles_ok && WriteKmz(paths_.Join("tiles"), tiles, paths_.Join("mosaic.kmz"), &err);
    if (!kmz) spdlog::warn("mosaic.kmz: {}", tiles_ok ? err : "no tiles");
    j["kmz"] = kmz;
    j["kmz_ms"] = tk.ElapsedMs();
  }
  j["tiles"] = {{"ok", tiles_ok},
                {"crs", georef_.ok ? "EPSG:3857" : "local"},
                {"min_zoom", tiles.min_zoom},
                {"max_zoom", tiles.max_zoom},
                {"count", tiles.tiles},
                {"empty_skipped", tiles.tiles_empty},
                {"ms", tiles_ms}};
  if (tiles_ok) {
    std::unordered_set<int> in(component.begin(), component.end());
    std::vector<MapFrame> frames;
    for (const auto& f : frames_) {
      MapFrame m;
      m.id = f.id;
      m.name = f.name;
      m.registered = in.count(f.id) != 0;
      m.mosaic_from_frame = canvas_from_original[static_cast<size_t>(f.id)];
      m.width = f.original_size.width;
      m.height = f.original_size.height;
      frames.push_back(m);
    }
    std::vector<MapEdge> edges;
    for (const Edge& e : engine_.edges())
      edges.push_back(
          {e.src, e.tgt, e.num_inliers, in.count(e.src) != 0 && in.count(e.tgt) != 0 && engine_.EdgeCounts(e)});
    const bool page = WriteWebPage(paths_.root, options_.leaflet_dir, tiles, georef_, frames, edges, &err);
    if (!page) spdlog::warn("index.html: {}", err);
    j["web_page"] = page;
  }
  j["ms"] = timer.ElapsedMs();
  j["peak_rss_mib"] = HighWaterRssMiB();
  spdlog::info("products: COG {}, tiles z{}-{} ({}), {:.0f} ms", cog ? "ok" : "failed", tiles.min_zoom, tiles.max_zoom,
               tiles.tiles, timer.ElapsedMs());
  return j;
}

}  // namespace uavm
