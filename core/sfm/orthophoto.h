#pragma once
#include <functional>
#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <string>

#include "core/sfm/cloud_and_dsm.h"
#include "core/sfm/reconstruction.h"

// The ground tool's true orthophoto: every output pixel is a point of the DSM, seen through the adjusted cameras and
// lens. Visibility comes from a z-buffer of the DSM per frame, so ground hidden by a roof in one frame is taken from
// another and walls do not lean; each pixel goes to the most nadir frame that sees it, and the owners are multi-band
// blended (core/mosaic's TileBlender) tile by tile. (The onboard quick look, a homography mosaic, is core/mosaic.)
namespace uavm::sfm {

struct OrthoOptions {
  double gsd = 0.0;      // world units per ortho pixel; 0 = the reconstruction's median GSD
  int tile_size = 1024;  // ortho pixels per tile side
  int num_bands = 5;     // multi-band levels (0 = hard seams)
  int seam_cell = 2;     // ownership decided per seam_cell x seam_cell pixels
  // Every frame's depth map together: the z-buffers' resolution is chosen to fit it (at most a quarter of the frame's).
  double zbuffer_mib = 128.0;
  double image_cache_mib = 512.0;  // decoded frames kept between tiles (at least one per worker)
  // A surface point is seen by a frame when its depth is within this many DSM cells of the frame's z-buffer there.
  double occlusion_tolerance_cells = 1.5;
  int threads = 2;
  // Seams keep off what stands on the terrain: a connected region of the surface more than this above the terrain
  // (world units: metres when georeferenced) is taken whole from one frame, the most nadir one that sees all of it,
  // so that no seam cuts a roof or a crown; 0 (or no terrain given) = each cell from its own most nadir view.
  double object_height = 2.5;
  bool seams_off_objects = true;  // false: objects found and counted (the seams on them), each cell its own view
  [[nodiscard]] bool Check(std::string* why) const;
};

struct OrthoReport {
  DsmGrid grid;  // the orthophoto's pixels: cell = GSD, local coordinates as the DSM's
  int tiles = 0;
  int tiles_written = 0;   // tiles with at least one covered pixel
  int images_in_view = 0;  // posed frames whose view reaches the orthophoto (each a candidate where it does)
  int images_used = 0;     // frames that own at least one pixel (the most nadir view of somewhere)
  int images_unreadable = 0;
  size_t pixels_covered = 0;
  // Seam cells whose most nadir frame did not see them (occluded there) and that another frame took.
  size_t cells_taken_from_another_view = 0;
  // Seam cells that no frame saw unoccluded: filled from the most nadir frame regardless (counted, not hidden).
  size_t cells_occluded_everywhere = 0;
  // Standing objects (options.object_height): found, and taken whole from one frame; seam cells (a neighbour has
  // another owner) over the orthophoto, and those on a standing object.
  int objects = 0;
  int objects_taken_whole = 0;
  size_t seam_cells = 0;
  size_t seam_cells_on_objects = 0;
  size_t image_loads = 0;
  // Frames that see each kOverlapBlock x kOverlapBlock block of the orthophoto unoccluded (at its centre).
  static constexpr int kOverlapBlock = 16;
  cv::Mat1b overlap;
  double zbuffer_scale = 0.0;  // of the frames' resolution
  double zbuffer_mib = 0.0;
  double seconds = 0.0;
  [[nodiscard]] nlohmann::json ToJson() const;
};

// BGR8 frame at full resolution (the camera's size); empty = unreadable.
using OrthoImageLoad = std::function<cv::Mat(size_t image)>;
// Receives each tile (BGR8 and its coverage, 255 = covered) at `top_left` in ortho pixels, from one thread at a time.
using OrthoTileSink =
    std::function<bool(const cv::Mat& image, const cv::Mat& mask, cv::Point top_left, std::string* error)>;

// The orthophoto's grid over the DSM's extent at `gsd`.
[[nodiscard]] DsmGrid OrthoGridOver(const DsmGrid& dsm_grid, double gsd);

// The height of the surface at (x, y), bilinear between the DSM's cell centres (nodata neighbours left out); false
// where no neighbour has a height.
[[nodiscard]] bool SurfaceHeight(const cv::Mat1f& dsm, const DsmGrid& grid, float nodata, double x, double y,
                                 double* z);

// The orthophoto of `rec`'s posed images over `dsm` (heights, `nodata` where none: those pixels stay empty), on
// `ortho_grid`, tile by tile into `sink`. `terrain` (the DTM on the DSM's grid; empty: none) tells what stands on
// the ground, for the seams (options.object_height: 5 bytes a DSM cell for the objects' labels and mask, made once).
// Memory: the z-buffers (options.zbuffer_mib), the frame cache (options.image_cache_mib) and per worker a tile's blend
// (~40 bytes a pixel of tile + margin).
[[nodiscard]] bool MakeOrthophoto(const Reconstruction& rec, const cv::Mat1f& dsm, const cv::Mat1f& terrain,
                                  const DsmGrid& dsm_grid, float nodata, const DsmGrid& ortho_grid,
                                  const OrthoOptions& options, const OrthoImageLoad& load, const OrthoTileSink& sink,
                                  OrthoReport* report, std::string* error);

}  // namespace uavm::sfm
