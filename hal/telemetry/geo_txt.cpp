#include "hal/telemetry/geo_txt.h"

#include <ogr_spatialref.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <memory>
#include <sstream>
#include <vector>

namespace uavm::hal {

namespace {

std::string Trim(const std::string& s) {
  const auto b = s.find_first_not_of(" \t\r\n");
  if (b == std::string::npos) return {};
  return s.substr(b, s.find_last_not_of(" \t\r\n") - b + 1);
}

std::string BaseName(const std::string& name) {
  return std::filesystem::path(name).filename().string();
}

struct Transform {
  std::unique_ptr<OGRCoordinateTransformation> to_wgs84;  // null: the file is in WGS84 already
};

bool MakeTransform(const std::string& crs, Transform* t, std::string* error) {
  OGRSpatialReference src;
  if (src.SetFromUserInput(crs.c_str()) != OGRERR_NONE) {
    *error = "unknown CRS '" + crs + "'";
    return false;
  }
  src.SetAxisMappingStrategy(OAMS_TRADITIONAL_GIS_ORDER);  // x = easting / longitude, as geo.txt writes them
  OGRSpatialReference wgs84;
  wgs84.importFromEPSG(4326);
  wgs84.SetAxisMappingStrategy(OAMS_TRADITIONAL_GIS_ORDER);
  if (src.IsSame(&wgs84)) return true;
  t->to_wgs84.reset(OGRCreateCoordinateTransformation(&src, &wgs84));
  if (!t->to_wgs84) {
    *error = "cannot transform CRS '" + crs + "' to WGS84";
    return false;
  }
  return true;
}

bool ParseLine(const std::string& line, const Transform& t, std::string* name, GeoTag* tag) {
  std::istringstream in(line);
  std::vector<double> v;
  if (!(in >> *name)) return false;
  for (double x; in >> x;) v.push_back(x);
  if (!in.eof() || v.size() < 2 || v.size() > 8) return false;  // a word where a number belongs, or too few
  for (double x : v)
    if (!std::isfinite(x)) return false;
  double x = v[0], y = v[1], z = v.size() > 2 ? v[2] : 0.0;
  if (t.to_wgs84 && !t.to_wgs84->Transform(1, &x, &y, &z)) return false;
  if (std::abs(y) > 90 || std::abs(x) > 180) return false;
  tag->lon_deg = x;
  tag->lat_deg = y;
  if (v.size() > 2) tag->alt_m = z;
  if (v.size() > 3) tag->omega_deg = v[3];
  if (v.size() > 4) tag->phi_deg = v[4];
  if (v.size() > 5) tag->kappa_deg = v[5];
  if (v.size() > 6) tag->h_acc_m = v[6];
  if (v.size() > 7) tag->v_acc_m = v[7];
  return true;
}

}  // namespace

bool GeoTxt::Load(const std::string& path, std::string* error) {
  std::ifstream in(path);
  if (!in) {
    *error = "cannot read " + path;
    return false;
  }
  std::string line;
  int number = 0;
  Transform t;
  while (crs_.empty() && std::getline(in, line)) {
    ++number;
    const std::string s = Trim(line);
    if (s.empty() || s[0] == '#') continue;
    crs_ = s;
    if (!MakeTransform(crs_, &t, error)) {
      *error = path + ":" + std::to_string(number) + ": " + *error;
      return false;
    }
  }
  if (crs_.empty()) {
    *error = path + ": empty (the first line must name the CRS, e.g. EPSG:4326)";
    return false;
  }
  while (std::getline(in, line)) {
    ++number;
    const std::string s = Trim(line);
    if (s.empty() || s[0] == '#') continue;
    std::string name;
    GeoTag tag;
    if (!ParseLine(s, t, &name, &tag)) {
      *error = path + ":" + std::to_string(number) + ": expected 'image_name x y [z] [omega phi kappa] [h_acc v_acc]'";
      return false;
    }
    if (!tags_.emplace(BaseName(name), tag).second) {
      *error = path + ":" + std::to_string(number) + ": " + name + " is listed twice";
      return false;
    }
  }
  return true;
}

const GeoTag* GeoTxt::Find(const std::string& image_name) const {
  const auto it = tags_.find(BaseName(image_name));
  return it == tags_.end() ? nullptr : &it->second;
}

}  // namespace uavm::hal
