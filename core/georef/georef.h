#pragma once
#include <Eigen/Core>
#include <memory>
#include <string>
#include <vector>

#include "core/geometry/transform.h"

class OGRCoordinateTransformation;

namespace uavm {

// Georeferencing of a pose-free mosaic: a map from mosaic pixels to a projected CRS (the flight's UTM zone), fitted to
// the registered frames' centres and their EXIF GPS positions. GPS is noisy (a few metres, occasional jumps), so the
// fit is robust: a similarity from RANSAC over pairs, refitted on its inliers; an affine only when enough well-spread
// frames support it (it absorbs a slightly anisotropic mosaic but is ill-posed for a single flight line).
struct GeorefOptions {
  double inlier_threshold_m = 15.0;  // consumer GPS is good to a few metres; jumps are tens of metres
  int min_points = 3;                // a similarity from 2 would have no redundancy at all
  int affine_min_points = 10;
  // The affine needs spread in both directions: the smaller principal spread of the centres, in metres.
  double affine_min_spread_m = 30.0;
  bool allow_affine = true;
  int ransac_iterations = 500;

  [[nodiscard]] bool Check(std::string* why) const;
};

struct GeoPoint {
  int id = -1;
  Vec2 pixel;  // mosaic pixel (pixel centres, (0,0) = centre of the top-left pixel)
  double latitude_deg = 0;
  double longitude_deg = 0;
};

struct GeorefFit {
  bool ok = false;
  std::string failure;         // why not, when !ok
  std::string model = "none";  // "similarity" | "affine"
  int epsg = 0;                // 326zz (north) / 327zz (south)
  std::string crs_wkt;
  // (easting, northing) = world_from_pixel * (x, y, 1), for pixel centres.
  Eigen::Matrix<double, 2, 3> world_from_pixel = Eigen::Matrix<double, 2, 3>::Zero();
  int points = 0;
  int inliers = 0;
  double rms_m = 0;      // residual RMS of the inliers, metres
  double rms_all_m = 0;  // of every point
  double max_inlier_m = 0;
  double gsd_m = 0;         // ground sampling distance: metres per mosaic pixel (sqrt |det|)
  double rotation_deg = 0;  // of the pixel grid against grid north (0 = north-up)
  std::vector<int> inlier_ids;
  std::vector<double> residuals_m;  // per point, in input order
};

// world_from_pixel (2x3) as a homogeneous 3x3 map, to compose with the canvas's maps or invert.
[[nodiscard]] Mat3 WorldFromPixel3(const Eigen::Matrix<double, 2, 3>& world_from_pixel);

// EPSG code of the WGS 84 / UTM zone holding (lat, lon) (Norway/Svalbard exceptions ignored).
[[nodiscard]] int UtmEpsg(double latitude_deg, double longitude_deg);

// Transforms between WGS 84 lat/lon (degrees) and the projected CRS `epsg` (x = easting, y = northing).
// Returns false when PROJ cannot build the transformation.
[[nodiscard]] bool LatLonToProjected(int epsg, const std::vector<double>& lat, const std::vector<double>& lon,
                                     std::vector<Vec2>* out, std::string* error);
[[nodiscard]] bool ProjectedToLatLon(int epsg, const std::vector<Vec2>& xy, std::vector<double>* lat,
                                     std::vector<double>* lon, std::string* error);
[[nodiscard]] std::string EpsgWkt(int epsg);

// Between WGS 84 lat/lon and a projected CRS, one position at a time, for loops: PROJ's transformations (~0.4 ms to
// build) are kept and built again only when the EPSG changes. The same numbers as LatLonToProjected and
// ProjectedToLatLon (one function builds every transformation between WGS 84 and a projected CRS of the project).
class ProjectedConverter {
 public:
  ProjectedConverter();
  ~ProjectedConverter();
  ProjectedConverter(const ProjectedConverter&) = delete;
  ProjectedConverter& operator=(const ProjectedConverter&) = delete;

  [[nodiscard]] bool ToProjected(int epsg, double latitude_deg, double longitude_deg, Vec2* out,
                                 std::string* error = nullptr);
  // (x = easting, y = northing) of `epsg` -> WGS 84.
  [[nodiscard]] bool ToLatLon(int epsg, const Vec2& xy, double* latitude_deg, double* longitude_deg,
                              std::string* error = nullptr);

 private:
  // One direction's transformation and the EPSG it was built for.
  struct Cached {
    int epsg = 0;
    std::unique_ptr<OGRCoordinateTransformation> transform;
  };
  [[nodiscard]] static OGRCoordinateTransformation* TransformFor(Cached* cached, int epsg, bool to_projected,
                                                                 std::string* error);

  Cached to_projected_;
  Cached to_latlon_;
};

[[nodiscard]] GeorefFit FitGeoref(const std::vector<GeoPoint>& points, const GeorefOptions& options);

// GDAL geotransform of the pixel grid (GDAL's origin is the top-left pixel's corner, not its centre).
[[nodiscard]] std::array<double, 6> GdalGeoTransform(const Eigen::Matrix<double, 2, 3>& world_from_pixel);

}  // namespace uavm
