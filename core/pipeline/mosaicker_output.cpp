// Session outputs of the Mosaicker: transforms, graph, correspondences, mosaic and report.
#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <sstream>
#include <string_view>
#include <unordered_set>

#include "core/mosaic/gdal_writer.h"
#include "core/pipeline/mosaicker.h"
#include "core/util/clock.h"
#include "core/util/memory.h"

namespace uavm {

namespace {

// Decodes a stored frame no larger than needed: JPEG DCT scaling by 1/f when the canvas samples it that coarsely.
// How a stored frame is read for the canvas: JPEG DCT-scaled decode by 1/reduce, then resized to `size` (the
// canvas's own sampling of the frame), so cached images are no larger than the canvas needs.
struct CanvasLoad {
  int reduce = 1;
  cv::Size size;
};

cv::Mat LoadForCanvas(const std::string& path, const CanvasLoad& how) {
  const int flag = how.reduce >= 8   ? cv::IMREAD_REDUCED_COLOR_8
                   : how.reduce >= 4 ? cv::IMREAD_REDUCED_COLOR_4
                   : how.reduce >= 2 ? cv::IMREAD_REDUCED_COLOR_2
                                     : cv::IMREAD_COLOR;
  cv::Mat img;
  try {
    img = cv::imread(path, flag | cv::IMREAD_IGNORE_ORIENTATION);
  } catch (const cv::Exception&) {
    return {};
  }
  if (img.empty() || img.size() == how.size) return img;
  cv::Mat out;
  cv::resize(img, out, how.size, 0, 0, cv::INTER_AREA);
  return out;
}

nlohmann::json SummaryJson(const Summary& s) {
  return {{"median", s.median}, {"p95", s.p95}, {"max", s.max}, {"total", s.total}, {"count", s.count}};
}

}  // namespace

bool Mosaicker::WriteOutputs(const std::vector<int>& component, std::string* error) {
  std::unordered_set<int> in_component(component.begin(), component.end());
  // Canvas: mosaic_scale canvas pixels per original pixel of the median frame (in the reference frame's orientation),
  // shifted so the flight starts at (0,0). The median, not the reference frame: the first frame is often taken while
  // the drone still climbs (caliterra's is 80 m lower than the last ones), and the canvas should follow the survey.
  std::vector<Mat3> canvas_from_original(frames_.size(), Mat3::Identity());
  cv::Size canvas(0, 0);
  double scale = options_.mosaic_scale;
  if (!component.empty()) {
    const FrameState& ref = frames_[static_cast<size_t>(component.front())];
    std::vector<double> ref_px_per_px;
    for (int id : component) {
      const FrameState& f = frames_[static_cast<size_t>(id)];
      const Mat3 ref_from_original = ref.work_from_original.inverse() * mosaic_from_work_[id] * f.work_from_original;
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
        const Mat3 out_from_mosaic_work = pre * ResizeMap(scale, scale) * ref.work_from_original.inverse();
        double minx = 1e300, miny = 1e300, maxx = -1e300, maxy = -1e300;
        for (int id : component) {
          const FrameState& f = frames_[static_cast<size_t>(id)];
          canvas_from_original[static_cast<size_t>(id)] =
              out_from_mosaic_work * mosaic_from_work_[id] * f.work_from_original;
          for (const auto& p : Footprint(canvas_from_original[static_cast<size_t>(id)], f.original_size.width,
                                         f.original_size.height)) {
            minx = std::min<double>(minx, p.x);
            miny = std::min<double>(miny, p.y);
            maxx = std::max<double>(maxx, p.x);
            maxy = std::max<double>(maxy, p.y);
          }
        }
        const double w = std::ceil(maxx) - std::floor(minx) + 1;
        const double h = std::ceil(maxy) - std::floor(miny) + 1;
        if (std::max(w, h) > options_.max_canvas_side && attempt == 0) {
          const double shrink = options_.max_canvas_side / std::max(w, h);
          spdlog::warn("canvas {:.0f}x{:.0f} exceeds max_canvas_side {}; mosaic_scale {:.3f} -> {:.3f}", w, h,
                       options_.max_canvas_side, scale, scale * shrink);
          scale *= shrink * 0.999;
          continue;
        }
        const Mat3 shift = Translation(-std::floor(minx), -std::floor(miny));
        for (int id : component)
          canvas_from_original[static_cast<size_t>(id)] = shift * canvas_from_original[static_cast<size_t>(id)];
        canvas = cv::Size(static_cast<int>(w), static_cast<int>(h));
        break;
      }
    };
    place(Mat3::Identity());
    georef_ = GeorefCanvas(component, &canvas_from_original, place);
  }

