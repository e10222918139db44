#include "core/georef/georef.h"

#include <gdal.h>
#include <ogr_spatialref.h>

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <memory>
#include <numeric>
#include <random>

#include "core/geometry/similarity.h"

namespace uavm {

namespace {

using Affine23 = Eigen::Matrix<double, 2, 3>;

// Map coordinates in a y-down frame (u = easting, v = -northing), so that the pixel -> map similarity is proper
// (no reflection) and 4 parameters describe it.
Vec2 ToYDown(const Vec2& en) {
  return Vec2(en.x(), -en.y());
}

// Least-squares similarity pixel -> y-down map over `idx`, as an affine 2x3.
bool FitSimilarity23(const std::vector<Vec2>& px, const std::vector<Vec2>& uv, const std::vector<size_t>& idx,
                     Affine23* out) {
  Similarity2 fit;
  if (!FitSimilarity<2>(px, uv, &fit, {.indices = &idx})) return false;
  out->leftCols<2>() = fit.scale * fit.rotation;
  out->col(2) = fit.translation;
  return true;
}

bool FitAffine(const std::vector<Vec2>& px, const std::vector<Vec2>& uv, const std::vector<size_t>& idx,
               Affine23* out) {
  if (idx.size() < 3) return false;
  Eigen::MatrixXd A(idx.size(), 3);
  Eigen::MatrixXd B(idx.size(), 2);
  for (size_t k = 0; k < idx.size(); ++k) {
    const auto r = static_cast<Eigen::Index>(k);
    A.row(r) << px[idx[k]].x(), px[idx[k]].y(), 1;
    B.row(r) = uv[idx[k]].transpose();
  }
  const Eigen::Matrix<double, 3, 2> X = A.colPivHouseholderQr().solve(B);
  if (!X.allFinite()) return false;
  *out = X.transpose();
  return std::abs(out->leftCols<2>().determinant()) > 1e-18;
}

Vec2 ApplyAffine(const Affine23& m, const Vec2& p) {
  return m.leftCols<2>() * p + m.col(2);
}

std::vector<size_t> Inliers(const Affine23& m, const std::vector<Vec2>& px, const std::vector<Vec2>& uv,
                            double threshold) {
  std::vector<size_t> in;
  for (size_t i = 0; i < px.size(); ++i)
    if ((ApplyAffine(m, px[i]) - uv[i]).norm() <= threshold) in.push_back(i);
  return in;
}

// Smaller principal standard deviation of the points (metres): ~0 for a single straight flight line.
double MinorSpread(const std::vector<Vec2>& uv, const std::vector<size_t>& idx) {
  Vec2 mean = Vec2::Zero();
  for (size_t i : idx) mean += uv[i];
  mean /= static_cast<double>(idx.size());
  Eigen::Matrix2d c = Eigen::Matrix2d::Zero();
  for (size_t i : idx) c += (uv[i] - mean) * (uv[i] - mean).transpose();
  c /= static_cast<double>(idx.size());
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> es(c);
  return std::sqrt(std::max(0.0, es.eigenvalues()(0)));
}

std::unique_ptr<OGRCoordinateTransformation> MakeTransform(int epsg, bool to_projected, std::string* error) {
  OGRSpatialReference geo;
  OGRSpatialReference proj;
  if (geo.SetWellKnownGeogCS("WGS84") != OGRERR_NONE || proj.importFromEPSG(epsg) != OGRERR_NONE) {
    *error = "PROJ does not know EPSG:" + std::to_string(epsg);
    return nullptr;
  }
  // lat/lon in degrees as (x = longitude, y = latitude), whatever the EPSG axis order says.
  geo.SetAxisMappingStrategy(OAMS_TRADITIONAL_GIS_ORDER);
  proj.SetAxisMappingStrategy(OAMS_TRADITIONAL_GIS_ORDER);
  std::unique_ptr<OGRCoordinateTransformation> t(to_projected ? OGRCreateCoordinateTransformation(&geo, &proj)
                                                              : OGRCreateCoordinateTransformation(&proj, &geo));
  if (!t) *error = "no transformation between WGS 84 and EPSG:" + std::to_string(epsg);
  return t;
}

}  // namespace

bool GeorefOptions::Check(std::string* why_out) const {
  std::string ignored;
  std::string* why = why_out != nullptr ? why_out : &ignored;
  if (!(inlier_threshold_m > 0)) return *why = "georef.inlier_threshold_m must be > 0", false;
  if (min_points < 2) return *why = "georef.min_points must be >= 2", false;
  if (affine_min_points < 3) return *why = "georef.affine_min_points must be >= 3", false;
  if (ransac_iterations < 1) return *why = "georef.ransac_iterations must be >= 1", false;
  return true;
}

int UtmEpsg(double latitude_deg, double longitude_deg) {
  double lon = std::fmod(longitude_deg + 180.0, 360.0);
  if (lon < 0) lon += 360.0;
  const int zone = std::clamp(static_cast<int>(std::floor(lon / 6.0)) + 1, 1, 60);
  return (latitude_deg >= 0 ? 32600 : 32700) + zone;
}

std::string EpsgWkt(int epsg) {
  OGRSpatialReference s;
  if (s.importFromEPSG(epsg) != OGRERR_NONE) return {};
  char* wkt = nullptr;
  s.exportToWkt(&wkt);
  std::string out = wkt != nullptr ? wkt : "";
  CPLFree(wkt);
  return out;
}

bool LatLonToProjected(int epsg, const std::vector<double>& lat, const std::vector<double>& lon, std::vector<Vec2>* out,
                       std::string* error) {
  auto t = MakeTransform(epsg, true, error);
  if (!t) return false;
  std::vector<double> x(lon), y(lat);
  if (!x.empty() && !t->Transform(static_cast<int>(x.size()), x.data(), y.data())) {
    *error = "PROJ failed to project the positions";
    return false;
  }
  out->clear();
  for (size_t i = 0; i < x.size(); ++i) out->emplace_back(x[i], y[i]);
  return true;
}

ProjectedConverter::ProjectedConverter() = default;
ProjectedConverter::~ProjectedConverter() = default;

OGRCoordinateTransformation* ProjectedConverter::TransformFor(Cached* cached, int epsg, bool to_projected,
                                                              std::string* error) {
  if (!cached->transform || epsg != cached->epsg) {
    cached->epsg = epsg;
    cached->transform = MakeTransform(epsg, to_projected, error);
  }
  return cached->transform.get();
}

bool ProjectedConverter::ToProjected(int epsg, double latitude_deg, double longitude_deg, Vec2* out,
                                     std::string* error_out) {
  std::string ignored;
  std::string* error = error_out != nullptr ? error_out : &ignored;
  OGRCoordinateTransformation* transform = TransformFor(&to_projected_, epsg, true, error);
  if (transform == nullptr) return false;
  double x = longitude_deg, y = latitude_deg;
  if (!transform->Transform(1, &x, &y)) {
    *error = "PROJ failed to project the positions";
    return false;
  }
  *out = Vec2(x, y);
  return true;
}

bool ProjectedConverter::ToLatLon(int epsg, const Vec2& xy, double* latitude_deg, double* longitude_deg,
                                  std::string* error_out) {
  std::string ignored;
  std::string* error = error_out != nullptr ? error_out : &ignored;
  OGRCoordinateTransformation* transform = TransformFor(&to_latlon_, epsg, false, error);
  if (transform == nullptr) return false;
  double x = xy.x(), y = xy.y();
  if (!transform->Transform(1, &x, &y)) {
    *error = "PROJ failed to unproject the positions";
    return false;
  }
  *longitude_deg = x;
  *latitude_deg = y;
  return true;
}

bool ProjectedToLatLon(int epsg, const std::vector<Vec2>& xy, std::vector<double>* lat, std::vector<double>* lon,
                       std::string* error) {
  auto t = MakeTransform(epsg, false, error);
  if (!t) return false;
  lon->clear();
  lat->clear();
  for (const auto& p : xy) {
    lon->push_back(p.x());
    lat->push_back(p.y());
  }
  if (!xy.empty() && !t->Transform(static_cast<int>(xy.size()), lon->data(), lat->data())) {
    *error = "PROJ failed to unproject the positions";
    return false;
  }
  return true;
}

Mat3 WorldFromPixel3(const Eigen::Matrix<double, 2, 3>& world_from_pixel) {
  Mat3 m = Mat3::Identity();
  m.topRows<2>() = world_from_pixel;
  return m;
}

std::array<double, 6> GdalGeoTransform(const Eigen::Matrix<double, 2, 3>& m) {
  // GDAL: X = gt0 + col*gt1 + row*gt2 with (col, row) = (0, 0) at the top-left corner = pixel centre (-0.5, -0.5).
  const Vec2 origin = m.leftCols<2>() * Vec2(-0.5, -0.5) + m.col(2);
  return {origin.x(), m(0, 0), m(0, 1), origin.y(), m(1, 0), m(1, 1)};
}

GeorefFit FitGeoref(const std::vector<GeoPoint>& points, const GeorefOptions& o) {
  GeorefFit fit;
  fit.points = static_cast<int>(points.size());
  if (static_cast<int>(points.size()) < o.min_points) {
    fit.failure = "only " + std::to_string(points.size()) + " registered frames with GPS (need " +
                  std::to_string(o.min_points) + ")";
    return fit;
  }
  // The zone of the flight's median position, so that a flight over a zone border stays in one CRS.
  std::vector<double> lat, lon;
  for (const auto& p : points) {
    lat.push_back(p.latitude_deg);
    lon.push_back(p.longitude_deg);
  }
  std::vector<double> slat(lat), slon(lon);
  std::nth_element(slat.begin(), slat.begin() + static_cast<long>(slat.size() / 2), slat.end());
  std::nth_element(slon.begin(), slon.begin() + static_cast<long>(slon.size() / 2), slon.end());
  fit.epsg = UtmEpsg(slat[slat.size() / 2], slon[slon.size() / 2]);
  std::vector<Vec2> en;
  if (!LatLonToProjected(fit.epsg, lat, lon, &en, &fit.failure)) return fit;
  std::vector<Vec2> px, uv;
  for (size_t i = 0; i < points.size(); ++i) {
    px.push_back(points[i].pixel);
    uv.push_back(ToYDown(en[i]));
  }

  // RANSAC over pairs (deterministic seed: the same session gives the same georeference).
  std::mt19937 rng(12345);
  std::uniform_int_distribution<size_t> pick(0, points.size() - 1);
  std::vector<size_t> best;
  Affine23 best_m;
  const size_t n = points.size();
  const int iterations = n <= 40 ? static_cast<int>(n * (n - 1) / 2) : o.ransac_iterations;
  int it = 0;
  for (size_t i = 0; i < n && it < iterations; ++i)
    for (size_t j = i + 1; j < n && it < iterations; ++j, ++it) {
      size_t a = i, b = j;
      if (n > 40) {  // random pairs when exhausting them would take too long
        a = pick(rng);
        b = pick(rng);
        if (a == b) continue;
      }
      if ((px[a] - px[b]).norm() < 1.0) continue;
      Affine23 m;
      if (!FitSimilarity23(px, uv, {a, b}, &m)) continue;
      auto in = Inliers(m, px, uv, o.inlier_threshold_m);
      if (in.size() > best.size()) {
        best = std::move(in);
        best_m = m;
      }
    }
  if (static_cast<int>(best.size()) < o.min_points) {
    fit.failure = "no consistent GPS subset (best " + std::to_string(best.size()) + " of " +
                  std::to_string(points.size()) + " within " + std::to_string(o.inlier_threshold_m) + " m)";
    return fit;
  }
  // Refit on the inliers until the set is stable.
  Affine23 m = best_m;
  std::vector<size_t> in = best;
  for (int k = 0; k < 5; ++k) {
    if (!FitSimilarity23(px, uv, in, &m)) break;
    auto next = Inliers(m, px, uv, o.inlier_threshold_m);
    if (next == in || static_cast<int>(next.size()) < o.min_points) break;
    in = std::move(next);
  }
  fit.model = "similarity";
  if (o.allow_affine && static_cast<int>(in.size()) >= o.affine_min_points &&
      MinorSpread(uv, in) >= o.affine_min_spread_m) {
    Affine23 a;
    if (FitAffine(px, uv, in, &a)) {
      auto ain = Inliers(a, px, uv, o.inlier_threshold_m);
      if (ain.size() >= in.size() && FitAffine(px, uv, ain, &a)) {
        m = a;
        in = Inliers(a, px, uv, o.inlier_threshold_m);
        fit.model = "affine";
      }
    }
  }
  // Back to (easting, northing).
  fit.world_from_pixel.row(0) = m.row(0);
  fit.world_from_pixel.row(1) = -m.row(1);
  fit.gsd_m = std::sqrt(std::abs(m.leftCols<2>().determinant()));
  fit.rotation_deg = std::atan2(m(1, 0), m(0, 0)) * 180.0 / M_PI;
  double s2 = 0, s2all = 0;
  for (size_t i = 0; i < n; ++i) {
    const double r = (ApplyAffine(m, px[i]) - uv[i]).norm();
    fit.residuals_m.push_back(r);
    s2all += r * r;
  }
  for (size_t i : in) {
    s2 += fit.residuals_m[i] * fit.residuals_m[i];
    fit.max_inlier_m = std::max(fit.max_inlier_m, fit.residuals_m[i]);
    fit.inlier_ids.push_back(points[i].id);
  }
  fit.inliers = static_cast<int>(in.size());
  fit.rms_m = std::sqrt(s2 / static_cast<double>(in.size()));
  fit.rms_all_m = std::sqrt(s2all / static_cast<double>(n));
  fit.crs_wkt = EpsgWkt(fit.epsg);
  fit.ok = true;
  return fit;
}

}  // namespace uavm
