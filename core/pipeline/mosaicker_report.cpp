// report.json: what the run did, in one document (schema in README).
#include <spdlog/spdlog.h>

#include <algorithm>
#include <nlohmann/json.hpp>
#include <unordered_set>

#include "core/pipeline/mosaicker.h"
#include "core/util/clock.h"
#include "core/util/memory.h"

namespace uavm {

namespace {

nlohmann::json SummaryJson(const Summary& s) {
  return {{"median", s.median}, {"p95", s.p95}, {"max", s.max}, {"total", s.total}, {"count", s.count}};
}

}  // namespace

// The registration's part: residuals, refinement, the engine's counters.
void Mosaicker::ReportRegistration(nlohmann::json* out) const {
  nlohmann::json& report = *out;
  report["residual_rms_px"] = solution_.rms_px;
  report["residual_median_px"] = solution_.median_px;
  report["residual_units"] = solution_.refine.ok ? "transfer error, pixels of the target frame at working resolution"
                                                 : "pixels of the reference frame at working resolution";
  report["holdout_rms_px"] = solution_.holdout_final.rms;
  report["holdout_median_px"] = solution_.holdout_final.median;
  report["holdout_points"] = solution_.holdout_final.count;
  report["holdout_inlier_rms_px"] = solution_.holdout_inliers.rms;
  report["holdout_inlier_share"] =
      solution_.holdout_final.count > 0
          ? static_cast<double>(solution_.holdout_inliers.count) / static_cast<double>(solution_.holdout_final.count)
          : 0.0;
  report["model"] = solution_.refine.ok ? ToString(solution_.model) : "affine";
  report["refine"] = {{"ok", solution_.refine.ok},
                      {"failure", solution_.refine.failure},
                      {"iterations", solution_.refine.iterations},
                      {"initial_rms_px", solution_.refine.initial_rms_px},
                      {"final_rms_px", solution_.refine.final_rms_px},
                      {"final_all_rms_px", solution_.refine.final_all_rms_px},
                      {"inliers", solution_.refine.final_inliers},
                      {"outliers_removed", solution_.refine.outliers},
                      {"solver_correspondences", solution_.refine.num_used},
                      {"holdout_linear_rms_px", solution_.holdout_linear.rms},
                      {"holdout_other_model_rms_px", solution_.holdout_other_model_rms},
                      {"correspondences", solution_.refine.num_residuals},
                      {"seconds", solution_.refine.seconds}};
  const RegistrationCounters rc = engine_.counters();
  report["relocalized"] = rc.relocalized;
  report["joined_on_retry"] = rc.joined_on_retry;
  report["joined_where_telemetry_placed"] = rc.joined_where_telemetry_placed;
  report["component_merges"] = rc.component_merges;
  report["edges"] = engine_.edges().size();
  report["edges_added_at_end"] = rc.edges_added_at_end;
  report["feature_store"] = {{"disk_loads", feature_store_.disk_loads()}, {"evictions", feature_store_.evictions()}};
  const SubpixelCounters& sc = refiner_.counters();
  report["subpixel"] = {{"enabled", options_.subpixel.enabled},
                        {"cache_frames", options_.subpixel.cache_frames},
                        {"edges_refined", sc.edges_refined},
                        {"edges_not_cached", sc.edges_not_cached},
                        {"edges_kept_unrefined", sc.edges_kept_unrefined},
                        {"points_refined", sc.points_refined},
                        {"points_dropped", sc.points_dropped}};
}

// What the run took and what it gave up so that the memory budget held.
nlohmann::json Mosaicker::ReportMemory(const CompositeResult& composite) const {
  const RegistrationCounters rc = engine_.counters();
  const RefineResult& refine = solution_.refine;
  nlohmann::json memory = resources_.MemoryJson(memory_plan_);
  memory["plan"]["tile_size"] = options_.mosaic.tile_size;
  memory["plan"]["compositor_threads"] = options_.mosaic.threads;
  // What did not fit and went to disk or was thinned, so that the budget held.
  memory["spilled"] = {
      {"feature_sets_evicted", feature_store_.evictions()},
      {"feature_sets_reloaded", feature_store_.disk_loads()},
      {"relocalization_thinnings", rc.relocalization_thinnings},
      {"frames_not_indexed_same_ground", rc.frames_not_indexed},
      {"edges_to_disk", rc.edges_released},
      {"edge_mib_to_disk", static_cast<double>(rc.edge_bytes_released) / (1 << 20)},
      {"edges_reloaded_in_flight", rc.edges_reloaded},
      {"end_points_left_on_disk", rc.end_points_thinned},
      {"end_points_per_edge", rc.end_points_per_edge},
      {"edges_bin_mib", static_cast<double>(edge_store_.bytes_written()) / (1 << 20)},
      {"frame_redecodes", std::max(0, composite.image_loads - composite.frames_used)},
      {"refine_correspondences_skipped", refine.num_residuals - std::min(refine.num_residuals, refine.num_used)},
      {"frames_dropped_by_queue", dropped_frames_}};
  return memory;
}

bool Mosaicker::WriteReport(const std::vector<int>& component, const CompositeResult& composite, cv::Size canvas,
                            double scale, nlohmann::json products, std::string* error) const {
  nlohmann::json report;
  report["version"] = UAVM_VERSION;
  report["frames_in"] = frames_.size() + skipped_.size();
  report["frames_decoded"] = frames_.size();
  // Frames in the map: placed by images or, where no image linked them, by telemetry.
  report["registered"] = component.size();
  report["placed_by_image"] = component.size() - placed_by_telemetry_.size();
  report["placed_by_telemetry"] = placed_by_telemetry_.size();
  report["bridge"] = bridge_report_;
  report["dropped_by_queue"] = dropped_frames_;
  report["live_tiles"] = live_tiles_report_;
  report["camera"] = {{"captured", capture_.captured},
                      {"dropped_in_source", capture_.dropped},
                      {"driver_gaps", capture_.driver_gaps},
                      {"reconnects", capture_.reconnects}};
  report["wall_s"] = static_cast<double>(MonotonicNs() - start_ns_) * 1e-9;  // this run's, after a resume too
  report["resumed_frames"] = resumed_frames_;
  report["open_fds"] = resources_.FdsJson();
  report["log"] = {{"warnings", LogWarnings()}, {"errors", LogErrors()}};
  report["journal_syncs"] = journal_.syncs();
  report["peak_rss_mib"] = resources_.PeakRssMiB();  // every phase's: the high-water mark is never reset
  report["reference_frame"] = component.empty() ? -1 : component.front();
  ReportRegistration(&report);
  report["memory"] = ReportMemory(composite);
  nlohmann::json skipped = nlohmann::json::array();
  for (const auto& s : skipped_) skipped.push_back({{"file", s.file}, {"reason", s.reason}});
  report["skipped"] = skipped;
  const std::unordered_set<int> in_component(component.begin(), component.end());
  nlohmann::json unregistered = nlohmann::json::array();
  for (const auto& f : frames_)
    if (in_component.count(f.id) == 0)
      unregistered.push_back({{"index", f.id}, {"file", f.name}, {"reason", engine_.frame(f.id).failure}});
  report["unregistered"] = unregistered;
  nlohmann::json stages;
  for (const auto& name : stats_.Stages()) stages[name] = SummaryJson(stats_.Get(name));
  report["stages_ms"] = stages;
  report["composite_ms"] = composite.ms;
  report["mosaic"] = {{"width", canvas.width},
                      {"height", canvas.height},
                      {"scale", options_.mosaic_scale},  // canvas px per original px of the median frame
                      {"canvas_px_per_reference_px", scale},
                      {"frames_blended", composite.frames_used},
                      {"frames_dropped_by_overlap", composite.frames_dropped_by_overlap},
                      {"frames_unreadable", composite.frames_unreadable},
                      {"tiles", composite.tiles_written},
                      {"image_loads", composite.image_loads},
                      {"reloads_from_memory", composite.reloads_from_memory},
                      {"image_load_ms", composite.load_ms}};
  report["radiometry"] = RadiometryJson();
  report["lens"] = LensJson();
  report["georef"] = GeorefJson();
  report["products"] = products;
  for (const auto& [key, value] : report_sections_.items()) report[key] = value;
  return WriteFileAtomic(paths_.Join("report.json"), report.dump(2) + "\n", error);
}

}  // namespace uavm
