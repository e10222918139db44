#include "core/pipeline/live_tiles.h"

#include <spdlog/spdlog.h>

#include <cmath>
#include <deque>
#include <filesystem>
#include <mutex>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "core/pipeline/stored_frame.h"
#include "core/tiles/web_mercator.h"
#include "core/util/clock.h"

namespace uavm {

namespace {

// A local pyramid: one max_zoom pixel per mosaic pixel, the first frame at the middle of a 2^kLocalMaxZoom-tile world
// (1 Mpx wide: room for a flight of ~1000 frame widths in any direction).
constexpr int kLocalMaxZoom = 12;
constexpr size_t kFootprintsShown = 300;  // the newest frames' outlines on the live page

// A stored frame read back at its work size (the live tiles' re-rendering), DCT-scaled when the file is larger.
// The largest JPEG DCT scaling (1/2, 1/4, 1/8) that still decodes the frame at least at its work size.
int DecodeReduce(cv::Size original, cv::Size work) {
  int r = 1;
  while (r < 8 && original.width / (2 * r) >= work.width && original.height / (2 * r) >= work.height) r *= 2;
  return r;
}

}  // namespace

LiveTiles::LiveTiles(const PipelineOptions& options, SessionPaths paths, const FlightRecord* record,
                     const WorkLens* lens, const LiveGeoref* georef)
    : options_(options), paths_(std::move(paths)), record_(record), georef_(georef) {
  // Frames redrawn from frames/ (moved by a solve) are undistorted like the new ones (the lens is chosen on the first
  // frame's preparation, before anything is drawn, and not changed again).
  auto read = [this, lens](int id, const std::string& path, cv::Size work_size, int decode_reduce, double heading) {
    const cv::Mat recorded = LoadStoredFrame(path, work_size, decode_reduce);
    cv::Mat ideal =
        lens->work().UndistortImage(recorded);  // the recorded image itself when the sizes differ or no lens
    std::shared_ptr<const RadiometryModel> radiometry;
    {
      const std::lock_guard<std::mutex> lock(radiometry_mutex_);
      radiometry = radiometry_;
    }
    if (radiometry && !ideal.empty()) {
      CorrectRadiometry(*radiometry, id, heading, ideal.size(), cv::Point2d(), &ideal);
    }
    return ideal;
  };
  pyramid_ = std::make_unique<LiveTilePyramid>(
      paths_.Join("live_tiles"), options_.live_tiles, read,
      [this](std::shared_ptr<const TileSetInfo> info) { tiles_published_.Emit(std::move(info)); });
}

void LiveTiles::SetRadiometry(std::shared_ptr<const RadiometryModel> model) {
  const std::lock_guard<std::mutex> lock(radiometry_mutex_);
  radiometry_ = std::move(model);
}

// The worker publishes through this object's signal: it stops before anything else goes.
LiveTiles::~LiveTiles() {
  pyramid_.reset();
}

Mat3 LiveTiles::GridFromWork(int id) const {
  const Grid& lt = grid_;
  const Mat3& mosaic_from_work = engine().mosaic_from_work(id);
  if (!lt.grid.geographic) return Translation(lt.local_offset.x(), lt.local_offset.y()) * mosaic_from_work;
  // Work pixels -> mosaic -> UTM (the live fit, affine) -> lat/lon -> web mercator: not affine over the map, but a
  // homography fitted on a 3x3 lattice of the frame is exact to far below a pixel over one footprint.
  const cv::Size size = engine().frame(id).work_size;
  std::vector<cv::Point2d> src, dst;
  for (int j = 0; j < 3; ++j)
    for (int i = 0; i < 3; ++i) {
      const Vec2 w(0.5 * i * (size.width - 1), 0.5 * j * (size.height - 1));
      const Vec2 m = Apply(mosaic_from_work, w);
      const double e =
          lt.fit.world_from_pixel(0, 0) * m.x() + lt.fit.world_from_pixel(0, 1) * m.y() + lt.fit.world_from_pixel(0, 2);
      const double n =
          lt.fit.world_from_pixel(1, 0) * m.x() + lt.fit.world_from_pixel(1, 1) * m.y() + lt.fit.world_from_pixel(1, 2);
      double lat = 0, lon = 0;
      if (!lt.to_latlon.ToLatLon(lt.fit.epsg, Vec2(e, n), &lat, &lon)) return Mat3::Zero();
      const Vec2 px = MercatorPixelFromLatLon(lat, lon, lt.grid.max_zoom);
      src.emplace_back(w.x(), w.y());
      dst.emplace_back(px.x(), px.y());
    }
  const cv::Mat h = cv::findHomography(src, dst, 0);
  if (h.empty()) return Mat3::Zero();
  Mat3 m;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) m(r, c) = h.at<double>(r, c);
  return m;
}