  // transforms.csv
  std::vector<TransformRow> rows;
  for (const auto& f : frames_) {
    TransformRow r;
    r.index = f.id;
    r.filename = f.name;
    r.registered = in_component.count(f.id) != 0;
    r.mosaic_from_frame = canvas_from_original[static_cast<size_t>(f.id)];
    rows.push_back(r);
  }
  if (!WriteFileAtomic(paths_.Join("transforms.csv"), FormatTransformsCsv(rows), error)) return false;

  // graph.csv and correspondences.csv (original-resolution pixels, so the ground tool needs no working sizes).
  // correspondences.csv grows with the flight (~5 kB per edge): it is streamed to disk, edge by edge, and an edge
  // whose points are only in edges.bin is read, written and given back.
  std::ostringstream graph_csv;
  graph_csv << "src,tgt,src_file,tgt_file,matches,inliers,used\n";
  AtomicFileWriter corr_csv;
  if (!corr_csv.Open(paths_.Join("correspondences.csv"), error)) return false;
  corr_csv.Write("src,tgt,x_src,y_src,x_tgt,y_tgt\n");
  for (Edge& e : graph_.mutable_edges()) {
    const bool used = in_component.count(e.src) != 0 && in_component.count(e.tgt) != 0 &&
                      graph_.EdgeCounts(e, options_.relative_inlier_fraction, options_.matching.min_inliers);
    graph_csv << e.src << ',' << e.tgt << ',' << frames_[static_cast<size_t>(e.src)].name << ','
              << frames_[static_cast<size_t>(e.tgt)].name << ',' << e.num_matches << ',' << e.num_inliers << ','
              << (used ? 1 : 0) << '\n';
    std::string load_error;
    if (!edge_store_.Load(&e, &load_error)) {
      spdlog::warn("correspondences.csv: edge {}-{} left out ({})", e.src, e.tgt, load_error);
      continue;
    }
    const Mat3 src_orig = frames_[static_cast<size_t>(e.src)].work_from_original.inverse();
    const Mat3 tgt_orig = frames_[static_cast<size_t>(e.tgt)].work_from_original.inverse();
    char line[160];
    for (size_t k = 0; k < e.src_points.size(); ++k) {
      const Vec2 a = Apply(src_orig, e.src_points[k]);
      const Vec2 b = Apply(tgt_orig, e.tgt_points[k]);
      const int n =
          std::snprintf(line, sizeof(line), "%d,%d,%.7g,%.7g,%.7g,%.7g\n", e.src, e.tgt, a.x(), a.y(), b.x(), b.y());
      corr_csv.Write(std::string_view(line, static_cast<size_t>(std::max(0, n))));
    }
    // The solves are done: the compositor gets the memory (the points stay in edges.bin).
    edge_store_.Release(&e);
  }
  if (!corr_csv.Commit(error)) return false;
  if (!WriteFileAtomic(paths_.Join("graph.csv"), graph_csv.str(), error)) return false;

