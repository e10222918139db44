#pragma once
#include <Eigen/Core>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

// The ground tool's point cloud and DSM: the PLY file, the DSM raster and its GeoTIFF, PNG previews. (The onboard
// program's map products are core/georef/products.h.)
namespace uavm::sfm {

struct CloudPoint {
  cv::Vec3f xyz;
  cv::Vec3b bgr;
};

// Binary little-endian PLY: vertex x y z float, red green blue uchar.
[[nodiscard]] bool WritePly(const std::string& path, const std::vector<CloudPoint>& points, std::string* error);
// Reads what WritePly writes (and any binary_little_endian PLY with exactly those vertex properties).
[[nodiscard]] bool ReadPly(const std::string& path, std::vector<CloudPoint>* points, std::string* error);

// The raster grid of a DSM: cell (col, row) covers x in [x0 + col*cell, x0 + (col+1)*cell), y in
// [y0 - (row+1)*cell, y0 - row*cell) (north up).
struct DsmGrid {
  double x0 = 0.0, y0 = 0.0, cell = 1.0;
  int width = 0, height = 0;
};

// Per-cell median height of points whose (x, y) fall in the grid. Cells without a point are `nodata`.
[[nodiscard]] cv::Mat1f RasterizeMedian(const std::vector<CloudPoint>& points, const DsmGrid& grid, float nodata);

// Fills the DSM's holes within `max_distance_cells` of a measured cell by GDAL's inverse-distance interpolation
// (GDALFillNodata, smoothed once), in place. Returns where the heights come from: 255 measured, 128 filled, 0 none
// (farther than max_distance_cells from any measurement: still nodata).
[[nodiscard]] cv::Mat1b FillDsmHoles(cv::Mat1f* dsm, float nodata, int max_distance_cells);

// float32 single-band GeoTIFF with nodata; `wkt` empty = no CRS (local metres). Coordinates are `offset` + grid.
[[nodiscard]] bool WriteDsmGeoTiff(const std::string& path, const cv::Mat1f& dsm, const DsmGrid& grid,
                                   const Eigen::Vector2d& offset, const std::string& wkt, float nodata,
                                   std::string* error);

// The filled DSM's provenance (FillDsmHoles' mask) as a Byte GeoTIFF on the DSM's grid: 1 filled, 0 measured, nodata
// 255 where the DSM has none.
[[nodiscard]] bool WriteDsmFillMask(const std::string& path, const cv::Mat1b& provenance, const DsmGrid& grid,
                                    const Eigen::Vector2d& offset, const std::string& wkt, std::string* error);

// PNG previews: a top view of the cloud (colours, z-buffered by height) and the DSM (hillshade-tinted colour ramp).
[[nodiscard]] cv::Mat RenderCloudTopView(const std::vector<CloudPoint>& points, int long_side);
[[nodiscard]] cv::Mat RenderDsm(const cv::Mat1f& dsm, float nodata, int long_side);

}  // namespace uavm::sfm
