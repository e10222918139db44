#include "core/pipeline/canvas_placement.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <unordered_map>

#include "core/util/id_set.h"

namespace uavm {

CanvasPlacement::CanvasPlacement(const PipelineOptions& options, const FlightRecord* record, const Solution* solution)
    : options_(options), record_(record), solution_(solution) {}

void CanvasPlacement::Place() {
  const std::vector<int>& component = solution_->component;
  canvas_from_original_.assign(record_->size(), Mat3::Identity());
  canvas_ = cv::Size(0, 0);
  scale_ = component.empty() ? options_.mosaic_scale : PlaceComponent(component);
  // The map: the component placed by images, then what telemetry places where no image links.
  placed_ = component;
  BridgeFrames();
}

// Canvas: mosaic_scale canvas pixels per original pixel of the median frame (in the reference frame's orientation),
// shifted so the flight starts at (0,0). The median, not the reference frame: the first frame is often taken while
// the drone still climbs (caliterra's is 80 m lower than the last ones), and the canvas should follow the survey.
// Georeferenced, the canvas is turned north-up. Returns canvas pixels per reference-frame pixel.
double CanvasPlacement::PlaceComponent(const std::vector<int>& component) {
  double scale = options_.mosaic_scale;
  const SessionFrame& ref = record_->frame(component.front());
  std::vector<double> ref_px_per_px;
  for (int id : component) {
    const SessionFrame& f = record_->frame(id);
    const Mat3 ref_from_original =
        ref.work_from_original().inverse() * record_->engine().mosaic_from_work(id) * f.work_from_original();
    ref_px_per_px.push_back(
        LocalScale(ref_from_original, Vec2(0.5 * (f.original_size.width - 1), 0.5 * (f.original_size.height - 1))));
  }
  std::nth_element(ref_px_per_px.begin(), ref_px_per_px.begin() + static_cast<long>(ref_px_per_px.size() / 2),
                   ref_px_per_px.end());
  const double median = ref_px_per_px[ref_px_per_px.size() / 2];
  if (median > 0 && std::isfinite(median)) scale /= median;
  // Placement on the canvas; `pre` (linear) turns the canvas, e.g. north-up once the flight is georeferenced.
  const auto place = [&](const Mat3& pre) {
    for (int attempt = 0; attempt < 2; ++attempt) {
      const Mat3 out_from_mosaic_work = pre * ResizeMap(scale, scale) * ref.work_from_original().inverse();
      for (int id : component)
        canvas_from_original_[static_cast<size_t>(id)] =
            out_from_mosaic_work * record_->engine().mosaic_from_work(id) * record_->frame(id).work_from_original();
      const Bounds2 box = FootprintBounds(component, canvas_from_original_,
                                          [this](int id) { return record_->frame(id).original_size; });
      const double w = std::ceil(box.maxx) - std::floor(box.minx) + 1;
      const double h = std::ceil(box.maxy) - std::floor(box.miny) + 1;
      if (std::max(w, h) > options_.max_canvas_side && attempt == 0) {
        const double shrink = options_.max_canvas_side / std::max(w, h);
        spdlog::warn("canvas {:.0f}x{:.0f} exceeds max_canvas_side {}; mosaic_scale {:.3f} -> {:.3f}", w, h,
                     options_.max_canvas_side, scale, scale * shrink);
        scale *= shrink * 0.999;
        continue;
      }
      const Mat3 shift = Translation(-std::floor(box.minx), -std::floor(box.miny));
      for (int id : component)
        canvas_from_original_[static_cast<size_t>(id)] = shift * canvas_from_original_[static_cast<size_t>(id)];
      canvas_ = cv::Size(static_cast<int>(w), static_cast<int>(h));
      break;
    }
  };
  place(Mat3::Identity());
  georef_ = GeorefCanvas(component, place);
  return scale;
}

GeorefFit CanvasPlacement::GeorefCanvas(const std::vector<int>& component,
                                        const std::function<void(const Mat3&)>& place) {
  const auto centre = [&](int id) {
    const SessionFrame& f = record_->frame(id);
    return Apply(canvas_from_original_[static_cast<size_t>(id)],
                 Vec2(0.5 * (f.original_size.width - 1), 0.5 * (f.original_size.height - 1)));
  };
  std::vector<GeoPoint> points;
  for (int id : component) {
    const auto& m = record_->frame(id).metadata();
    if (!m.latitude_deg || !m.longitude_deg) continue;
    if (*m.latitude_deg == 0 && *m.longitude_deg == 0) continue;  // "no fix" as some cameras write it
    points.push_back({id, centre(id), *m.latitude_deg, *m.longitude_deg});
  }
  gps_frames_ = static_cast<int>(points.size());
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
  const Mat3 old_from_ref = canvas_from_original_[static_cast<size_t>(ref)];
  Eigen::Matrix2d L;
  L << fit.world_from_pixel(0, 0), fit.world_from_pixel(0, 1), -fit.world_from_pixel(1, 0), -fit.world_from_pixel(1, 1);
  const double s = std::sqrt(std::abs(L.determinant()));
  Mat3 pre = Mat3::Identity();
  pre.topLeftCorner<2, 2>() = L / s;
  rotation_removed_deg_ = fit.rotation_deg;
  place(pre);
  // new canvas = T * old canvas (an affine map: shift, turn, any shrink), T from the reference frame's maps.
  Mat3 T = canvas_from_original_[static_cast<size_t>(ref)] * old_from_ref.inverse();
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
      rotation_removed_deg_);
  return fit;
}

