#pragma once
#include <array>
#include <memory>
#include <opencv2/core.hpp>
#include <string>

namespace uavm {

// Tiled RGBA GeoTIFF / BigTIFF written block by block through GDAL: the canvas never exists whole in memory.
// The file is written as "<path>.part" and renamed to `path` by a successful Close(): a run killed or stopped by a
// full disk leaves the previous mosaic (if any) intact and no half-written one under the final name.
class GdalTiffWriter {
 public:
  GdalTiffWriter();
  ~GdalTiffWriter();
  GdalTiffWriter(const GdalTiffWriter&) = delete;
  GdalTiffWriter& operator=(const GdalTiffWriter&) = delete;

  // With `overviews`, internal overview levels (2, 4, ... down to ~256 px) are written from each tile as it comes.
  [[nodiscard]] bool Open(const std::string& path, cv::Size canvas, int block_size, int tile_size, bool overviews,
                          int cache_mib, std::string* error);
  // image CV_8UC3 (BGR), mask CV_8U (alpha); top_left in canvas pixels, region inside the canvas.
  [[nodiscard]] bool Write(const cv::Mat& image, const cv::Mat& mask, cv::Point top_left, std::string* error);
  // Geotransform (GDAL convention) and CRS (WKT; empty = none) stored with the file at Close().
  void SetGeoreference(const std::array<double, 6>& geo_transform, const std::string& crs_wkt);
  // Flushes and closes. Returns false on an I/O error.
  [[nodiscard]] bool Close(std::string* error);

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace uavm