// The ground pixel the live tiles need: what they are drawn from (the newest frame's working copy; the reference frame
// may have been taken lower, at take-off), but no finer than the final mosaic's (mosaic_scale of the originals): a
// finer zoom would only enlarge the same pixels into more tiles.
double LiveTiles::TilesGsd(int id) const {
  const SessionFrame& st = record_->frame(id);
  const cv::Size work = engine().frame(id).work_size;
  const Vec2 centre(0.5 * (work.width - 1), 0.5 * (work.height - 1));
  const double work_gsd = grid_.fit.gsd_m * LocalScale(engine().mosaic_from_work(id), centre);
  const double work_per_original = std::sqrt(std::abs(st.work_from_original().topLeftCorner<2, 2>().determinant()));
  return std::max(work_gsd, work_gsd * work_per_original / options_.mosaic_scale);
}

bool LiveTiles::StartGrid(int id) {
  Grid& lt = grid_;
  const FrameMetadata& m = record_->frame(id).metadata();
  const bool has_position = m.latitude_deg && m.longitude_deg;
  if (georef_->ok()) {
    lt.fit = georef_->fit();
    lt.refits_seen = georef_->refits();
    double lat = 0, lon = 0;
    const Vec2 origin(lt.fit.world_from_pixel(0, 2), lt.fit.world_from_pixel(1, 2));
    if (!lt.to_latlon.ToLatLon(lt.fit.epsg, origin, &lat, &lon)) return false;
    // The zoom of the first georeference stays unless a later one differs by two levels or more (a GSD estimate
    // near a level's edge must not redraw the map back and forth).
    const int zoom = MaxZoomForGsd(lat, TilesGsd(id));
    if (!lt.grid.geographic || std::abs(zoom - lt.grid.max_zoom) >= 2) lt.grid.max_zoom = zoom;
    lt.grid.geographic = true;
  } else if (!has_position && !lt.started) {
    const cv::Size s = engine().frame(id).work_size;
    const Vec2 centre = Apply(engine().mosaic_from_work(id), Vec2(0.5 * (s.width - 1), 0.5 * (s.height - 1)));
    lt.grid.geographic = false;
    lt.grid.max_zoom = kLocalMaxZoom;
    lt.local_offset = Vec2::Constant(kTileSize * std::ldexp(1.0, kLocalMaxZoom - 1)) - centre;
  } else {
    return false;  // positions are coming: wait for the live georeference rather than draw twice
  }
  lt.grid.min_zoom = std::max(0, lt.grid.max_zoom - options_.live_tiles.levels);
  lt.started = true;
  lt.anchor = id;
  lt.drawn.clear();
  lt.outlines.clear();
  lt.drawn_mosaic = cv::Rect2d();
  pyramid_->Reset(lt.grid);
  spdlog::info("live tiles: {} grid, zoom {}-{} (tile pixel no coarser than {:.1f} cm)",
               lt.grid.geographic ? "web-mercator" : "local", lt.grid.min_zoom, lt.grid.max_zoom,
               lt.grid.geographic ? 100 * TilesGsd(id) : 0.0);
  return true;
}