nlohmann::json CanvasPlacement::GeorefJson() const {
  const GeorefFit& g = georef_;
  nlohmann::json j;
  j["crs"] = g.ok ? "EPSG:" + std::to_string(g.epsg) : "local";
  j["georeferenced"] = g.ok;
  j["frames_with_gps"] = gps_frames_;
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
  j["rotation_removed_deg"] = rotation_removed_deg_;
  j["geotransform"] = std::vector<double>(gt.begin(), gt.end());
  j["inlier_threshold_m"] = options_.georef.inlier_threshold_m;
  j["residual_units"] = "metres between each frame centre mapped through the fit and its EXIF GPS position";
  return j;
}

// Frames of placed_ are the map's; the others that are stored in the session become the pieces bridging may place.
std::vector<BridgeFrame> CanvasPlacement::BridgeInputs(int* candidates) const {
  const IdSet in_map(placed_);
  std::unordered_map<int, int> piece_of;  // frames of the other image-linked pieces: the piece's first frame
  for (const auto& members : solution_->other_components)
    for (int id : members) piece_of[id] = members.front();
  const Mat3 world = WorldFromPixel3(georef_.world_from_pixel);
  std::vector<BridgeFrame> frames;
  std::vector<double> lat, lon;
  *candidates = 0;
  for (const SessionFrame& f : record_->frames()) {
    std::error_code ec;
    const bool in = in_map.contains(f.id);
    if (!in && (f.stored_file.empty() || !std::filesystem::exists(f.stored_file, ec))) continue;
    BridgeFrame b;
    b.id = f.id;
    b.size = f.original_size;
    if (in) {
      b.world_from_frame = world * canvas_from_original_[static_cast<size_t>(f.id)];
    } else {
      ++*candidates;
      const auto it = piece_of.find(f.id);
      b.piece = it != piece_of.end() && record_->engine().placed(f.id) ? it->second : f.id;
      if (record_->engine().placed(f.id))
        b.piece_from_frame = record_->engine().mosaic_from_work(f.id) * f.work_from_original();
    }
    const auto& m = f.metadata();
    b.height_m = m.relative_altitude_m;
    b.altitude_m = m.altitude_m;
    b.heading_deg = m.flight_yaw_deg;
    if (m.latitude_deg && m.longitude_deg && !(*m.latitude_deg == 0 && *m.longitude_deg == 0)) {
      b.position = Vec2::Zero();  // projected below, all at once
      lat.push_back(*m.latitude_deg);
      lon.push_back(*m.longitude_deg);
    }
    frames.push_back(b);
  }
  std::vector<Vec2> xy;
  std::string error;
  if (!LatLonToProjected(georef_.epsg, lat, lon, &xy, &error)) {
    spdlog::warn("bridge: {}", error);
    for (auto& b : frames) b.position.reset();
    return frames;
  }
  size_t k = 0;
  for (auto& b : frames)
    if (b.position) b.position = xy[k++];
  return frames;
}

