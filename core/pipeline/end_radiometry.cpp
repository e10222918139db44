// Radiometry at the end of the flight: the solve over the component's edges from the session's thumbnails.
#include "core/pipeline/end_radiometry.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <opencv2/imgcodecs.hpp>
#include <unordered_map>
#include <utility>

#include "core/pipeline/session_stores.h"
#include "core/util/clock.h"
#include "core/util/id_set.h"
#include "core/util/memory.h"

namespace uavm {

namespace {
constexpr size_t kTrimEveryEdges = 5000;
}  // namespace

EndRadiometry SolveEndRadiometry(const FlightRecord& record, const std::vector<int>& component,
                                 const RadiometryOptions& options, const SessionPaths& paths) {
  EndRadiometry out;
  RadiometryModel& radiometry = out.model;
  if (!options.enabled || component.size() < 2) return out;
  const StageTimer timer;
  const IdSet in_component(component);
  const std::string dir = paths.Join("thumbs");
  // Edges come in flight order, so a small cache of thumbnails serves most of them.
  std::unordered_map<int, cv::Mat> thumbs;
  auto thumb_of = [&](int id) -> const cv::Mat& {
    if (thumbs.size() >= 64) thumbs.clear();
    auto it = thumbs.find(id);
    if (it == thumbs.end())
      it = thumbs.emplace(id, cv::imread(SessionStores::ThumbPath(dir, id), cv::IMREAD_COLOR)).first;
    return it->second;
  };
  std::vector<const Edge*> edges;
  for (const Edge& e : record.engine().edges())
    if (in_component.contains(e.src) && in_component.contains(e.tgt)) edges.push_back(&e);
  // A long flight samples fewer points per edge: the edges share max_samples, each at least one point (a fractional
  // share, accumulated in edge order), so the samples stop growing with the flight there.
  const double share =
      std::clamp(static_cast<double>(options.max_samples) / static_cast<double>(std::max<size_t>(1, edges.size())), 1.0,
                 static_cast<double>(options.samples_per_edge));
  std::vector<RadiometrySample> samples;
  samples.reserve(static_cast<size_t>(std::ceil(share * static_cast<double>(edges.size()))));
  for (size_t k = 0; k < edges.size(); ++k) {
    const Edge& e = *edges[k];
    const int count =
        static_cast<int>(std::floor(static_cast<double>(k + 1) * share) - std::floor(static_cast<double>(k) * share));
    // Copies (a reference count each): thumb_of(e.tgt) may empty the cache that a's reference would point into.
    const cv::Mat a = thumb_of(e.src);
    const cv::Mat b = thumb_of(e.tgt);
    if (a.empty() || b.empty()) continue;
    const cv::Size work_a = record.frame(e.src).work_size;
    const cv::Size work_b = record.frame(e.tgt).work_size;
    SampleOverlap({e.src, &a, work_a, HeadingOf(record.engine().mosaic_from_work(e.src), work_a)},
                  {e.tgt, &b, work_b, HeadingOf(record.engine().mosaic_from_work(e.tgt), work_b)}, e.tgt_from_src,
                  count, &samples);
    // A long flight's edges to earlier strips load most thumbnails again (~15 000 loads at 5000 frames, 300 at 200),
    // and each decode's short-lived buffers landed in other free holes of the heap: without giving the free pages
    // back as it goes, the sampling left ~9 MiB more resident at 5000 frames than it holds. A trim of that fragmented
    // heap costs ~0.35 s (every 500 edges took the phase from 5 to 22 s), so every 5000.
    if ((k + 1) % kTrimEveryEdges == 0) TrimHeap();
  }
  TrimHeap();
  // The choice of terms' copies of the samples and trial solves (~1 MB of equations each at 5000 frames, placed
  // wherever the heap had room) give their pages back before the final solves touch new ones.
  radiometry = SolveRadiometry(std::move(samples), component, options, TrimHeap);
  out.ms = timer.ElapsedMs();
  if (!radiometry.ok) {
    spdlog::warn("radiometry: not corrected ({})", radiometry.note);
    return out;
  }
  if (radiometry.failed_solves > 0)
    spdlog::warn(
        "radiometry: {} reweighting(s) of the gains did not reach the conjugate gradients' tolerance (in at most {} "
        "steps); each kept the pass before",
        radiometry.failed_solves, options.max_iterative_steps);
  // Each frame's gains beside transforms.csv: what the mosaic divided out (a reader can compare them with the
  // camera's recorded exposure, or undo them).
  std::string csv = "frame,name,gain_b,gain_g,gain_r\n";
  for (int id : component) {
    const cv::Vec3d g = radiometry.Gain(id);
    csv += fmt::format("{},{},{:.5f},{:.5f},{:.5f}\n", id, record.frame(id).name, g[0], g[1], g[2]);
  }
  std::string error;
  if (!WriteFileAtomic(paths.Join("radiometry.csv"), csv, &error)) spdlog::warn("radiometry: {}", error);
  const Hotspot& hot = radiometry.hotspot;
  spdlog::info(
      "radiometry: {} samples over {} edges, log RMS {:.4f} -> {:.4f}, corner falloff {:.3f} {:.3f} {:.3f}, flat "
      "field {}, hotspot {}{} ({:.0f} ms)",
      radiometry.samples, radiometry.edges, radiometry.rms_log_before, radiometry.rms_log_after,
      radiometry.Falloff(0, 1.0), radiometry.Falloff(1, 1.0), radiometry.Falloff(2, 1.0),
      radiometry.flat_field ? "kept" : "not kept",
      hot.found ? fmt::format("{:+.0f} % at ({:.2f}, {:.2f}) half-diagonals", 100 * (std::exp(hot.LogBoost(0)) - 1),
                              hot.antisolar_u, hot.antisolar_v)
                : "not found",
      radiometry.note.empty() ? "" : " (" + radiometry.note + ")", out.ms);
  return out;
}

nlohmann::json RadiometryJson(const EndRadiometry& end, const RadiometryOptions& options) {
  const RadiometryModel& radiometry = end.model;
  nlohmann::json j = {{"enabled", options.enabled}, {"corrected", radiometry.ok}};
  if (!options.enabled) return j;
  double min_gain = 1e9, max_gain = 0;
  for (const auto& [id, g] : radiometry.log_gain)
    for (int c = 0; c < 3; ++c) {
      min_gain = std::min(min_gain, std::exp(g[c]));
      max_gain = std::max(max_gain, std::exp(g[c]));
    }
  j["samples"] = radiometry.samples;
  j["edges"] = radiometry.edges;
  j["rms_log_before"] = radiometry.rms_log_before;
  j["rms_log_after"] = radiometry.rms_log_after;
  j["vignetting"] = radiometry.vignetting;
  j["corner_falloff_bgr"] = {radiometry.Falloff(0, 1.0), radiometry.Falloff(1, 1.0), radiometry.Falloff(2, 1.0)};
  j["log_falloff_c1_c2_bgr"] = radiometry.log_falloff;
  j["flat_field"] = radiometry.flat_field;
  if (radiometry.flat_field) j["log_flat_u_v_uu-vv_uv_ur2_vr2"] = radiometry.log_flat;
  const Hotspot& hot = radiometry.hotspot;
  nlohmann::json hotspot = {{"found", hot.found}};
  if (hot.found) {
    hotspot["peak_gain"] = std::exp(hot.LogBoost(0.0));
    hotspot["core_radius_half_diagonals"] = hot.CoreRadius();
    // Where a frame whose axes lie along the mosaic's sees the antisolar point (x right, y down).
    hotspot["antisolar_half_diagonals"] = {hot.antisolar_u, hot.antisolar_v};
    hotspot["log_weights"] = hot.weights;
    hotspot["sigmas_half_diagonals"] = Hotspot::kSigma;
  }
  j["hotspot"] = hotspot;
  // The held-out fifth of the edges' robust cost under each model tried (0: not tried): what chose the terms.
  j["holdout_cost_radial_flat_hotspot"] = radiometry.holdout_cost;
  if (!radiometry.log_gain.empty()) j["gain_range"] = {min_gain, max_gain};
  j["note"] = radiometry.note;
  // Conjugate gradients beyond radiometry.direct_max_frames: the most steps one solve took, and the reweightings whose
  // solve did not converge (each kept the pass before).
  j["iterative"] = radiometry.iterative;
  j["most_iterative_steps"] = radiometry.most_iterative_steps;
  j["failed_solves"] = radiometry.failed_solves;
  j["solve_ms"] = end.ms;
  return j;
}

}  // namespace uavm