// Whether the pyramid must start again: the first georeference, a new one that moves the drawn map by more than
// refit_shift_m, or another piece of the flight has become the largest.
bool LiveTiles::GridStale(int id) {
  Grid& lt = grid_;
  if (!lt.started) return true;
  if (engine().ComponentOf(id) != engine().ComponentOf(lt.anchor) &&
      engine().ComponentSize(id) > engine().ComponentSize(lt.anchor))
    return true;
  if (!georef_->ok() || georef_->refits() == lt.refits_seen) return false;
  if (!lt.grid.geographic) return true;
  lt.refits_seen = georef_->refits();
  const auto& a = lt.fit.world_from_pixel;
  const auto& b = georef_->fit().world_from_pixel;
  double shift = 0;
  const cv::Rect2d r = lt.drawn_mosaic;
  for (const Vec2& c : {Vec2(r.x, r.y), Vec2(r.br().x, r.y), Vec2(r.x, r.br().y), Vec2(r.br().x, r.br().y)})
    shift = std::max(shift, ((a.leftCols<2>() - b.leftCols<2>()) * c + a.col(2) - b.col(2)).norm());
  // Moves within the fit's own residual are GPS noise, not news: the map stays where it is.
  const double threshold = std::max(options_.live_tiles.refit_shift_m, 2.0 * georef_->fit().rms_m);
  return georef_->fit().epsg != lt.fit.epsg || shift > threshold;
}

void LiveTiles::Draw(int id, std::shared_ptr<const cv::Mat> image) {
  Grid& lt = grid_;
  const Mat3 grid_from_work = GridFromWork(id);
  if (grid_from_work.isZero()) return;
  const SessionFrame& st = record_->frame(id);
  const cv::Size size = engine().frame(id).work_size;
  const int64_t registered_ns = image ? MonotonicNs() : 0;  // a new frame's latency is measured, not a redraw's
  TileFrame f;
  f.id = id;
  f.path = st.stored_file;
  f.work_size = size;
  f.grid_from_work = grid_from_work;
  f.image = std::move(image);
  f.decode_reduce = DecodeReduce(st.original_size, size);
  f.registered_ns = registered_ns;
  f.heading = HeadingOf(engine().mosaic_from_work(id), size);
  if (!pyramid_->Draw(std::move(f))) return;
  const bool is_new = lt.drawn.insert(id).second;
  const cv::Rect2d box = cv::boundingRect(Footprint(engine().mosaic_from_work(id), size.width, size.height));
  lt.drawn_mosaic = lt.drawn_mosaic.area() > 0 ? (lt.drawn_mosaic | box) : box;
  if (!is_new) return;
  std::array<Vec2, 4> outline;
  const auto corners = ImageCorners(size.width, size.height);
  for (size_t k = 0; k < 4; ++k) outline[k] = Apply(grid_from_work, corners[k]);
  lt.outlines.emplace_back(id, outline);
  if (lt.outlines.size() > kFootprintsShown) lt.outlines.pop_front();
}

void LiveTiles::Update(int id, const cv::Mat& work_bgr, const std::vector<int>& moved_frames) {
  Grid& lt = grid_;
  std::vector<int> moved = moved_frames;
  if (!engine().frame(id).failure.empty() || !engine().placed(id)) return;
  if (GridStale(id)) {
    if (!StartGrid(id)) return;
    // Everything of the piece shown is drawn again on the new grid (read back from frames/ by the worker).
    for (int k : engine().MembersOf(engine().ComponentOf(id)))
      if (k != id && engine().placed(k)) Draw(k, nullptr);
    moved.clear();
  }
  const int root = engine().ComponentOf(lt.anchor);
  for (int k : moved)  // a solve or a merge moved them (or brought them into the piece shown)
    if (k != id && engine().ComponentOf(k) == root) Draw(k, nullptr);
  if (engine().ComponentOf(id) == root) Draw(id, std::make_shared<const cv::Mat>(work_bgr));
}

