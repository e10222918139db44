#pragma once
#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <string>

// The terrain model (DTM): the ground under buildings and trees, from the DSM by a simple morphological filter in the
// manner of SMRF (Pingel, Clarke & McBride 2013): progressively larger openings of the surface flag what rises above
// the ground faster than the terrain's slope allows, the flagged cells are interpolated from the ground around them,
// and the cells that lie close to that provisional terrain are the ground the DTM is made from. (No Debian 12 package
// has a ground classifier: PDAL, which has SMRF and a cloth simulation, is not in bookworm.)
namespace uavm::sfm {

struct TerrainOptions {
  double max_window_m = 24.0;          // the largest opening's radius: more than half the widest building
  double slope = 0.15;                 // rise per metre the terrain may have (SMRF's s)
  double elevation_threshold_m = 0.5;  // a cell within this (plus slope x cell) of the provisional DTM is ground
  double elevation_scaler = 1.25;      // SMRF's w_k: the threshold grows with the local slope of the provisional DTM
  [[nodiscard]] bool Check(std::string* why) const;
};

struct TerrainReport {
  int cells = 0;         // with a DSM height
  int ground_cells = 0;  // classified as ground
  int windows = 0;       // openings applied
  [[nodiscard]] nlohmann::json ToJson() const;
};

// The DTM on the DSM's grid (`cell` metres): heights of the ground, interpolated under what is not ground; nodata
// where the DSM has none. *ground (optional): 255 where the DSM cell is ground.
[[nodiscard]] cv::Mat1f TerrainFromDsm(const cv::Mat1f& dsm, float nodata, double cell, const TerrainOptions& options,
                                       cv::Mat1b* ground, TerrainReport* report);

}  // namespace uavm::sfm
