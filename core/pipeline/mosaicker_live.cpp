// The live picture's georeference during the flight (core/georef/live_georef.h): each drawn frame's point, the refit
// when due, live.jgw and live.jpg.aux.xml beside live.jpg, and the live view's "georef".
#include <spdlog/spdlog.h>

#include <cstdio>

#include "core/pipeline/mosaicker.h"
#include "core/util/clock.h"

namespace uavm {

namespace {

Vec2 WorkCentre(cv::Size work) {
  return Vec2(0.5 * (work.width - 1), 0.5 * (work.height - 1));
}

}  // namespace

void Mosaicker::AddLiveGeorefPoint(int id) {
  const FrameMetadata& m = frames_[static_cast<size_t>(id)].metadata;
  if (!m.latitude_deg || !m.longitude_deg) {
    live_georef_.AddFrame(std::nullopt);
    return;
  }
  const cv::Size work = engine_.frame(id).work_size;
  const Mat3& map = engine_.mosaic_from_work(id);
  const Vec2 centre = Apply(map, WorkCentre(work));
  const double radius = 0.5 * (Apply(map, Vec2(work.width - 1, work.height - 1)) - Apply(map, Vec2(0, 0))).norm();
  live_georef_.AddFrame(LivePoint{id, centre, radius, *m.latitude_deg, *m.longitude_deg});
}

std::shared_ptr<const nlohmann::json> Mosaicker::UpdateLiveGeoref() {
  StageTimer t;
  const bool was_ok = live_georef_.ok();
  const bool refit = live_georef_.Due();
  if (refit) {
    // Where the engine has each sampled frame now: a full solve or a merge may have moved it since it was drawn.
    live_georef_.Refit([this](int id) -> std::optional<LivePlacement> {
      if (!engine_.placed(id) || !engine_.frame(id).in_graph) return std::nullopt;
      return LivePlacement{engine_.ComponentOf(id), engine_.ComponentSize(id),
                           Apply(engine_.mosaic_from_work(id), WorkCentre(engine_.frame(id).work_size))};
    });
  }
  const cv::Size size = preview_.last_jpeg_size();
  const LiveGeorefView view = live_georef_.Describe(preview_.last_jpeg_from_mosaic(), size.width, size.height);
  WriteLiveSidecars(view);
  stats_.Add("live_georef", t.ElapsedMs());  // part of "preview": what the georeference adds to it
  if (refit) {
    if (view.ok && !was_ok)
      spdlog::info("live georef: EPSG:{} {} fit over {}/{} frames, RMS {:.1f} m ({:.0f} ms)", view.epsg, view.model,
                   view.inliers, view.points, view.rms_m, t.ElapsedMs());
    else if (!view.ok && was_ok)
      spdlog::warn("live georef lost: {}", view.reason);
  }
  return std::make_shared<const nlohmann::json>(view.ToJson());
}

void Mosaicker::WriteLiveSidecars(const LiveGeorefView& view) {
  const std::string jgw = paths_.Join("live.jgw");
  const std::string aux = paths_.Join("live.jpg.aux.xml");
  if (!view.ok) {
    // No georeference (yet, or any more): a GIS must not place the picture by an old one (a resumed session's too).
    if (live_sidecar_epsg_ != 0) {
      std::remove(jgw.c_str());
      std::remove(aux.c_str());
      live_sidecar_epsg_ = 0;
    }
    return;
  }
  // Written after live.jpg, each atomically: a reader sees whole files, at worst one picture's world file late.
  std::string error;
  if (!WriteFileAtomic(jgw, WorldFileText(view.world_from_pixel), &error)) spdlog::warn("live.jgw: {}", error);
  if (view.epsg == live_sidecar_epsg_) return;  // the CRS changes only with the UTM zone: rarely rewritten
  if (WriteFileAtomic(aux, PamSrsXml(view.crs_wkt), &error))
    live_sidecar_epsg_ = view.epsg;
  else
    spdlog::warn("live.jpg.aux.xml: {}", error);
}

}  // namespace uavm
