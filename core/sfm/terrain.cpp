#include "core/sfm/terrain.h"

#include <algorithm>
#include <cmath>
#include <opencv2/imgproc.hpp>

#include "core/sfm/cloud_and_dsm.h"

namespace uavm::sfm {

bool TerrainOptions::Check(std::string* why) const {
  if (max_window_m <= 0.0 || slope < 0.0 || elevation_threshold_m <= 0.0 || elevation_scaler < 0.0) {
    *why = "terrain: max_window_m and elevation_threshold_m must be > 0, slope and elevation_scaler >= 0";
    return false;
  }
  return true;
}

nlohmann::json TerrainReport::ToJson() const {
  return {{"cells", cells},
          {"ground_cells", ground_cells},
          {"ground_fraction", cells > 0 ? static_cast<double>(ground_cells) / cells : 0.0},
          {"windows", windows}};
}

namespace {

// `surface` with the cells not in `keep` interpolated from those that are (GDAL's inverse-distance fill, unbounded).
cv::Mat1f Interpolate(const cv::Mat1f& surface, const cv::Mat& keep, float nodata) {
  cv::Mat1f holes = surface.clone();
  holes.setTo(nodata, keep == 0);
  (void)FillDsmHoles(&holes, nodata, std::max(surface.rows, surface.cols));
  return holes;
}

}  // namespace

cv::Mat1f TerrainFromDsm(const cv::Mat1f& dsm, float nodata, double cell, const TerrainOptions& options,
                         cv::Mat1b* ground, TerrainReport* report) {
  TerrainReport local;
  TerrainReport& rep = report != nullptr ? *report : local;
  rep = TerrainReport{};
  const cv::Mat valid = dsm != nodata;
  rep.cells = cv::countNonZero(valid);
  if (rep.cells == 0) {
    if (ground != nullptr) *ground = cv::Mat1b(dsm.size(), uchar{0});
    return dsm.clone();
  }
  // The surface with no hole (the openings must not see nodata as a pit).
  cv::Mat1f z = Interpolate(dsm, valid, nodata);
  // Progressive openings: a cell that an opening of radius r lowers by more than slope x r x cell stands on something.
  cv::Mat1b object(dsm.size(), uchar{0});
  cv::Mat last = z.clone();
  const int max_radius = std::max(1, static_cast<int>(std::ceil(options.max_window_m / cell)));
  for (int radius = 1; radius <= max_radius; radius = radius < 4 ? radius + 1 : radius * 3 / 2) {
    const cv::Mat disc = cv::getStructuringElement(cv::MORPH_ELLIPSE, cv::Size(2 * radius + 1, 2 * radius + 1));
    cv::Mat opened;
    cv::morphologyEx(z, opened, cv::MORPH_OPEN, disc, cv::Point(-1, -1), 1, cv::BORDER_REPLICATE);
    const float threshold = static_cast<float>(options.slope * radius * cell);
    const cv::Mat rises = (last - opened) > threshold;
    cv::bitwise_or(object, rises, object);
    last = opened;
    ++rep.windows;
  }
  // The provisional terrain: the surface where nothing stands, interpolated under the objects.
  const cv::Mat open_ground = (object == 0) & valid;
  const cv::Mat1f provisional = Interpolate(z, open_ground, nodata);
  // Ground: cells close to it, the tolerance growing with the terrain's local slope.
  cv::Mat1f gx, gy;
  cv::Sobel(provisional, gx, CV_32F, 1, 0, 3, 1.0 / (8.0 * cell));
  cv::Sobel(provisional, gy, CV_32F, 0, 1, 3, 1.0 / (8.0 * cell));
  cv::Mat1f local_slope;
  cv::magnitude(gx, gy, local_slope);
  cv::Mat1f tolerance;
  local_slope.convertTo(tolerance, CV_32F, options.elevation_scaler * cell);
  tolerance += static_cast<float>(options.elevation_threshold_m);
  const int buffer = 1;
  cv::Mat1f above;
  cv::absdiff(z, provisional, above);
  cv::Mat1b is_ground;
  cv::bitwise_and(above <= tolerance, valid, is_ground);
  // A cell's width around what stands is not ground either: the DSM's cell at an edge mixes the object's height with
  // the ground's, within the tolerance of neither (left in, crown edges raised the ground under trees by 0.1 m).
  cv::Mat standing = is_ground == 0;
  cv::dilate(standing, standing, cv::getStructuringElement(cv::MORPH_RECT, cv::Size(2 * buffer + 1, 2 * buffer + 1)));
  is_ground.setTo(0, standing);
  rep.ground_cells = cv::countNonZero(is_ground);
  cv::Mat1f dtm = Interpolate(z, is_ground, nodata);
  dtm.setTo(nodata, valid == 0);
  if (ground != nullptr) *ground = is_ground;
  return dtm;
}

}  // namespace uavm::sfm
