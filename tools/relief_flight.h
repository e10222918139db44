#pragma once
#include <nlohmann/json.hpp>
#include <string>

// A survey flown over a synthetic scene with relief (core/eval/relief_scene.h), written as a replayable flight with
// its truth, and the ground tool's products measured against that truth. For `uavmosaic-relief`, the tests and bench/.
namespace uavm::tools {

struct ReliefFlightOptions {
  uint32_t seed = 1;
  double half_extent_m = 60.0;  // the scene: [-half, half]^2 metres around the origin
  int buildings = 8;            // 8-25 m tall
  int trees = 20;               // 6-14 m tall
  int width = 1000, height = 750;
  double hfov_deg = 65.0;
  double altitude_m = 70.0;  // above the ground at the origin
  double forward_overlap = 0.8;
  double side_overlap = 0.7;
  double gps_sigma_m = 1.5;           // reported positions: horizontal noise per axis
  double gps_vertical_sigma_m = 2.0;  // and vertical
  double tilt_sigma_deg = 2.0;        // the gimbal's pointing error about nadir
  double k1 = -0.06, k2 = 0.02;       // the lens
  int jpeg_quality = 95;
  // Surveyed targets on open ground, each clicked in the frames that see it: OUT/gcp_list.txt (OpenDroneMap format)
  // and OUT/gcp_list_no_heights.txt (every height 0, as a handheld GPS survey gives them).
  int targets = 9;
  double survey_sigma_m = 0.02;
  double click_sigma_px = 0.5;
  // The scene's place: its origin at this UTM 15N easting / northing, heights above this datum.
  double easting = 576000.0, northing = 5188000.0, datum_m = 300.0;
  [[nodiscard]] bool Check(std::string* why) const;
};

// Writes OUT/images/frame_NNNN.jpg (the frames, along strips that cover the scene), OUT/geo.txt (reported positions,
// OpenDroneMap format in EPSG:32615, for --telemetry geo:), OUT/geo_truth.txt, OUT/truth/{ortho,dsm,dtm,cover}.tif (the
// truth from above at the flight's GSD, georeferenced in EPSG:32615; cover: 0 ground, 1 building, 2 tree) and
// OUT/truth/flight.json (camera, scene, poses), OUT/gcp_list.txt and OUT/gcp_list_no_heights.txt (the targets; the
// summary's "checkpoints" names every third, to be kept out of the adjustment). Returns a summary.
[[nodiscard]] bool WriteReliefFlight(const ReliefFlightOptions& options, const std::string& out_dir,
                                     nlohmann::json* summary, std::string* error);

// Measures an orthophoto (any georeferenced RGB(A) raster in the truth's CRS: the ground tool's ortho.tif, the
// onboard mosaic.tif) and, when given, a DSM (+ its fill mask) and a DTM against OUT/truth: the orthophoto's
// positional error by phase correlation of patches against the true orthophoto (in GSD, RMS and per cover class); the
// DSM's coverage of the scene and its height error on surfaces; the DTM's height error under buildings and trees.
struct ProductPaths {
  std::string ortho;
  std::string dsm;         // empty = not measured
  std::string dsm_filled;  // the ground tool's dsm_filled.tif (measured cells are its 0s)
  std::string dtm;         // empty = not measured
};
[[nodiscard]] bool CompareWithTruth(const std::string& flight_dir, const ProductPaths& products, nlohmann::json* report,
                                    std::string* error);

}  // namespace uavm::tools
