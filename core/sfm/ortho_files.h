#pragma once
#include <Eigen/Core>
#include <functional>
#include <string>
#include <vector>

#include "core/sfm/orthophoto.h"

// The orthophoto's files: a Cloud Optimized GeoTIFF (JPEG-compressed RGB with a mask, internal overviews), its
// quick-look PNG and, when the map has a CRS, an MBTiles package for ground stations that import offline maps and
// XYZ web tiles (core/georef's, as the onboard program writes them).
namespace uavm::sfm {

struct OrthoFiles {
  std::string cog;        // e.g. OUT/ortho.tif
  std::string quicklook;  // PNG (RGBA, transparent where no frame sees the ground); empty = none
  std::string mbtiles;    // empty = none (also none without a CRS)
  std::string tiles_dir;  // XYZ web tiles (z/x/y.png, EPSG:3857) as the onboard program writes them; empty = none
  int quicklook_long_side = 2000;
  int jpeg_quality = 90;
};

struct OrthoFilesReport {
  OrthoReport ortho;
  bool mbtiles_written = false;
  int web_tiles = 0;  // written to tiles_dir
  int web_min_zoom = 0, web_max_zoom = 0;
  std::vector<std::string> warnings;  // products not made (the orthophoto itself was)
  double write_seconds = 0.0;         // the COG's conversion, the quick-look and the MBTiles
  [[nodiscard]] nlohmann::json ToJson() const;
};

// The orthophoto of `rec` over `dsm` (local coordinates; the map's are + offset, in `crs_wkt`, empty = local) from
// the frames at `image_paths` (one per image of rec), written to `files`. Tiles go through a tiled GeoTIFF beside the
// COG (removed after), so no more than a tile of the map is ever in memory.
// `correct` (may be empty) is applied to each frame as it is read, before it is warped (e.g. the onboard radiometry
// divided out).
using OrthoFrameCorrection = std::function<void(size_t image, cv::Mat* bgr)>;
// `terrain` (the DTM on the DSM's grid, or empty) keeps the seams off what stands on it (MakeOrthophoto).
[[nodiscard]] bool WriteOrthophoto(const Reconstruction& rec, const std::vector<std::string>& image_paths,
                                   const cv::Mat1f& dsm, const cv::Mat1f& terrain, const DsmGrid& dsm_grid,
                                   float nodata, const Eigen::Vector2d& offset, const std::string& crs_wkt,
                                   const OrthoOptions& options, const OrthoFiles& files,
                                   const OrthoFrameCorrection& correct, OrthoFilesReport* report, std::string* error);

}  // namespace uavm::sfm
