#pragma once
#include <optional>
#include <string>
#include <unordered_map>

namespace uavm::hal {

// One image's geotag from an OpenDroneMap geo.txt, in WGS84 whatever the file's CRS.
struct GeoTag {
  double lat_deg = 0, lon_deg = 0;
  std::optional<double> alt_m;
  std::optional<double> omega_deg, phi_deg, kappa_deg;
  std::optional<double> h_acc_m, v_acc_m;
};

// OpenDroneMap's geo.txt: the first line a CRS (e.g. "EPSG:4326", "EPSG:32633" or a proj string), then one line per
// image: `image_name x y [z] [omega phi kappa] [horizontal_accuracy vertical_accuracy]` (x = easting/longitude).
// Coordinates in another CRS are transformed to WGS84 with GDAL/PROJ. Blank lines and '#' comments are skipped. A
// line that cannot be read is an error naming its line number (the file is the user's survey data: guessing would
// misplace the map). Tags are looked up by file name (without folders).
class GeoTxt {
 public:
  [[nodiscard]] bool Load(const std::string& path, std::string* error);
  [[nodiscard]] const GeoTag* Find(const std::string& image_name) const;
  [[nodiscard]] size_t size() const { return tags_.size(); }
  [[nodiscard]] const std::string& crs() const { return crs_; }

 private:
  std::string crs_;
  std::unordered_map<std::string, GeoTag> tags_;
};

}  // namespace uavm::hal
