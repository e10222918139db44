// Bridging at the end of the flight: frames and pieces that no image links to the map, placed on the georeferenced
// canvas from their telemetry (core/georef/telemetry_bridge), and the canvas grown to hold them.
#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <unordered_map>
#include <unordered_set>

#include "core/georef/georef.h"
#include "core/pipeline/mosaicker.h"

namespace uavm {

// Frames of `placed` are the map's; the others that are stored in the session become the pieces bridging may place.
std::vector<BridgeFrame> Mosaicker::BridgeInputs(const std::vector<int>& placed,
                                                 const std::vector<Mat3>& canvas_from_original, int* candidates) {
  const std::unordered_set<int> in_map(placed.begin(), placed.end());
  std::unordered_map<int, int> piece_of;  // frames of the other image-linked pieces: the piece's first frame
  for (const auto& members : solution_.other_components)
    for (int id : members) piece_of[id] = members.front();
  const Mat3 world = WorldFromPixel3(georef_.world_from_pixel);
  std::vector<BridgeFrame> frames;
  std::vector<double> lat, lon;
  *candidates = 0;
  for (const FrameState& f : frames_) {
    std::error_code ec;
    const bool in = in_map.count(f.id) != 0;
    if (!in && (f.stored_file.empty() || !std::filesystem::exists(f.stored_file, ec))) continue;
    BridgeFrame b;
    b.id = f.id;
    b.size = f.original_size;
    if (in) {
      b.world_from_frame = world * canvas_from_original[static_cast<size_t>(f.id)];
    } else {
      ++*candidates;
      const auto it = piece_of.find(f.id);
      b.piece = it != piece_of.end() && engine_.placed(f.id) ? it->second : f.id;
      if (engine_.placed(f.id)) b.piece_from_frame = engine_.mosaic_from_work(f.id) * f.work_from_original;
    }
    const auto& m = f.metadata;
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

void Mosaicker::BridgeFrames(std::vector<int>* placed, std::vector<Mat3>* canvas_from_original, cv::Size* canvas) {
  bridge_report_ = {{"frames_placed", 0}, {"pieces_placed", 0}};
  if (placed->empty() || placed->size() == frames_.size()) return;
  if (!georef_.ok) {
    bridge_report_["reason"] = "the map is not georeferenced: nothing to place the other frames on";
    return;
  }
  int candidates = 0;
  const std::vector<BridgeFrame> inputs = BridgeInputs(*placed, *canvas_from_original, &candidates);
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
    (*canvas_from_original)[static_cast<size_t>(p.id)] = pixel_from_world * p.world_from_frame;
    added.push_back(p.id);
  }
  std::vector<int> all = *placed;
  all.insert(all.end(), added.begin(), added.end());
  if (!GrowCanvas(all, canvas_from_original, canvas)) {
    bridge_report_["frames_placed"] = 0;
    bridge_report_["reason"] = "the placed frames would make the canvas exceed max_canvas_side";
    return;
  }
  *placed = std::move(all);
  placed_by_telemetry_.insert(added.begin(), added.end());
  spdlog::info(
      "bridge: {} frames in {} pieces placed by telemetry ({} of them single, turned by their heading), {} "
      "without",
      added.size(), r.pieces_placed, r.rotation_from.count("heading") ? r.rotation_from.at("heading") : 0,
      candidates - static_cast<int>(added.size()));
}

// Grows the canvas (and shifts every placed frame and the georeference) to hold `placed`; false, with nothing
// changed, when that would exceed max_canvas_side.
bool Mosaicker::GrowCanvas(const std::vector<int>& placed, std::vector<Mat3>* canvas_from_original, cv::Size* canvas) {
  const Bounds2 box = FootprintBounds(placed, *canvas_from_original,
                                      [this](int id) { return frames_[static_cast<size_t>(id)].original_size; },
                                      {0, 0, canvas->width - 1.0, canvas->height - 1.0});
  const double x0 = std::floor(box.minx), y0 = std::floor(box.miny);
  const double w = std::ceil(box.maxx) - x0 + 1, h = std::ceil(box.maxy) - y0 + 1;
  if (std::max(w, h) > options_.max_canvas_side) {
    spdlog::warn("bridge: the canvas would grow to {:.0f}x{:.0f} (max_canvas_side {}): no frame placed by telemetry", w,
                 h, options_.max_canvas_side);
    return false;
  }
  const Mat3 shift = Translation(-x0, -y0);
  for (int id : placed)
    (*canvas_from_original)[static_cast<size_t>(id)] = shift * (*canvas_from_original)[static_cast<size_t>(id)];
  georef_.world_from_pixel = (WorldFromPixel3(georef_.world_from_pixel) * shift.inverse()).topRows<2>();
  *canvas = cv::Size(static_cast<int>(w), static_cast<int>(h));
  return true;
}

nlohmann::json Mosaicker::BridgeJson(const BridgeResult& r, int candidates) const {
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
