#include "core/georef/live_georef.h"

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "core/util/xml_escape.h"

namespace uavm {

namespace {

constexpr double kMetresPerDegLat = 111320.0;  // thinning and spread only: a few per mille off is harmless

bool HasFix(const LivePoint& p) {
  // (0, 0) is "no fix" as some cameras write it.
  return std::isfinite(p.latitude_deg) && std::isfinite(p.longitude_deg) &&
         !(p.latitude_deg == 0 && p.longitude_deg == 0);
}

}  // namespace

LiveGeoref::LiveGeoref(const LiveGeorefOptions& options) : options_(options), cell_m_(options.initial_cell_m) {
  if (!(cell_m_ > 0)) cell_m_ = 1.0;
  options_.max_points = std::max(options_.max_points, std::max(options_.min_points, 3));
}

Vec2 LiveGeoref::LocalMetres(double latitude_deg, double longitude_deg) const {
  return Vec2((longitude_deg - origin_lon_) * metres_per_deg_lon_, (latitude_deg - origin_lat_) * kMetresPerDegLat);
}

int64_t LiveGeoref::CellKey(const Vec2& local_m) const {
  const auto ix = static_cast<int64_t>(std::floor(local_m.x() / cell_m_));
  const auto iy = static_cast<int64_t>(std::floor(local_m.y() / cell_m_));
  return (ix << 32) ^ (iy & 0xffffffffLL);
}

void LiveGeoref::Rebuild() {
  std::vector<Sampled> kept;
  cells_.clear();
  for (const Sampled& s : sample_) {
    const auto [it, inserted] = cells_.emplace(CellKey(s.local_m), kept.size());
    if (inserted)
      kept.push_back(s);
    else if (s.point.id > kept[it->second].point.id)
      kept[it->second] = s;
  }
  sample_ = std::move(kept);
}

void LiveGeoref::AddFrame(const std::optional<LivePoint>& point) {
  ++frames_since_attempt_;
  if (!point || !HasFix(*point)) return;
  ++frames_with_gps_;
  if (!have_origin_) {
    have_origin_ = true;
    origin_lat_ = point->latitude_deg;
    origin_lon_ = point->longitude_deg;
    metres_per_deg_lon_ = kMetresPerDegLat * std::cos(origin_lat_ * M_PI / 180.0);
  }
  const Sampled s{*point, LocalMetres(point->latitude_deg, point->longitude_deg)};
  const auto [it, inserted] = cells_.emplace(CellKey(s.local_m), sample_.size());
  if (inserted)
    sample_.push_back(s);
  else
    sample_[it->second] = s;  // the newest frame of a cell stands for it
  // Coarser cells until the sample fits again: each doubling costs the sample, and happens log(flight) times.
  while (static_cast<int>(sample_.size()) > options_.max_points) {
    cell_m_ *= 2.0;
    Rebuild();
  }
}

double LiveGeoref::SpreadM() const {
  if (sample_.empty()) return 0.0;
  Vec2 lo = sample_.front().local_m, hi = lo;
  for (const Sampled& s : sample_) {
    lo = lo.cwiseMin(s.local_m);
    hi = hi.cwiseMax(s.local_m);
  }
  return (hi - lo).norm();
}

bool LiveGeoref::Due() const {
  if (static_cast<int>(sample_.size()) < options_.min_points || SpreadM() < options_.min_spread_m) return false;
  if (!attempted_ || frames_since_attempt_ >= options_.refit_every) return true;
  const double grown = std::max(1.0, std::ceil(options_.refit_growth * static_cast<double>(size_at_attempt_)));
  return static_cast<double>(sample_.size()) >= static_cast<double>(size_at_attempt_) + grown;
}

bool LiveGeoref::Refit(const LiveLocate& locate) {
  ++refits_;
  attempted_ = true;
  frames_since_attempt_ = 0;
  // Keep the frames still drawn where the engine has them; note each one's component.
  std::vector<Sampled> kept;
  std::vector<LivePlacement> where;
  for (const Sampled& s : sample_) {
    const auto p = locate(s.point.id);
    if (!p || (p->centre - s.point.drawn).norm() > options_.moved_fraction * s.point.radius_px) continue;
    kept.push_back(s);
    where.push_back(*p);
  }
  // The largest component (ties: the one most sampled frames belong to).
  std::unordered_map<int, int> count;
  for (const auto& p : where) ++count[p.component];
  int best = -1, best_size = -1, best_count = -1;
  for (const auto& p : where)
    if (p.component_size > best_size || (p.component_size == best_size && count[p.component] > best_count)) {
      best = p.component;
      best_size = p.component_size;
      best_count = count[p.component];
    }
  std::vector<GeoPoint> points;
  for (size_t i = 0; i < kept.size(); ++i)
    if (where[i].component == best)
      points.push_back(
          {kept[i].point.id, kept[i].point.drawn, kept[i].point.latitude_deg, kept[i].point.longitude_deg});
  sample_ = std::move(kept);
  Rebuild();
  size_at_attempt_ = sample_.size();
  fit_ = FitGeoref(points, options_.fit);
  return fit_.ok;
}

bool LiveGeoref::Update(const LiveLocate& locate) {
  if (Due()) Refit(locate);
  return fit_.ok;
}

std::string LiveGeoref::WaitingReason() const {
  if (frames_with_gps_ == 0) return "no registered frame carries GPS yet";
  if (static_cast<int>(sample_.size()) < options_.min_points)
    return std::to_string(sample_.size()) + " registered frames with GPS (need " + std::to_string(options_.min_points) +
           ")";
  char buf[96];
  std::snprintf(buf, sizeof(buf), "the GPS positions span %.0f m (need %.0f m)", SpreadM(), options_.min_spread_m);
  return buf;
}

LiveGeorefView LiveGeoref::Describe(const Mat3& image_from_mosaic, int width, int height) const {
  LiveGeorefView v;
  v.frames_with_gps = frames_with_gps_;
  v.width = width;
  v.height = height;
  if (!fit_.ok) {
    v.reason = attempted_ && !fit_.failure.empty() ? fit_.failure : WaitingReason();
    return v;
  }
  Mat3 world_from_image = WorldFromPixel3(fit_.world_from_pixel) * image_from_mosaic.inverse();
  world_from_image /= world_from_image(2, 2);
  v.world_from_pixel = world_from_image.topRows<2>();
  // The picture's outer corners: pixel centres are integers, so its edges lie half a pixel beyond them.
  const double w = width - 0.5, h = height - 0.5;
  std::vector<Vec2> xy;
  for (const Vec2& px : {Vec2(-0.5, -0.5), Vec2(w, -0.5), Vec2(w, h), Vec2(-0.5, h)})
    xy.push_back(v.world_from_pixel.leftCols<2>() * px + v.world_from_pixel.col(2));
  std::vector<double> lat, lon;
  if (!ProjectedToLatLon(fit_.epsg, xy, &lat, &lon, &v.reason)) return v;
  for (size_t i = 0; i < 4; ++i) v.corners[i] = {lat[i], lon[i]};
  v.bounds = {*std::min_element(lat.begin(), lat.end()), *std::min_element(lon.begin(), lon.end()),
              *std::max_element(lat.begin(), lat.end()), *std::max_element(lon.begin(), lon.end())};
  v.epsg = fit_.epsg;
  v.crs_wkt = fit_.crs_wkt;
  v.model = fit_.model;
  v.rms_m = fit_.rms_m;
  v.inliers = fit_.inliers;
  v.points = fit_.points;
  v.gsd_m = std::sqrt(std::abs(v.world_from_pixel.leftCols<2>().determinant()));
  v.rotation_deg = std::atan2(v.world_from_pixel(1, 0), v.world_from_pixel(0, 0)) * 180.0 / M_PI;
  v.ok = true;
  return v;
}

nlohmann::json LiveGeorefView::ToJson() const {
  if (!ok) return {{"georeferenced", false}, {"reason", reason}, {"frames_with_gps", frames_with_gps}};
  const auto gt = GdalGeoTransform(world_from_pixel);
  nlohmann::json corner_list = nlohmann::json::array();
  for (const auto& c : corners) corner_list.push_back({c[0], c[1]});
  return {{"georeferenced", true},
          {"crs", "EPSG:" + std::to_string(epsg)},
          {"epsg", epsg},
          {"model", model},
          {"rms_m", rms_m},
          {"frames_used", inliers},
          {"points", points},
          {"frames_with_gps", frames_with_gps},
          {"gsd_m", gsd_m},
          {"rotation_deg", rotation_deg},
          {"width", width},
          {"height", height},
          {"corners", corner_list},
          {"bounds", {bounds[0], bounds[1], bounds[2], bounds[3]}},
          {"geotransform", std::vector<double>(gt.begin(), gt.end())}};
}

std::string WorldFileText(const Eigen::Matrix<double, 2, 3>& m) {
  char buf[256];
  std::snprintf(buf, sizeof(buf), "%.12g\n%.12g\n%.12g\n%.12g\n%.4f\n%.4f\n", m(0, 0), m(1, 0), m(0, 1), m(1, 1),
                m(0, 2), m(1, 2));
  return buf;
}

std::string PamSrsXml(const std::string& wkt) {
  return "<PAMDataset>\n  <SRS dataAxisToSRSAxisMapping=\"1,2\">" + XmlEscape(wkt) + "</SRS>\n</PAMDataset>\n";
}

}  // namespace uavm
