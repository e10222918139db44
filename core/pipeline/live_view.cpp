#include "core/pipeline/live_view.h"

#include <spdlog/spdlog.h>

#include <cstdio>
#include <opencv2/imgproc.hpp>

#include "core/util/clock.h"
#include "core/util/memory.h"

namespace uavm {

namespace {

constexpr int kThumbLongSide = 320;  // what the preview draws of each frame

Vec2 WorkCentre(cv::Size work) {
  return Vec2(0.5 * (work.width - 1), 0.5 * (work.height - 1));
}

}  // namespace

LiveView::LiveView(const PipelineOptions& options, SessionPaths paths, const FlightRecord* record, const WorkLens* lens,
                   StageStats* stats)
    : options_(options),
      paths_(std::move(paths)),
      record_(record),
      stats_(stats),
      preview_(options.preview_side),
      georef_(LiveGeorefOptions{.fit = options.georef}) {
  if (options.live_tiles.enabled) tiles_ = std::make_unique<LiveTiles>(options_, paths_, record_, lens, &georef_);
}

LiveView::~LiveView() {
  following_.clear();  // no frame reaches a half-destroyed view
}

void LiveView::Follow(FlightSession* session) {
  following_.push_back(session->OnFrameRegistered([this](const RegisteredFrame& f) { FrameRegistered(f); }));
  following_.push_back(session->OnHintRequest([this](HintRequest& request) {
    if (!request.hint) request.hint = HintFor(*request.metadata);
  }));
}

Connection LiveView::OnTiles(std::function<void(std::shared_ptr<const TileSetInfo>)> slot) {
  return tiles_ ? tiles_->OnTiles(std::move(slot)) : Connection();
}

Connection LiveView::OnFootprints(std::function<void(std::shared_ptr<const std::string>)> slot) {
  return tiles_ ? tiles_->OnFootprints(std::move(slot)) : Connection();
}

void LiveView::FrameRegistered(const RegisteredFrame& frame) {
  StageTimer t;
  const cv::Mat live_bgr = CorrectedImage(frame);
  if (record_->engine().frame(frame.id).failure.empty() || frame.id == 0) UpdatePreview(frame.id, live_bgr);
  stats_->Add("preview", t.ElapsedMs());
  if (!tiles_) return;
  t.Restart();
  tiles_->Update(frame.id, live_bgr, frame.moved);
  stats_->Add("live_tiles", t.ElapsedMs());  // the frame loop's share; the drawing is the worker's
}

cv::Mat LiveView::CorrectedImage(const RegisteredFrame& frame) {
  const cv::Mat& work_bgr = *frame.work_bgr;
  const RadiometryOptions& radiometry = options_.radiometry;
  if (!radiometry.enabled || !(radiometry.vignetting || radiometry.flat_field || radiometry.hotspot) ||
      frame.thumb->empty() || (options_.preview_every <= 0 && !tiles_))
    return work_bgr;
  if (!radiometry_) radiometry_.emplace(options_.radiometry);
  const double heading = HeadingOf(record_->engine().mosaic_from_work(frame.id), work_bgr.size());
  radiometry_->AddFrame(frame.id, *frame.thumb, work_bgr.size(), heading);
  const auto& edges = record_->engine().edges();
  for (size_t k = frame.edges_before; k < edges.size(); ++k)
    radiometry_->AddEdge(edges[k].src, edges[k].tgt, edges[k].tgt_from_src);
  if (radiometry_->MaybeSolve()) {
    const RadiometryModel& m = radiometry_->model();
    if (tiles_) tiles_->SetRadiometry(std::make_shared<const RadiometryModel>(m));
    spdlog::info("radiometry: live model from the last frames: corner {:.3f} {:.3f} {:.3f}, flat field {}, hotspot {}",
                 m.Falloff(0, 1.0), m.Falloff(1, 1.0), m.Falloff(2, 1.0), m.flat_field ? "kept" : "not kept",
                 m.hotspot.found ? fmt::format("{:+.0f} %", 100 * (std::exp(m.hotspot.LogBoost(0)) - 1)) : "not found");
  }
  if (!radiometry_->model().ok) return work_bgr;
  cv::Mat corrected = work_bgr.clone();
  CorrectRadiometry(radiometry_->model(), frame.id, heading, work_bgr.size(), cv::Point2d(), &corrected);
  return corrected;
}

void LiveView::UpdatePreview(int id, const cv::Mat& work_bgr) {
  if (options_.preview_every <= 0) return;
  const double s = std::min(1.0, kThumbLongSide / static_cast<double>(std::max(work_bgr.cols, work_bgr.rows)));
  cv::Mat thumb;
  cv::resize(work_bgr, thumb, cv::Size(), s, s, cv::INTER_AREA);
  const Mat3 work_from_thumb =
      ResizeMap(static_cast<double>(thumb.cols) / work_bgr.cols, static_cast<double>(thumb.rows) / work_bgr.rows)
          .inverse();
  preview_.Add(thumb, record_->engine().mosaic_from_work(id) * work_from_thumb);
  AddGeorefPoint(id);
  if (static_cast<int>(record_->size()) % options_.preview_every == 0) {
    std::string err;
    if (!preview_.Write(paths_.Join("live.jpg"), &err)) spdlog::warn("live preview: {}", err);
    auto georef = UpdateGeoref();
    preview_published_.Emit(preview_.last_jpeg(), std::move(georef));
    if (tiles_) tiles_->PublishFootprints();
  }
}

// The live picture's georeference during the flight (core/georef/live_georef.h): each drawn frame's point, the refit
// when due, live.jgw and live.jpg.aux.xml beside live.jpg, and the live view's "georef".
void LiveView::AddGeorefPoint(int id) {
  const FrameMetadata& m = record_->frame(id).metadata();
  if (!m.latitude_deg || !m.longitude_deg) {
    georef_.AddFrame(std::nullopt);
    return;
  }
  const RegistrationEngine& engine = record_->engine();
  const cv::Size work = engine.frame(id).work_size;
  const Mat3& map = engine.mosaic_from_work(id);
  const Vec2 centre = Apply(map, WorkCentre(work));
  const double radius = 0.5 * (Apply(map, Vec2(work.width - 1, work.height - 1)) - Apply(map, Vec2(0, 0))).norm();
  georef_.AddFrame(LivePoint{id, centre, radius, *m.latitude_deg, *m.longitude_deg});
}

std::shared_ptr<const nlohmann::json> LiveView::UpdateGeoref() {
  StageTimer t;
  const bool was_ok = georef_.ok();
  const bool refit = georef_.Due();
  if (refit) {
    // Where the engine has each sampled frame now: a full solve or a merge may have moved it since it was drawn.
    const RegistrationEngine& engine = record_->engine();
    georef_.Refit([&engine](int id) -> std::optional<LivePlacement> {
      if (!engine.placed(id) || !engine.frame(id).in_graph) return std::nullopt;
      return LivePlacement{engine.ComponentOf(id), engine.ComponentSize(id),
                           Apply(engine.mosaic_from_work(id), WorkCentre(engine.frame(id).work_size))};
    });
  }
  const cv::Size size = preview_.last_jpeg_size();
  const LiveGeorefView view = georef_.Describe(preview_.last_jpeg_from_mosaic(), size.width, size.height);
  WriteSidecars(view);
  stats_->Add("live_georef", t.ElapsedMs());  // part of "preview": what the georeference adds to it
  if (refit) {
    if (view.ok && !was_ok)
      spdlog::info("live georef: EPSG:{} {} fit over {}/{} frames, RMS {:.1f} m ({:.0f} ms)", view.epsg, view.model,
                   view.inliers, view.points, view.rms_m, t.ElapsedMs());
    else if (!view.ok && was_ok)
      spdlog::warn("live georef lost: {}", view.reason);
  }
  return std::make_shared<const nlohmann::json>(view.ToJson());
}

void LiveView::WriteSidecars(const LiveGeorefView& view) {
  const std::string jgw = paths_.Join("live.jgw");
  const std::string aux = paths_.Join("live.jpg.aux.xml");
  if (!view.ok) {
    // No georeference (yet, or any more): a GIS must not place the picture by an old one (a resumed session's too).
    if (sidecar_epsg_ != 0) {
      std::remove(jgw.c_str());
      std::remove(aux.c_str());
      sidecar_epsg_ = 0;
    }
    return;
  }
  // Written after live.jpg, each atomically: a reader sees whole files, at worst one picture's world file late.
  std::string error;
  if (!WriteFileAtomic(jgw, WorldFileText(view.world_from_pixel), &error)) spdlog::warn("live.jgw: {}", error);
  if (view.epsg == sidecar_epsg_) return;  // the CRS changes only with the UTM zone: rarely rewritten
  if (WriteFileAtomic(aux, PamSrsXml(view.crs_wkt), &error))
    sidecar_epsg_ = view.epsg;
  else
    spdlog::warn("live.jpg.aux.xml: {}", error);
}

std::optional<PositionHint> LiveView::HintFor(const FrameMetadata& m) const {
  if (!georef_.ok() || !m.latitude_deg || !m.longitude_deg) return std::nullopt;
  const GeorefFit& fit = georef_.fit();
  if (fit.inlier_ids.empty()) return std::nullopt;
  Vec2 world;
  if (!hint_projection_.ToProjected(fit.epsg, *m.latitude_deg, *m.longitude_deg, &world)) return std::nullopt;
  // The fit's pixels are the mosaic coordinates the preview drew its frames in: those of its newest inlier's
  // component (a later merge may have moved it; the hint only chooses candidates, a wrong one costs a few matches).
  return PositionHint{fit.inlier_ids.back(), Apply(WorldFromPixel3(fit.world_from_pixel).inverse(), world)};
}

void LiveView::StopForFinalTiles() {
  if (tiles_) tiles_->StopForFinalTiles();
}

TileOptions LiveView::FinalTileOptions(bool georeferenced) const {
  return tiles_ ? tiles_->FinalTileOptions(georeferenced) : options_.tiles;
}

void LiveView::FinalTiles(const TileSet* tiles, int frames) {
  if (tiles_) tiles_->Finish(tiles, frames);
}

void LiveView::WriteLastPreview() {
  std::string err;
  if (options_.preview_every > 0 && !preview_.Write(paths_.Join("live.jpg"), &err))
    spdlog::warn("live preview: {}", err);
}

nlohmann::json LiveView::Report() const {
  return tiles_ ? tiles_->report() : nlohmann::json{{"enabled", false}};
}

}  // namespace uavm
