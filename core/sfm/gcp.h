#pragma once
#include <Eigen/Core>
#include <istream>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

namespace uavm::sfm {

// Ground control points as OpenDroneMap's gcp_list.txt gives them: line 1 the CRS (an EPSG code such as
// "EPSG:32615", a proj4 string or WKT), then one row per click: `geo_x geo_y geo_z im_x im_y image_name [gcp_name]`.
// Pixels are in the original image with (0,0) the centre of the top-left pixel (OpenSfM's convention, and ours).
// Blank lines and lines starting with '#' are skipped. Rows without a name are grouped by their coordinates.
struct GcpClick {
  std::string image;
  Eigen::Vector2d pixel = Eigen::Vector2d::Zero();
  int line = 0;
};

struct GcpEntry {
  std::string name;
  Eigen::Vector3d geo = Eigen::Vector3d::Zero();  // in the file's CRS
  std::vector<GcpClick> clicks;
  int first_line = 0;
  bool named = true;  // false: rows without a name, called gcp-<n> in messages and reports
};

struct GcpList {
  std::string crs_line;
  std::vector<GcpEntry> points;  // in the order of their first row
};

// Parses the rows; refuses a row that is not `x y z px py image [name]`, one name with two different coordinates,
// two names with the same coordinates or at the same pixel of one image (one point clicked under two names), and one
// point clicked twice in one image. `source` names the file in messages.
[[nodiscard]] bool ParseGcpList(std::istream& in, const std::string& source, GcpList* out, std::string* error);
[[nodiscard]] bool ReadGcpList(const std::string& path, GcpList* out, std::string* error);

// The GCPs' CRS, in which the products are then written. A geographic CRS (degrees) is replaced by the WGS 84 UTM
// zone of the points (the products need metres); a projected CRS must be in metres.
class GcpCrs {
 public:
  GcpCrs();
  ~GcpCrs();
  GcpCrs(const GcpCrs&) = delete;
  GcpCrs& operator=(const GcpCrs&) = delete;

  // `points` are in the CRS of `crs_line` and are converted in place when it is geographic.
  [[nodiscard]] bool Init(const std::string& crs_line, std::vector<Eigen::Vector3d>* points, std::string* error);
  [[nodiscard]] std::string wkt() const { return wkt_; }
  [[nodiscard]] int epsg() const { return epsg_; }  // 0 when the CRS has no EPSG code
  [[nodiscard]] std::string name() const;           // "EPSG:n" or the file's line
  [[nodiscard]] bool converted_from_geographic() const { return from_geographic_; }
  // WGS 84 latitude/longitude -> this CRS's x, y (for the flight's GPS positions).
  [[nodiscard]] std::optional<Eigen::Vector2d> FromLatLon(double lat_deg, double lon_deg) const;
  [[nodiscard]] std::optional<Eigen::Vector2d> ToLatLon(const Eigen::Vector2d& xy) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
  std::string line_, wkt_;
  int epsg_ = 0;
  bool from_geographic_ = false;
};

// A GCP tied to the reconstruction's images.
struct ControlPoint {
  std::string name;
  Eigen::Vector3d world = Eigen::Vector3d::Zero();            // in the GCP CRS minus the offset (metres)
  std::vector<std::pair<int, Eigen::Vector2d>> observations;  // reconstruction image slot, pixel
  bool checkpoint = false;                                    // kept out of the adjustment; its error is reported
};

struct ImageInfo {
  std::string name;  // as a gcp_list.txt names it (the frame's file name)
  int width = 0, height = 0;
  int slot = -1;  // image of the reconstruction, -1 when the frame is not used by it
};

struct GcpBinding {
  std::vector<ControlPoint> points;
  int clicks_skipped = 0;  // clicks in frames the reconstruction does not use
  std::vector<std::string> warnings;
};

// Ties the parsed GCPs to the images: refuses unknown images, pixels outside the image, checkpoint names that are
// not in the file and fewer than three control points seen in two or more used images. `world` holds the points'
// coordinates (already in metres, see GcpCrs) minus `offset`.
[[nodiscard]] bool BindGcps(const GcpList& list, const std::vector<Eigen::Vector3d>& world,
                            const Eigen::Vector2d& offset, const std::vector<ImageInfo>& images,
                            const std::vector<std::string>& checkpoint_names, GcpBinding* out, std::string* error);

}  // namespace uavm::sfm