  // frames.csv: what the ground tool and georeferencing need per frame; empty cells where metadata is absent.
  std::ostringstream frames_csv;
  frames_csv.precision(12);
  frames_csv << "index,filename,stored_file,width,height,timestamp_ns,registered,latitude_deg,longitude_deg,"
                "altitude_m,relative_altitude_m,flight_yaw_deg,gimbal_yaw_deg,gimbal_pitch_deg,focal_length_mm\n";
  const auto cell = [](const std::optional<double>& v) {
    std::ostringstream c;
    c.precision(12);
    if (v) c << *v;
    return c.str();
  };
  for (const auto& f : frames_) {
    const auto& m = f.metadata;
    frames_csv << f.id << ',' << f.name << ',' << std::filesystem::path(f.stored_file).filename().string() << ','
               << f.original_size.width << ',' << f.original_size.height << ',' << f.timestamp_ns << ','
               << (in_component.count(f.id) != 0 ? 1 : 0) << ',' << cell(m.latitude_deg) << ',' << cell(m.longitude_deg)
               << ',' << cell(m.altitude_m) << ',' << cell(m.relative_altitude_m) << ',' << cell(m.flight_yaw_deg)
               << ',' << cell(m.gimbal_yaw_deg) << ',' << cell(m.gimbal_pitch_deg) << ',' << cell(m.focal_length_mm)
               << '\n';
  }
  if (!WriteFileAtomic(paths_.Join("frames.csv"), frames_csv.str(), error)) return false;
  if (!WriteFileAtomic(paths_.Join("config.yaml"), ToYaml(options_), error)) return false;

  // Mosaic, tile by tile.
  CompositeResult composite;
  if (!component.empty()) {
    std::vector<CompositeInput> inputs;
    std::unordered_map<int, CanvasLoad> load_of;
    for (int id : component) {
      const FrameState& f = frames_[static_cast<size_t>(id)];
      const Mat3& c = canvas_from_original[static_cast<size_t>(id)];
      // Canvas pixels per original pixel; the frame is loaded at that sampling (never above its own resolution).
      const double local_scale =
          LocalScale(c, Vec2(0.5 * (f.original_size.width - 1), 0.5 * (f.original_size.height - 1)));
      const double keep = std::min(1.0, local_scale);
      CanvasLoad how;
      // DCT-scaled decoding is 2-3x cheaper than full; allow the final resize to enlarge by up to 1.25x for it.
      while (how.reduce < 8 && 1.25 / (how.reduce * 2) >= keep) how.reduce *= 2;
      how.size = cv::Size(std::max(1, static_cast<int>(std::lround(f.original_size.width * keep))),
                          std::max(1, static_cast<int>(std::lround(f.original_size.height * keep))));
      load_of[id] = how;
      CompositeInput in;
      in.id = id;
      in.image_size = how.size;
      in.canvas_from_image = c * ResizeMap(static_cast<double>(how.size.width) / f.original_size.width,
                                           static_cast<double>(how.size.height) / f.original_size.height)
                                     .inverse();
      inputs.push_back(in);
    }
    auto load = [&](int id) { return LoadForCanvas(frames_[static_cast<size_t>(id)].stored_file, load_of[id]); };
    GdalTiffWriter tiff;
    const bool write_tiff = options_.write_tiff;
    // The compositor writes a tiled GeoTIFF; MakeProducts() copies it into the COG mosaic.tif.
    if (write_tiff &&
        !tiff.Open(paths_.Join("mosaic.tiled.tif"), canvas, options_.mosaic.tiff_block, options_.mosaic.tile_size,
                   options_.mosaic.build_overviews, options_.mosaic.gdal_cache_mib, error))
      return false;
    composite = Composite(inputs, canvas, load, options_.mosaic, write_tiff ? &tiff : nullptr);
    if (!composite.ok) {
      *error = "composite failed: " + composite.error;
      return false;
    }
    if (write_tiff && georef_.ok) tiff.SetGeoreference(GdalGeoTransform(georef_.world_from_pixel), georef_.crs_wkt);
    if (write_tiff && !tiff.Close(error)) return false;
    composite_ms_ = composite.ms;
    compose_peak_rss_mib_ = HighWaterRssMiB();
    std::vector<uchar> png;
    if (!cv::imencode(".png", composite.quicklook, png) ||
        !WriteFileAtomic(paths_.Join("mosaic.png"), std::string(png.begin(), png.end()), error))
      return false;
    spdlog::info("mosaic {}x{} px (scale {:.3f}), {} frames blended, {} dropped by overlap, {} tiles, {:.0f} ms",
                 canvas.width, canvas.height, scale, composite.frames_used, composite.frames_dropped_by_overlap,
                 composite.tiles_written, composite.ms);
  }
  nlohmann::json products = MakeProducts(component, canvas_from_original, options_.write_tiff && !component.empty());
  {
    std::string err;
    if (options_.preview_every > 0 && !preview_.Write(paths_.Join("live.jpg"), &err))
      spdlog::warn("live preview: {}", err);
  }

