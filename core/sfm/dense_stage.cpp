#include "core/sfm/dense_stage.h"

#include <algorithm>
#include <cmath>
#include <cstdio>

namespace uavm::sfm {

bool DenseStage(const std::string& session_dir, const std::vector<const SessionFrame*>& frames,
                const Reconstruction& rec, const ReconstructionOptions& options, const ProgressFn& progress,
                DenseCloud* out, nlohmann::json* js, std::string* error) {
  if (options.dense) {
    DenseOptions dopt;
    dopt.image_scale = options.dense_image_scale;
    dopt.sample_step = options.dense_sample_step;
    dopt.max_pairs = options.max_dense_pairs;
    dopt.pairs_per_image = options.dense_pairs_per_image;
    dopt.min_baseline_ratio = options.min_baseline_ratio;
    dopt.max_baseline_ratio = options.max_baseline_ratio;
    dopt.target_baseline_ratio = options.target_baseline_ratio;
    dopt.min_overlap = options.min_pair_overlap;
    dopt.threads = options.threads;
    dopt.daisy_cost = options.dense_daisy;
    std::vector<std::string> paths;
    for (const auto* f : frames) paths.push_back(session_dir + "/" + f->stored_file);
    if (!DenseFromReconstruction(rec, paths, dopt, progress, &out->points, &out->report, error)) return false;
  }
  (*js)["dense"] = out->report.ToJson();
  return true;
}

double DsmCell(const Reconstruction& rec, bool have_dense, const ReconstructionOptions& options, nlohmann::json* js) {
  const double gsd = rec.MedianGsd();
  double cell = options.dsm_cell_m;
  if (cell <= 0.0) {
    cell = !have_dense ? 20.0 * gsd : 1.5 * gsd * options.dense_sample_step / options.dense_image_scale;
  }
  (*js)["gsd_m"] = gsd;
  (*js)["dsm_cell"] = cell;
  return cell;
}

DsmGrid GridOver(const std::vector<CloudPoint>& points, double cell) {
  float x0 = 1e30f, x1 = -1e30f, y0 = 1e30f, y1 = -1e30f;
  for (const auto& p : points) {
    x0 = std::min(x0, p.xyz[0]);
    x1 = std::max(x1, p.xyz[0]);
    y0 = std::min(y0, p.xyz[1]);
    y1 = std::max(y1, p.xyz[1]);
  }
  DsmGrid g;
  g.cell = cell;
  g.x0 = std::floor(x0 / cell) * cell;
  g.y0 = std::ceil(y1 / cell) * cell;
  g.width = static_cast<int>(std::ceil((x1 - g.x0) / cell)) + 1;
  g.height = static_cast<int>(std::ceil((g.y0 - y0) / cell)) + 1;
  return g;
}

SurfaceModel FuseAndRasterize(const DenseCloud& dense, const Reconstruction& rec, const ReconstructionOptions& options,
                              nlohmann::json* summary) {
  nlohmann::json& js = *summary;
  SurfaceModel surface;
  std::vector<CloudPoint> sparse_cloud;
  for (const auto& p : rec.points) {
    sparse_cloud.push_back(
        {cv::Vec3f(static_cast<float>(p.X.x()), static_cast<float>(p.X.y()), static_cast<float>(p.X.z())), p.bgr});
  }
  const double cell = DsmCell(rec, !dense.points.empty(), options, &js);
  FusionReport fusion;
  std::vector<CloudPoint> fused;
  if (!dense.points.empty()) {
    fused = FuseClouds(dense.points, dense.report.point_pair, cell, options.fusion_tolerance_cells * cell,
                       options.fusion_min_pairs, &fusion);
  }
  const std::vector<CloudPoint>& dsm_source = fused.empty() ? sparse_cloud : fused;
  js["fusion"] = fusion.ToJson();
  js["dense_points"] = fused.size();
  const DsmGrid g = GridOver(dsm_source, cell);
  surface.grid = g;
  surface.dsm = RasterizeMedian(dsm_source, g, -9999.0f);
  surface.dsm_provenance = FillDsmHoles(&surface.dsm, -9999.0f, options.dsm_fill_cells);
  const double cells = std::max(1, g.width * g.height);
  js["dsm_measured_fraction"] = cv::countNonZero(surface.dsm_provenance == 255) / cells;
  js["dsm_filled_fraction"] = cv::countNonZero(surface.dsm_provenance == 128) / cells;
  js["dsm_size"] = {g.width, g.height};
  js["dsm_source"] = fused.empty() ? "sparse" : "dense";
  if (options.dense && fused.empty()) {
    // A stage that made nothing is said, in the log and the summary: the products fall back to the sparse points.
    const auto& failures = dense.report.failures;
    std::string why =
        std::to_string(dense.report.pairs.size()) + " stereo pair(s), " + std::to_string(failures.size()) + " refused";
    if (!failures.empty()) why += " (first: " + failures.front() + ")";
    const std::string warning =
        "dense matching made no point: " + why + "; cloud.ply and dsm.tif hold the sparse points";
    std::fprintf(stderr, "uavmosaic-ground: warning: %s\n", warning.c_str());
    js["warnings"].push_back(warning);
  }
  surface.cloud = fused.empty() ? std::move(sparse_cloud) : std::move(fused);
  return surface;
}

}  // namespace uavm::sfm
