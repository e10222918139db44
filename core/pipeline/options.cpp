#include "core/pipeline/options.h"

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <functional>
#include <set>
#include <sstream>
#include <stdexcept>
#include <type_traits>
#include <variant>
#include <vector>

#include "core/util/fail.h"

namespace uavm {

namespace {

using FieldPtr = std::variant<int*, double*, bool*, size_t*, MotionModel*>;
struct Field {
  std::string section;  // "" = top level
  std::string key;
  FieldPtr ptr;
};

// The lens's keys (core/lens, the engine's lens_calibration).
std::vector<Field> LensFields(PipelineOptions& o) {
  return {
      {"camera", "k1", &o.camera.k1},
      {"camera", "k2", &o.camera.k2},
      {"camera", "p1", &o.camera.p1},
      {"camera", "p2", &o.camera.p2},
      {"camera", "focal_px", &o.camera.focal_px},
      {"camera", "database", &o.camera.database},
      {"camera", "self_calibrate", &o.lens_calibration.enabled},
      {"lens_calibration", "min_frames", &o.lens_calibration.min_frames},
      {"lens_calibration", "max_frames", &o.lens_calibration.max_frames},
      {"lens_calibration", "max_correspondences", &o.lens_calibration.max_correspondences},
      {"lens_calibration", "min_holdout_gain", &o.lens_calibration.min_holdout_gain},
      {"lens_calibration", "min_holdout_t", &o.lens_calibration.min_holdout_t},
      {"lens_calibration", "max_distortion", &o.lens_calibration.max_distortion},
      {"lens_calibration", "prior_weight", &o.lens_calibration.prior_weight},
      {"lens_calibration", "min_effect_px", &o.lens_calibration.min_effect_px},
      {"lens_calibration", "max_halves_disagreement", &o.lens_calibration.max_halves_disagreement},
      {"lens_calibration", "halves_below_gain", &o.lens_calibration.halves_below_gain},
      {"lens_calibration", "rematch", &o.lens_calibration.rematch},
      {"lens_calibration", "rematch_holdout_tolerance", &o.lens_calibration.rematch_holdout_tolerance},
  };
}

// The end-of-flight solves' keys (the engine's adjust and refine).
std::vector<Field> SolveFields(PipelineOptions& o) {
  return {
      {"adjust", "rigidity_weight", &o.adjust.rigidity_weight},
      {"adjust", "relative_linear_weight", &o.adjust.relative_linear_weight},
      {"adjust", "huber_px", &o.adjust.huber_px},
      {"adjust", "robust_iterations", &o.adjust.robust_iterations},
      {"adjust", "direct_max_frames", &o.adjust.direct_max_frames},
      {"adjust", "max_iterative_steps", &o.adjust.max_iterative_steps},
      {"refine", "huber_px", &o.refine.huber_px},
      {"refine", "max_frames_per_solve", &o.refine.max_frames_per_solve},
      {"refine", "max_linear_iterations", &o.refine.max_linear_iterations},
      {"refine", "choose_model", &o.refine.choose_model},
      {"refine", "homography_min_gain", &o.refine.homography_min_gain},
      {"refine", "nadir_weight", &o.refine.nadir_weight},
      {"refine", "rigidity_weight", &o.refine.rigidity_weight},
      {"refine", "max_perspective_ratio", &o.refine.max_perspective_ratio},
      {"refine", "outlier_px", &o.refine.outlier_px},
      {"refine", "max_iterations", &o.refine.max_iterations},
      {"refine", "max_correspondences", &o.refine.max_correspondences},
      {"refine", "max_seconds", &o.refine.max_seconds},
      {"refine", "threads", &o.refine.threads},
  };
}

std::vector<Field> SubpixelFields(PipelineOptions& o) {
  return {
      {"subpixel", "enabled", &o.subpixel.enabled},
      {"subpixel", "window", &o.subpixel.window},
      {"subpixel", "cache_frames", &o.subpixel.cache_frames},
      {"subpixel", "max_shift_px", &o.subpixel.max_shift_px},
      {"subpixel", "min_kept_fraction", &o.subpixel.min_kept_fraction},
  };
}

// One table drives loading, dumping and the unknown-key check, so they cannot disagree.
std::vector<Field> Fields(PipelineOptions& o) {
  // Top-level keys first: the YAML writer starts a section at each new one.
  std::vector<Field> fields = {
      {"", "work_long_side", &o.work_long_side},
      {"", "recent_candidates", &o.recent_candidates},
      {"", "overlap_candidates", &o.overlap_candidates},
      {"", "min_overlap_fraction", &o.min_overlap_fraction},
      {"", "relative_inlier_fraction", &o.relative_inlier_fraction},
      {"", "relocalization_candidates", &o.relocalization_candidates},
      {"", "bridge_candidates", &o.bridge_candidates},
      {"", "retry_list_size", &o.retry_list_size},
      {"", "retry_per_frame", &o.retry_per_frame},
      {"", "retry_max_attempts", &o.retry_max_attempts},
      {"", "full_solve_every", &o.full_solve_every},
      {"", "solve_window", &o.solve_window},
      {"", "end_correspondences", &o.end_correspondences},
      {"", "trim_heap_every", &o.trim_heap_every},
      {"", "journal_sync_every", &o.journal_sync_every},
      {"", "preview_every", &o.preview_every},
      {"", "preview_side", &o.preview_side},
      {"", "mosaic_scale", &o.mosaic_scale},
      {"", "max_canvas_side", &o.max_canvas_side},
      {"", "memory_budget_mib", &o.memory_budget_mib},
      {"", "max_flight_frames", &o.max_flight_frames},
      {"", "feature_cache_mib", &o.feature_cache_mib},
      {"", "queue_capacity", &o.queue_capacity},
      {"", "write_tiff", &o.write_tiff},
      {"", "model", &o.refine.model},
      {"features", "max_features", &o.features.max_features},
      {"features", "contrast_threshold", &o.features.contrast_threshold},
      {"features", "target_min_features", &o.features.target_min_features},
      {"features", "min_contrast_threshold", &o.features.min_contrast_threshold},
      {"features", "octave_layers", &o.features.octave_layers},
      {"features", "root_sift", &o.features.root_sift},
      {"features", "half_size", &o.features.half_size},
      {"features", "double_first_octave", &o.features.double_first_octave},
      {"features", "descriptor_samples_per_cell", &o.features.descriptor_samples_per_cell},
      {"features", "awake_workers", &o.features.awake_workers},
      {"features", "opencv_sift", &o.features.opencv_sift},
      {"features", "max_scale_space_mib", &o.features.max_scale_space_mib},
      {"features", "band_margin", &o.features.band_margin},
      {"matching", "ratio", &o.matching.ratio},
      {"matching", "flann_trees", &o.matching.flann_trees},
      {"matching", "flann_checks", &o.matching.flann_checks},
      {"matching", "flann_leaf_size", &o.matching.flann_leaf_size},
      {"matching", "min_inliers", &o.matching.min_inliers},
      {"matching", "max_scale_change", &o.matching.max_scale_change},
      {"matching", "max_anisotropy", &o.matching.max_anisotropy},
      {"matching", "max_edge_correspondences", &o.matching.max_edge_correspondences},
      {"matching", "correspondence_grid", &o.matching.correspondence_grid},
      {"matching", "average_cells", &o.matching.average_cells},
      {"matching", "holdout_correspondences", &o.matching.holdout_correspondences},
      {"matching", "max_guided_queries", &o.matching.max_guided_queries},
      {"matching", "ransac_max_error_px", &o.matching.ransac.max_error},
      {"matching", "ransac_confidence", &o.matching.ransac.confidence},
      {"matching", "ransac_min_iterations", &o.matching.ransac.min_iterations},
      {"matching", "ransac_max_iterations", &o.matching.ransac.max_iterations},
      {"relocalization", "descriptors_per_frame", &o.relocalization.descriptors_per_frame},
      {"relocalization", "max_descriptors", &o.relocalization.max_descriptors},
      {"relocalization", "min_votes", &o.relocalization.min_votes},
      {"relocalization", "ratio", &o.relocalization.ratio},
      {"relocalization", "rebuild_every_frames", &o.relocalization.rebuild_every_frames},
      {"relocalization", "keyframe_spacing", &o.relocalization.keyframe_spacing},
      {"mosaic", "tile_size", &o.mosaic.tile_size},
      {"mosaic", "tiff_block", &o.mosaic.tiff_block},
      {"mosaic", "num_bands", &o.mosaic.num_bands},
      {"mosaic", "max_covered_fraction", &o.mosaic.max_covered_fraction},
      {"mosaic", "quicklook_long_side", &o.mosaic.quicklook_long_side},
      {"mosaic", "image_cache_bytes", &o.mosaic.image_cache_bytes},
      {"mosaic", "compressed_share", &o.mosaic.compressed_share},
      {"mosaic", "decoded_cache_mib", &o.mosaic.decoded_cache_mib},
      {"mosaic", "build_overviews", &o.mosaic.build_overviews},
      {"mosaic", "threads", &o.mosaic.threads},
      {"mosaic", "gdal_cache_mib", &o.mosaic.gdal_cache_mib},
      {"radiometry", "enabled", &o.radiometry.enabled},
      {"radiometry", "vignetting", &o.radiometry.vignetting},
      {"radiometry", "thumb_long_side", &o.radiometry.thumb_long_side},
      {"radiometry", "samples_per_edge", &o.radiometry.samples_per_edge},
      {"radiometry", "max_samples", &o.radiometry.max_samples},
      {"radiometry", "gain_prior_weight", &o.radiometry.gain_prior_weight},
      {"radiometry", "colour_prior_weight", &o.radiometry.colour_prior_weight},
      {"radiometry", "huber_log", &o.radiometry.huber_log},
      {"radiometry", "min_vignetting_samples", &o.radiometry.min_vignetting_samples},
      {"radiometry", "max_corner_falloff", &o.radiometry.max_corner_falloff},
      {"radiometry", "flat_field", &o.radiometry.flat_field},
      {"radiometry", "hotspot", &o.radiometry.hotspot},
      {"radiometry", "min_holdout_gain", &o.radiometry.min_holdout_gain},
      {"radiometry", "direct_max_frames", &o.radiometry.direct_max_frames},
      {"radiometry", "iterative_tolerance", &o.radiometry.iterative_tolerance},
      {"radiometry", "max_iterative_steps", &o.radiometry.max_iterative_steps},
      {"georef", "inlier_threshold_m", &o.georef.inlier_threshold_m},
      {"georef", "min_points", &o.georef.min_points},
      {"georef", "affine_min_points", &o.georef.affine_min_points},
      {"georef", "affine_min_spread_m", &o.georef.affine_min_spread_m},
      {"georef", "allow_affine", &o.georef.allow_affine},
      {"bridge", "enabled", &o.bridge.enabled},
      {"bridge", "min_reference_frames", &o.bridge.min_reference_frames},
      {"bridge", "max_heading_rms_deg", &o.bridge.max_heading_rms_deg},
      {"bridge", "piece_fit_min_spread_m", &o.bridge.piece_fit_min_spread_m},
      {"products", "write", &o.write_products},
      {"products", "max_tiles", &o.tiles.max_tiles},
      {"live_tiles", "enabled", &o.live_tiles.enabled},
      {"live_tiles", "cache_tiles", &o.live_tiles.cache_tiles},
      {"live_tiles", "frame_cache", &o.live_tiles.frame_cache},
      {"live_tiles", "queue_images", &o.live_tiles.queue_images},
      {"live_tiles", "queue_jobs", &o.live_tiles.queue_jobs},
      {"live_tiles", "feather_px", &o.live_tiles.feather_px},
      {"live_tiles", "png_compression", &o.live_tiles.png_compression},
      {"live_tiles", "levels", &o.live_tiles.levels},
      {"live_tiles", "redraw_shift_px", &o.live_tiles.redraw_shift_px},
      {"live_tiles", "refit_shift_m", &o.live_tiles.refit_shift_m},
  };
  for (Field& f : SolveFields(o)) fields.push_back(std::move(f));
  for (Field& f : LensFields(o)) fields.push_back(std::move(f));
  for (Field& f : SubpixelFields(o)) fields.push_back(std::move(f));
  return fields;
}

}  // namespace

bool PipelineOptions::Check(std::string* why) const {
  if (work_long_side < 64 || work_long_side > 16384) return Fail(why, "work_long_side must be in [64,16384]");
  if (!RegistrationOptions::Check(why)) return false;
  if (trim_heap_every < 0) return Fail(why, "trim_heap_every must be >= 0 (0 = never)");
  if (journal_sync_every < 1) return Fail(why, "journal_sync_every must be >= 1");
  if (!georef.Check(why)) return false;
  if (!bridge.Check(why)) return false;
  if (tiles.max_tiles < 1) return Fail(why, "products.max_tiles must be >= 1");
  if (!live_tiles.Check(why)) return false;
  if (preview_every < 0 || preview_side < 64) return Fail(why, "preview_every >= 0 and preview_side >= 64");
  if (!(mosaic_scale > 0 && mosaic_scale <= 4)) return Fail(why, "mosaic_scale must be in (0,4]");
  if (max_canvas_side < 256) return Fail(why, "max_canvas_side must be >= 256");
  if (feature_cache_mib < 1) return Fail(why, "feature_cache_mib must be >= 1");
  if (memory_budget_mib < 0) return Fail(why, "memory_budget_mib must be >= 0 (0 = no budget)");
  if (max_flight_frames < 0) return Fail(why, "max_flight_frames must be >= 0");
  if (queue_capacity < 1 || queue_capacity > 1024) return Fail(why, "queue_capacity must be in [1,1024]");
  return features.Check(why) && mosaic.Check(why) && radiometry.Check(why) && camera.Check(why);
}

bool LoadOptionsYaml(const std::string& path, PipelineOptions* options, std::string* error,
                     const std::vector<std::string>& sections_read_elsewhere) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return Fail(error, "config " + path + ": cannot read");
  std::ostringstream text;
  text << in.rdbuf();  // an empty file leaves the text empty: the defaults
  return ParseOptionsYaml(text.str(), path, options, error, sections_read_elsewhere);
}

