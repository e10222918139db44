#pragma once
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "core/sfm/cloud_and_dsm.h"
#include "core/sfm/reconstruction.h"
#include "core/sfm/reconstruction_options.h"

namespace uavm::sfm {

struct ReconstructionResult {
  Reconstruction rec;
  std::vector<CloudPoint> dense;  // fused cloud (world coordinates, relative to `offset`)
  cv::Mat1f dsm;                  // holes filled (FillDsmHoles)
  cv::Mat1b dsm_provenance;       // FillDsmHoles' mask: 255 measured, 128 filled, 0 none
  DsmGrid grid;
  std::vector<std::string> image_paths;              // the stored frame of each image of rec
  Eigen::Vector2d offset = Eigen::Vector2d::Zero();  // world x,y = local + offset (UTM easting/northing)
  double z_offset = 0.0;
  std::string crs_wkt;  // empty = local coordinates
  int epsg = 0;
  nlohmann::json summary;
};

// The whole offline reconstruction of a session: features, matching of graph.csv's used pairs, tracks, initial
// poses, triangulation, BA rounds, georeferencing, dense pairs, fusion, DSM.
[[nodiscard]] bool RunReconstruction(const std::string& session_dir, const ReconstructionOptions& options,
                                     const ProgressFn& progress, ReconstructionResult* result, std::string* error);

}  // namespace uavm::sfm