  // report.json
  nlohmann::json report;
  report["version"] = UAVM_VERSION;
  report["frames_in"] = frames_.size() + skipped_.size();
  report["frames_decoded"] = frames_.size();
  report["registered"] = final_registered_;
  report["dropped_by_queue"] = dropped_frames_;
  report["camera"] = {{"captured", capture_.captured},
                      {"dropped_in_source", capture_.dropped},
                      {"driver_gaps", capture_.driver_gaps},
                      {"reconnects", capture_.reconnects}};
  report["residual_rms_px"] = final_rms_;
  report["residual_median_px"] = residual_median_;
  report["residual_units"] = refine_.ok ? "transfer error, pixels of the target frame at working resolution"
                                        : "pixels of the reference frame at working resolution";
  report["holdout_rms_px"] = holdout_final_.rms;
  report["holdout_median_px"] = holdout_final_.median;
  report["holdout_points"] = holdout_final_.count;
  report["holdout_inlier_rms_px"] = holdout_inliers_.rms;
  report["holdout_inlier_share"] =
      holdout_final_.count > 0 ? static_cast<double>(holdout_inliers_.count) / static_cast<double>(holdout_final_.count)
                               : 0.0;
  report["model"] = refine_.ok ? ToString(refined_model_) : "affine";
  report["refine"] = {{"ok", refine_.ok},
                      {"failure", refine_.failure},
                      {"iterations", refine_.iterations},
                      {"initial_rms_px", refine_.initial_rms_px},
                      {"final_rms_px", refine_.final_rms_px},
                      {"final_all_rms_px", refine_.final_all_rms_px},
                      {"inliers", refine_.final_inliers},
                      {"outliers_removed", refine_.outliers},
                      {"solver_correspondences", refine_.num_used},
                      {"holdout_linear_rms_px", holdout_linear_.rms},
                      {"correspondences", refine_.num_residuals},
                      {"seconds", refine_.seconds}};
  report["wall_s"] = static_cast<double>(MonotonicNs() - start_ns_) * 1e-9;  // this run's, after a resume too
  report["resumed_frames"] = resumed_frames_;
  report["open_fds"] = {{"flight_start", fds_at_start_}, {"flight_end", fds_at_flight_end_}};
  report["log"] = {{"warnings", LogWarnings()}, {"errors", LogErrors()}};
  report["journal_syncs"] = journal_.syncs();
  report["peak_rss_mib"] = PeakRssMiB();
  report["reference_frame"] = component.empty() ? -1 : component.front();
  report["relocalized"] = relocalized_;
  report["joined_on_retry"] = retried_ok_;
  report["component_merges"] = merges_;
  report["edges"] = graph_.edges().size();
  report["edges_added_at_end"] = densified_edges_;
  report["feature_store"] = {{"disk_loads", feature_store_.disk_loads()}, {"evictions", feature_store_.evictions()}};
  const MemoryPlan& mp = memory_plan_;
  report["memory"] = {
      {"budget_mib", mp.budget_mib},
      {"peak_rss_mib", std::max({PeakRssMiB(), flight_peak_rss_mib_, solve_peak_rss_mib_, compose_peak_rss_mib_})},
      // Each phase's own peak (the kernel's high-water mark is reset between phases).
      {"phase_peak_rss_mib",
       {{"flight", flight_peak_rss_mib_}, {"solve", solve_peak_rss_mib_}, {"compose", compose_peak_rss_mib_}}},
      {"flight_peak_rss_mib", flight_peak_rss_mib_},
      {"flight_end_rss_mib", flight_end_rss_mib_},
      {"flight_end_heap",
       {{"in_use_mib", flight_end_heap_.in_use_mib},
        {"arena_mib", flight_end_heap_.arena_mib},
        {"mmapped_mib", flight_end_heap_.mmapped_mib}}},
      {"plan_flight_mib", mp.FlightMiB()},
      {"plan_end_mib", mp.EndMiB()},
      {"plan",
       {{"baseline_mib", mp.baseline_mib},
        {"graph_mib", mp.graph_mib},
        {"sift_mib", mp.sift_mib},
        {"sift_bands", mp.sift_bands},
        {"queue_mib", mp.queue_mib},
        {"queue_capacity", mp.queue_capacity},
        {"feature_cache_mib", mp.feature_cache_mib},
        {"relocalization_mib", mp.relocalization_mib},
        {"relocalization_descriptors", mp.relocalization_descriptors},
        {"refine_mib", mp.refine_mib},
        {"refine_correspondences", mp.refine_correspondences},
        {"image_cache_mib", mp.image_cache_mib},
        {"blend_mib", mp.blend_mib},
        {"gdal_cache_mib", mp.gdal_cache_mib},
        {"tile_size", options_.mosaic.tile_size},
        {"compositor_threads", options_.mosaic.threads}}},
      // What did not fit and went to disk or was thinned, so that the budget held.
      {"spilled",
       {{"feature_sets_evicted", feature_store_.evictions()},
        {"feature_sets_reloaded", feature_store_.disk_loads()},
        {"relocalization_thinnings", global_index_.thinnings()},
        {"frames_not_indexed_same_ground", frames_not_indexed_},
        {"edges_to_disk", edges_released_},
        {"edge_mib_to_disk", static_cast<double>(edge_bytes_released_) / (1 << 20)},
        {"edges_reloaded_in_flight", edges_reloaded_},
        {"edges_bin_mib", static_cast<double>(edge_store_.bytes_written()) / (1 << 20)},
        {"frame_redecodes", std::max(0, composite.image_loads - composite.frames_used)},
        {"refine_correspondences_skipped", refine_.num_residuals - std::min(refine_.num_residuals, refine_.num_used)},
        {"frames_dropped_by_queue", dropped_frames_}}}};
  nlohmann::json skipped = nlohmann::json::array();
  for (const auto& s : skipped_) skipped.push_back({{"file", s.file}, {"reason", s.reason}});
  report["skipped"] = skipped;
  nlohmann::json unregistered = nlohmann::json::array();
  for (const auto& f : frames_)
    if (in_component.count(f.id) == 0)
      unregistered.push_back({{"index", f.id}, {"file", f.name}, {"reason", f.failure}});
  report["unregistered"] = unregistered;
  nlohmann::json stages;
  for (const auto& name : stats_.Stages()) stages[name] = SummaryJson(stats_.Get(name));
  report["stages_ms"] = stages;
  report["composite_ms"] = composite_ms_;
  report["mosaic"] = {{"width", canvas.width},
                      {"height", canvas.height},
                      {"scale", options_.mosaic_scale},  // canvas px per original px of the median frame
                      {"canvas_px_per_reference_px", scale},
                      {"frames_blended", composite.frames_used},
                      {"frames_dropped_by_overlap", composite.frames_dropped_by_overlap},
                      {"frames_unreadable", composite.frames_unreadable},
                      {"tiles", composite.tiles_written},
                      {"image_loads", composite.image_loads}};
  report["georef"] = GeorefJson();
  report["products"] = products;
  return WriteFileAtomic(paths_.Join("report.json"), report.dump(2) + "\n", error);
}

}  // namespace uavm
