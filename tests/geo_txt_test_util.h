#pragma once
// The simulated flights' OpenDroneMap geo.txt files (tools/sim_writer: the fixes and the truth), read back by the
// end-to-end tests.
#include <ogr_spatialref.h>

#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <sstream>
#include <string>

#include "core/geometry/transform.h"

namespace uavm::test {

struct GeoRow {
  Vec2 utm = Vec2::Zero();
  double lat = 0, lon = 0, alt = 0, kappa = 0;
};

// An OpenDroneMap geo.txt in WGS 84 (name lon lat alt [omega phi kappa]), with each position in UTM zone 15 N (the
// simulated flights').
inline std::map<std::string, GeoRow> ReadGeoTxt(const std::filesystem::path& path) {
  OGRSpatialReference wgs84, utm;
  wgs84.importFromEPSG(4326);
  wgs84.SetAxisMappingStrategy(OAMS_TRADITIONAL_GIS_ORDER);
  utm.importFromEPSG(32615);
  std::unique_ptr<OGRCoordinateTransformation> to_utm(OGRCreateCoordinateTransformation(&wgs84, &utm));
  std::map<std::string, GeoRow> out;
  std::ifstream in(path);
  std::string line, name;
  std::getline(in, line);  // CRS
  while (std::getline(in, line)) {
    std::istringstream fields(line);
    GeoRow r;
    double omega = 0, phi = 0;
    if (!(fields >> name >> r.lon >> r.lat >> r.alt)) continue;
    fields >> omega >> phi >> r.kappa;
    double x = r.lon, y = r.lat;
    to_utm->Transform(1, &x, &y);
    r.utm = Vec2(x, y);
    out[name] = r;
  }
  return out;
}

}  // namespace uavm::test