bool ParseOptionsYaml(const std::string& text, const std::string& origin, PipelineOptions* options, std::string* error,
                      const std::vector<std::string>& sections_read_elsewhere) {
  YAML::Node root;
  try {
    root = YAML::Load(text);
  } catch (const std::exception& e) {
    return Fail(error, "config " + origin + ": " + e.what());
  }
  if (root.IsNull()) return true;  // an empty file means defaults
  if (!root.IsMap()) return Fail(error, "config " + origin + ": top level must be a mapping");
  PipelineOptions o = *options;
  auto fields = Fields(o);
  std::set<std::string> known_sections;
  std::set<std::string> known_keys;
  for (const auto& f : fields) {
    if (!f.section.empty()) known_sections.insert(f.section);
    known_keys.insert(f.section.empty() ? f.key : f.section + "." + f.key);
  }
  // Keys that are not strings (e.g. a sequence as a key) make as<std::string>() throw: an error, never a crash.
  try {
    for (const auto& kv : root) {
      const std::string k = kv.first.as<std::string>();
      if (std::find(sections_read_elsewhere.begin(), sections_read_elsewhere.end(), k) != sections_read_elsewhere.end())
        continue;
      if (known_sections.count(k) != 0) {
        if (!kv.second.IsMap()) return Fail(error, "config " + origin + ": '" + k + "' must be a mapping");
        for (const auto& sub : kv.second) {
          const std::string full = k + "." + sub.first.as<std::string>();
          if (known_keys.count(full) == 0) return Fail(error, "config " + origin + ": unknown key '" + full + "'");
        }
      } else if (known_keys.count(k) == 0) {
        return Fail(error, "config " + origin + ": unknown key '" + k + "'");
      }
    }
  } catch (const std::exception& e) {
    return Fail(error, "config " + origin + ": " + e.what());
  }
  for (const auto& f : fields) {
    const YAML::Node node = f.section.empty() ? root[f.key] : root[f.section][f.key];
    if (!node) continue;
    const std::string name = f.section.empty() ? f.key : f.section + "." + f.key;
    try {
      std::visit(
          [&](auto* p) {
            using T = std::remove_pointer_t<decltype(p)>;
            if constexpr (std::is_same_v<T, MotionModel>) {
              if (!ParseMotionModel(node.as<std::string>(), p)) throw std::invalid_argument("model");
            } else {
              *p = node.as<T>();
            }
          },
          f.ptr);
    } catch (const std::invalid_argument&) {
      return Fail(error, "config " + origin + ": '" + name + "' must be affine or homography");
    } catch (const std::exception&) {
      return Fail(error, "config " + origin + ": '" + name + "' has the wrong type");
    }
  }
  std::string why;
  if (!o.Check(&why)) return Fail(error, "config " + origin + ": " + why);
  *options = o;
  return true;
}

std::string ToYaml(const PipelineOptions& options) {
  PipelineOptions copy = options;
  YAML::Emitter out;
  out << YAML::BeginMap;
  std::string open_section;
  for (const auto& f : Fields(copy)) {
    if (f.section != open_section) {
      if (!open_section.empty()) out << YAML::EndMap;
      out << YAML::Key << f.section << YAML::Value << YAML::BeginMap;
      open_section = f.section;
    }
    out << YAML::Key << f.key << YAML::Value;
    std::visit(
        [&](auto* p) {
          if constexpr (std::is_same_v<std::remove_pointer_t<decltype(p)>, MotionModel>)
            out << ToString(*p);
          else
            out << *p;
        },
        f.ptr);
  }
  if (!open_section.empty()) out << YAML::EndMap;
  out << YAML::EndMap;
  return std::string(out.c_str()) + "\n";
}

}  // namespace uavm
