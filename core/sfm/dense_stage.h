#pragma once
#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "core/sfm/cloud_and_dsm.h"
#include "core/sfm/dense.h"
#include "core/sfm/reconstruction.h"
#include "core/sfm/reconstruction_options.h"
#include "core/sfm/session_import.h"

namespace uavm::sfm {

// 8. Dense: stereo pairs of the adjusted images, their raw points and which pair made each.
struct DenseCloud {
  std::vector<CloudPoint> points;
  DenseReport report;
};

// Dense pairs of the adjusted images (none when options.dense is off); figures under (*js)["dense"].
[[nodiscard]] bool DenseStage(const std::string& session_dir, const std::vector<const SessionFrame*>& frames,
                              const Reconstruction& rec, const ReconstructionOptions& options,
                              const ProgressFn& progress, DenseCloud* out, nlohmann::json* js, std::string* error);

// 9. The surface: the fused cloud (the sparse points when dense made none) and the DSM rasterised from it, holes
// filled up to options.dsm_fill_cells and marked.
struct SurfaceModel {
  std::vector<CloudPoint> cloud;
  cv::Mat1f dsm;
  cv::Mat1b dsm_provenance;  // FillDsmHoles' mask: 255 measured, 128 filled, 0 none
  DsmGrid grid;
};

// The DSM cell: options.dsm_cell_m, or the dense sampling distance on the ground (20x the sparse GSD without dense
// points).
[[nodiscard]] double DsmCell(const Reconstruction& rec, bool have_dense, const ReconstructionOptions& options,
                             nlohmann::json* js);
// The grid covering the points' x, y extent, north up.
[[nodiscard]] DsmGrid GridOver(const std::vector<CloudPoint>& points, double cell);
// A dense stage that made nothing is a warning in the log and in (*js)["warnings"].
[[nodiscard]] SurfaceModel FuseAndRasterize(const DenseCloud& dense, const Reconstruction& rec,
                                            const ReconstructionOptions& options, nlohmann::json* js);

}  // namespace uavm::sfm
