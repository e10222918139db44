// Radiometry of the Mosaicker: thumbnails during the flight, the solve over the component's edges at its end.
#include <spdlog/spdlog.h>

#include <algorithm>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <unordered_map>
#include <unordered_set>

#include "core/pipeline/mosaicker.h"
#include "core/util/clock.h"

namespace uavm {

namespace {

std::string ThumbPath(const std::string& dir, int id) {
  return dir + "/" + std::to_string(id) + ".png";
}

}  // namespace

// A thumbnail per frame on disk rather than in memory: the flight's memory stays flat however long it is, and the
// end-of-flight solve reads each back a few times (~30 KB each).
cv::Mat Mosaicker::StoreThumbnail(int id, const cv::Mat& work_bgr) {
  if (!options_.radiometry.enabled || work_bgr.empty()) return {};
  const std::string dir = paths_.Join("thumbs");
  if (!thumbs_dir_made_) {
    std::error_code ec;
    thumbs_dir_made_ = std::filesystem::create_directories(dir, ec) || std::filesystem::is_directory(dir, ec);
  }
  cv::Mat thumb = MakeThumbnail(work_bgr, options_.radiometry.thumb_long_side);
  try {
    if (!cv::imwrite(ThumbPath(dir, id), thumb)) spdlog::warn("radiometry: cannot write the thumbnail of frame {}", id);
  } catch (const cv::Exception& e) {
    spdlog::warn("radiometry: cannot write the thumbnail of frame {}: {}", id, e.what());
  }
  return thumb;
}

cv::Mat Mosaicker::LiveViewImage(int id, const cv::Mat& work_bgr, const cv::Mat& thumb, size_t edges_before) {
  if (!options_.radiometry.enabled || !options_.radiometry.vignetting || thumb.empty() ||
      (options_.preview_every <= 0 && !live_tiles_))
    return work_bgr;
  if (!live_radiometry_) live_radiometry_.emplace(options_.radiometry);
  live_radiometry_->AddFrame(id, thumb, work_bgr.size());
  const auto& edges = engine_.edges();
  for (size_t k = edges_before; k < edges.size(); ++k)
    live_radiometry_->AddEdge(edges[k].src, edges[k].tgt, edges[k].tgt_from_src);
  if (live_radiometry_->MaybeSolve()) {
    const RadiometryModel& m = live_radiometry_->model();
    spdlog::info("radiometry: live vignetting from the last frames: corner {:.3f} {:.3f} {:.3f}", m.Falloff(0, 1.0),
                 m.Falloff(1, 1.0), m.Falloff(2, 1.0));
  }
  if (!live_radiometry_->model().ok) return work_bgr;
  cv::Mat corrected = work_bgr.clone();
  CorrectRadiometry(live_radiometry_->model(), id, work_bgr.size(), cv::Point2d(), &corrected);
  return corrected;
}

void Mosaicker::SolveFrameRadiometry(const std::vector<int>& component) {
  radiometry_ = RadiometryModel{};
  if (!options_.radiometry.enabled || component.size() < 2) return;
  const StageTimer timer;
  const std::unordered_set<int> in_component(component.begin(), component.end());
  const std::string dir = paths_.Join("thumbs");
  // Edges come in flight order, so a small cache of thumbnails serves most of them.
  std::unordered_map<int, cv::Mat> thumbs;
  auto thumb_of = [&](int id) -> const cv::Mat& {
    if (thumbs.size() >= 64) thumbs.clear();
    auto it = thumbs.find(id);
    if (it == thumbs.end()) it = thumbs.emplace(id, cv::imread(ThumbPath(dir, id), cv::IMREAD_COLOR)).first;
    return it->second;
  };
  std::vector<const Edge*> edges;
  for (const Edge& e : engine_.edges())
    if (in_component.count(e.src) != 0 && in_component.count(e.tgt) != 0) edges.push_back(&e);
  // A long flight samples fewer points per edge (4 at least: the solve's memory grows with the frames and pairs, the
  // samples' with their count).
  const int per_edge = std::clamp(options_.radiometry.max_samples / std::max<int>(1, static_cast<int>(edges.size())), 4,
                                  options_.radiometry.samples_per_edge);
  std::vector<RadiometrySample> samples;
  samples.reserve(edges.size() * static_cast<size_t>(per_edge));
  for (const Edge* edge : edges) {
    const Edge& e = *edge;
    const cv::Mat& a = thumb_of(e.src);
    const cv::Mat& b = thumb_of(e.tgt);
    if (a.empty() || b.empty()) continue;
    SampleOverlap(e.src, e.tgt, a, b, frames_[static_cast<size_t>(e.src)].work_size,
                  frames_[static_cast<size_t>(e.tgt)].work_size, e.tgt_from_src, per_edge, &samples);
  }
  radiometry_ = SolveRadiometry(samples, component, options_.radiometry);
  radiometry_ms_ = timer.ElapsedMs();
  if (!radiometry_.ok) {
    spdlog::warn("radiometry: not corrected ({})", radiometry_.note);
    return;
  }
  // Each frame's gains beside transforms.csv: what the mosaic divided out (a reader can compare them with the
  // camera's recorded exposure, or undo them).
  std::string csv = "frame,name,gain_b,gain_g,gain_r\n";
  for (int id : component) {
    const cv::Vec3d g = radiometry_.Gain(id);
    csv += fmt::format("{},{},{:.5f},{:.5f},{:.5f}\n", id, frames_[static_cast<size_t>(id)].name, g[0], g[1], g[2]);
  }
  std::string error;
  if (!WriteFileAtomic(paths_.Join("radiometry.csv"), csv, &error)) spdlog::warn("radiometry: {}", error);
  spdlog::info(
      "radiometry: {} samples over {} edges, log RMS {:.4f} -> {:.4f}, corner falloff {:.3f} {:.3f} {:.3f}{} "
      "({:.0f} ms)",
      radiometry_.samples, radiometry_.edges, radiometry_.rms_log_before, radiometry_.rms_log_after,
      radiometry_.Falloff(0, 1.0), radiometry_.Falloff(1, 1.0), radiometry_.Falloff(2, 1.0),
      radiometry_.note.empty() ? "" : " (" + radiometry_.note + ")", radiometry_ms_);
}

nlohmann::json Mosaicker::RadiometryJson() const {
  nlohmann::json j = {{"enabled", options_.radiometry.enabled}, {"corrected", radiometry_.ok}};
  if (!options_.radiometry.enabled) return j;
  double min_gain = 1e9, max_gain = 0;
  for (const auto& [id, g] : radiometry_.log_gain)
    for (int c = 0; c < 3; ++c) {
      min_gain = std::min(min_gain, std::exp(g[c]));
      max_gain = std::max(max_gain, std::exp(g[c]));
    }
  j["samples"] = radiometry_.samples;
  j["edges"] = radiometry_.edges;
  j["rms_log_before"] = radiometry_.rms_log_before;
  j["rms_log_after"] = radiometry_.rms_log_after;
  j["vignetting"] = radiometry_.vignetting;
  j["corner_falloff_bgr"] = {radiometry_.Falloff(0, 1.0), radiometry_.Falloff(1, 1.0), radiometry_.Falloff(2, 1.0)};
  j["log_falloff_c1_c2_bgr"] = radiometry_.log_falloff;
  if (!radiometry_.log_gain.empty()) j["gain_range"] = {min_gain, max_gain};
  j["note"] = radiometry_.note;
  j["solve_ms"] = radiometry_ms_;
  return j;
}

}  // namespace uavm
