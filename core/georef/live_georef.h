#pragma once
#include <array>
#include <cstdint>
#include <functional>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <unordered_map>
#include <vector>

#include "core/georef/georef.h"

namespace uavm {

// The georeference of the live picture, during the flight: the GPS fit (FitGeoref) over a bounded sample of the frames
// the live preview drew, refitted as the flight grows. The preview never redraws a frame, so a frame's point is where
// the preview drew its centre (mosaic coordinates at that time), not where the engine has it now.
struct LiveGeorefOptions {
  int min_points = 3;
  // The sampled GPS positions must span this much (box diagonal): over a shorter baseline a few metres of GPS noise
  // would turn the fit's rotation and scale by tens of percent.
  double min_spread_m = 30.0;
  int refit_every = 10;        // frames registered since the last fit...
  double refit_growth = 0.25;  // ...or the sample grew by this fraction
  // The sample: at most one frame (the newest) per grid cell of GPS space, the cell doubled whenever the sample
  // exceeds max_points. Per frame O(1); a refit costs the sample (RANSAC over <= max_points), never the flight.
  int max_points = 64;
  double initial_cell_m = 2.0;
  // A sampled frame the engine has since moved by more than this share of its half-diagonal (a merge re-expressed its
  // component in another frame's coordinates) is no longer where the picture shows it: it leaves the sample.
  double moved_fraction = 0.25;
  GeorefOptions fit;
};

// A registered frame the preview drew, with its position.
struct LivePoint {
  int id = -1;
  Vec2 drawn;              // the frame's centre where the preview drew it (mosaic coordinates)
  double radius_px = 1.0;  // its half-diagonal there
  double latitude_deg = 0;
  double longitude_deg = 0;
};

// Where the engine has a frame now: its component (any id naming it), that component's size and the frame's centre.
struct LivePlacement {
  int component = -1;
  int component_size = 0;
  Vec2 centre;
};
using LiveLocate = std::function<std::optional<LivePlacement>(int id)>;

// The live picture's georeference: an image whose pixels relate to the mosaic by image_from_mosaic.
struct LiveGeorefView {
  bool ok = false;
  std::string reason;  // why not, when !ok
  int epsg = 0;
  std::string crs_wkt;
  std::string model;
  double rms_m = 0;
  int inliers = 0;
  int points = 0;
  int frames_with_gps = 0;
  double gsd_m = 0;
  double rotation_deg = 0;  // of the picture's rows against east (0 = north-up)
  int width = 0;
  int height = 0;
  // (easting, northing) = world_from_pixel * (x, y, 1), pixel centres of the picture.
  Eigen::Matrix<double, 2, 3> world_from_pixel = Eigen::Matrix<double, 2, 3>::Zero();
  // (lat, lon) of the picture's outer corners: top-left, top-right, bottom-right, bottom-left.
  std::array<std::array<double, 2>, 4> corners{};
  std::array<double, 4> bounds{};  // south, west, north, east

  // status.json "georef": {"georeferenced": false, "reason"} or the CRS, fit, corners, bounds and geotransform.
  [[nodiscard]] nlohmann::json ToJson() const;
};

class LiveGeoref {
 public:
  explicit LiveGeoref(const LiveGeorefOptions& options = {});

  // A registered frame the preview drew; `point` when it carries a position. O(1) amortised.
  void AddFrame(const std::optional<LivePoint>& point);
  // Whether a refit is due (enough spread points, and the schedule says so). Costs the sample.
  [[nodiscard]] bool Due() const;
  // Fits again: the engine's current placement of each sampled frame (`locate`) decides which of them still count
  // (the largest component's, drawn where the engine still has them); those are fitted at their drawn centres.
  // Returns whether a georeference is held afterwards (a failed refit drops the previous one: it is not known to hold).
  bool Refit(const LiveLocate& locate);
  // Due() then Refit(); whether a georeference is held.
  bool Update(const LiveLocate& locate);

  [[nodiscard]] bool ok() const { return fit_.ok; }
  [[nodiscard]] const GeorefFit& fit() const { return fit_; }
  [[nodiscard]] size_t sample_size() const { return sample_.size(); }
  [[nodiscard]] double cell_m() const { return cell_m_; }
  [[nodiscard]] int refits() const { return refits_; }
  // The georeference of a picture of `width` x `height` pixels (image_from_mosaic: the preview's view of the mosaic).
  [[nodiscard]] LiveGeorefView Describe(const Mat3& image_from_mosaic, int width, int height) const;

 private:
  struct Sampled {
    LivePoint point;
    Vec2 local_m;  // east, north of the first position (equirectangular: thinning and spread only)
  };
  [[nodiscard]] Vec2 LocalMetres(double latitude_deg, double longitude_deg) const;
  [[nodiscard]] int64_t CellKey(const Vec2& local_m) const;
  [[nodiscard]] double SpreadM() const;
  [[nodiscard]] std::string WaitingReason() const;
  void Rebuild();  // the grid from the sample, keeping the newest frame per cell

  LiveGeorefOptions options_;
  std::vector<Sampled> sample_;
  std::unordered_map<int64_t, size_t> cells_;  // cell -> index in sample_
  double cell_m_;
  bool have_origin_ = false;
  double origin_lat_ = 0;
  double origin_lon_ = 0;
  double metres_per_deg_lon_ = 0;
  int frames_with_gps_ = 0;
  int frames_since_attempt_ = 0;
  size_t size_at_attempt_ = 0;
  bool attempted_ = false;
  int refits_ = 0;
  std::string last_failure_;
  GeorefFit fit_;
};

// World file (.jgw, .wld) of a picture: the six terms, the last two the top-left pixel's centre.
[[nodiscard]] std::string WorldFileText(const Eigen::Matrix<double, 2, 3>& world_from_pixel);
// GDAL's PAM sidecar (.aux.xml) naming the picture's CRS.
[[nodiscard]] std::string PamSrsXml(const std::string& wkt);

}  // namespace uavm