void CanvasPlacement::BridgeFrames() {
  bridge_report_ = {{"frames_placed", 0}, {"pieces_placed", 0}};
  if (placed_.empty() || placed_.size() == record_->size()) return;
  if (!georef_.ok) {
    bridge_report_["reason"] = "the map is not georeferenced: nothing to place the other frames on";
    return;
  }
  int candidates = 0;
  const std::vector<BridgeFrame> inputs = BridgeInputs(&candidates);
  if (candidates == 0) return;
  const BridgeResult r = PlaceByTelemetry(inputs, options_.bridge);
  bridge_report_ = BridgeJson(r, candidates);
  if (!r.calibrated) {
    spdlog::warn("bridge: {} frames not placed ({})", candidates, r.failure);
    return;
  }
  const Mat3 pixel_from_world = WorldFromPixel3(georef_.world_from_pixel).inverse();
  std::vector<int> added;
  for (const BridgePlacement& p : r.placed) {
    canvas_from_original_[static_cast<size_t>(p.id)] = pixel_from_world * p.world_from_frame;
    added.push_back(p.id);
  }
  std::vector<int> all = placed_;
  all.insert(all.end(), added.begin(), added.end());
  if (!GrowCanvas(all)) {
    bridge_report_["frames_placed"] = 0;
    bridge_report_["reason"] = "the placed frames would make the canvas exceed max_canvas_side";
    return;
  }
  placed_ = std::move(all);
  placed_by_telemetry_.insert(added.begin(), added.end());
  spdlog::info(
      "bridge: {} frames in {} pieces placed by telemetry ({} of them single, turned by their heading), {} "
      "without",
      added.size(), r.pieces_placed, r.rotation_from.count("heading") ? r.rotation_from.at("heading") : 0,
      candidates - static_cast<int>(added.size()));
}

// Grows the canvas (and shifts every placed frame and the georeference) to hold `placed`; false, with nothing
// changed, when that would exceed max_canvas_side.
bool CanvasPlacement::GrowCanvas(const std::vector<int>& placed) {
  const Bounds2 box =
      FootprintBounds(placed, canvas_from_original_, [this](int id) { return record_->frame(id).original_size; },
                      {0, 0, canvas_.width - 1.0, canvas_.height - 1.0});
  const double x0 = std::floor(box.minx), y0 = std::floor(box.miny);
  const double w = std::ceil(box.maxx) - x0 + 1, h = std::ceil(box.maxy) - y0 + 1;
  if (std::max(w, h) > options_.max_canvas_side) {
    spdlog::warn("bridge: the canvas would grow to {:.0f}x{:.0f} (max_canvas_side {}): no frame placed by telemetry", w,
                 h, options_.max_canvas_side);
    return false;
  }
  const Mat3 shift = Translation(-x0, -y0);
  for (int id : placed)
    canvas_from_original_[static_cast<size_t>(id)] = shift * canvas_from_original_[static_cast<size_t>(id)];
  georef_.world_from_pixel = (WorldFromPixel3(georef_.world_from_pixel) * shift.inverse()).topRows<2>();
  canvas_ = cv::Size(static_cast<int>(w), static_cast<int>(h));
  return true;
}

nlohmann::json CanvasPlacement::BridgeJson(const BridgeResult& r, int candidates) {
  nlohmann::json j = {{"frames_placed", r.placed.size()},
                      {"pieces_placed", r.pieces_placed},
                      {"candidates", candidates},
                      {"frames_without_position", r.frames_without_position},
                      {"reference_frames", r.reference_frames}};
  if (!r.calibrated) {
    j["reason"] = r.failure;
    return j;
  }
  j["rotation_from"] = r.rotation_from;  // single frames, by source
  j["offset_from"] = r.offset_from;
  j["heading_offset_deg"] = r.heading_offset_deg;
  j["heading_rms_deg"] = r.heading_rms_deg;
  j["heading_sense"] = r.heading_sense > 0 ? "clockwise" : "counter-clockwise";
  j["metres_per_px_per_metre_height"] = r.metres_per_px_per_metre;
  if (r.metres_per_px_per_metre_altitude > 0) {
    j["metres_per_px_per_metre_altitude"] = r.metres_per_px_per_metre_altitude;
    j["ground_altitude_m"] = r.ground_altitude_m;
  }
  j["metres_per_px_median"] = r.metres_per_px;
  return j;
}

}  // namespace uavm