void LiveTiles::PublishFootprints() {
  if (!grid_.started) return;
  Grid& lt = grid_;
  nlohmann::json features = nlohmann::json::array();
  const double local_unit = std::ldexp(1.0, lt.grid.max_zoom);
  for (const auto& [id, outline] : lt.outlines) {
    nlohmann::json ring = nlohmann::json::array();
    for (size_t k = 0; k <= 4; ++k) {
      const Vec2& p = outline[k % 4];
      const Vec2 ll = lt.grid.geographic ? LonLatFromMercatorPixel(p, lt.grid.max_zoom)
                                         : Vec2(p.x() / local_unit, -p.y() / local_unit);
      ring.push_back({ll.x(), ll.y()});
    }
    features.push_back({{"type", "Feature"},
                        {"properties", {{"id", id}, {"name", record_->frame(id).name}}},
                        {"geometry", {{"type", "Polygon"}, {"coordinates", {ring}}}}});
  }
  const nlohmann::json doc = {
      {"type", "FeatureCollection"}, {"crs", lt.grid.geographic ? "EPSG:4326" : "local"}, {"features", features}};
  footprints_published_.Emit(std::make_shared<const std::string>(doc.dump()));
}

TileOptions LiveTiles::FinalTileOptions(bool georeferenced) const {
  TileOptions o = options_.tiles;
  // The end-of-flight tiles on the live grid's zooms, so that a client keeps its URLs (and sees every zoom it had).
  if (grid_.started && grid_.grid.geographic && georeferenced) {
    o.keep_max_zoom = grid_.grid.max_zoom;
    o.keep_min_zoom = grid_.grid.min_zoom;
  }
  return o;
}

void LiveTiles::StopForFinalTiles() {
  // The final tiles will replace the live ones: what still waits to be drawn would only slow the end of the flight.
  if (pyramid_ && options_.write_products && options_.write_tiff) pyramid_->Cancel();
}

void LiveTiles::Finish(const TileSet* final_tiles, int frames) {
  if (!pyramid_) return;
  Grid& lt = grid_;
  pyramid_->Drain();
  const LiveTileStats stats = pyramid_->Stats();
  std::vector<double> latency = stats.latency_ms;
  std::sort(latency.begin(), latency.end());
  const auto at = [&](double q) {
    return latency.empty() ? 0.0 : latency[static_cast<size_t>(q * static_cast<double>(latency.size() - 1))];
  };
  report_ = {{"enabled", true},
             {"grid", !lt.started          ? "none"
                      : lt.grid.geographic ? "EPSG:3857"
                                           : "local"},
             {"min_zoom", lt.grid.min_zoom},
             {"max_zoom", lt.grid.max_zoom},
             {"frames_drawn", stats.frames_drawn},
             {"frames_redrawn", stats.frames_redrawn},
             {"frames_reread", stats.frames_reread},
             {"grid_resets", stats.resets},
             {"tiles_written", stats.tiles_written},
             {"jobs_dropped", stats.jobs_dropped},
             {"jobs_superseded", stats.jobs_superseded},
             {"write_errors", stats.write_errors},
             {"worker_ms", stats.busy_ms},
             {"latency_ms_median", at(0.5)},
             {"latency_ms_p95", at(0.95)}};
  auto last = pyramid_->Info();
  pyramid_.reset();  // the worker stops
  if (final_tiles == nullptr || final_tiles->tiles == 0) {
    // No end-of-flight tiles (--no-products, or they failed): the live pyramid stays, as it is, the map served.
    if (last) {
      auto info = std::make_shared<TileSetInfo>(*last);
      info->final = true;
      tiles_published_.Emit(std::move(info));
    }
    return;
  }
  auto info = std::make_shared<TileSetInfo>();
  info->dir = paths_.Join("tiles");
  info->geographic = final_tiles->geographic;
  info->min_zoom = final_tiles->min_zoom;
  info->max_zoom = final_tiles->max_zoom;
  info->west = final_tiles->west, info->south = final_tiles->south;
  info->east = final_tiles->east, info->north = final_tiles->north;
  info->final = true;
  info->generation = (last ? last->generation : 0) + 1;
  info->updated_ns = MonotonicNs();
  info->frames = frames;
  tiles_published_.Emit(std::move(info));
  std::error_code ec;
  std::filesystem::remove_all(paths_.Join("live_tiles"), ec);  // superseded: the server reads tiles/ now
}

}  // namespace uavm
