#include "core/sfm/gcp.h"

#include <ogr_spatialref.h>

#include <cmath>
#include <fstream>
#include <set>
#include <sstream>

#include "core/georef/georef.h"

namespace uavm::sfm {

namespace {

std::string At(const std::string& source, int line) {
  return source + " line " + std::to_string(line) + ": ";
}

std::string Trim(const std::string& s) {
  const size_t a = s.find_first_not_of(" \t\r\n");
  if (a == std::string::npos) return "";
  return s.substr(a, s.find_last_not_of(" \t\r\n") + 1 - a);
}

// One click row; false with a message when it is not `x y z px py image [name]`.
bool ParseRow(const std::string& text, const std::string& where, GcpEntry* entry, GcpClick* click, std::string* error) {
  std::istringstream row(text);
  std::vector<std::string> f;
  for (std::string tok; row >> tok;) f.push_back(tok);
  if (f.size() < 6 || f.size() > 7) {
    *error = where + "expected `geo_x geo_y geo_z im_x im_y image_name [gcp_name]`, found " + std::to_string(f.size()) +
             " fields";
    return false;
  }
  double v[5];
  for (size_t i = 0; i < 5; ++i) {
    char* end = nullptr;
    v[i] = std::strtod(f[i].c_str(), &end);
    if (end == f[i].c_str() || *end != '\0' || !std::isfinite(v[i])) {
      *error = where + "field " + std::to_string(i + 1) + " ('" + f[i] + "') is not a number";
      return false;
    }
  }
  entry->geo = Eigen::Vector3d(v[0], v[1], v[2]);
  entry->name = f.size() == 7 ? f[6] : "";
  click->pixel = Eigen::Vector2d(v[3], v[4]);
  click->image = f[5];
  return true;
}

bool SameGeo(const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  return (a - b).cwiseAbs().maxCoeff() < 1e-3;  // a millimetre: survey coordinates are given to that at best
}

// Adds a click to its point (by name, or by coordinates for unnamed rows), refusing the inconsistencies.
bool AddClick(const GcpEntry& row, const GcpClick& click, const std::string& source, GcpList* out, std::string* error) {
  GcpEntry* target = nullptr;
  for (auto& p : out->points) {
    const bool same_name = !row.name.empty() && p.name == row.name;
    const bool same_geo = SameGeo(p.geo, row.geo);
    if (same_name && !same_geo) {
      *error = At(source, click.line) + "GCP '" + row.name + "' has other coordinates than on line " +
               std::to_string(p.first_line);
      return false;
    }
    if (same_geo && !same_name && !row.name.empty() && p.named) {
      *error = At(source, click.line) + "'" + row.name + "' has the coordinates of '" + p.name + "' (line " +
               std::to_string(p.first_line) + "): one point under two names?";
      return false;
    }
    if (same_name || (row.name.empty() && same_geo)) target = &p;
  }
  if (target == nullptr) {
    out->points.push_back(row);
    target = &out->points.back();
    target->first_line = click.line;
    target->named = !target->name.empty();
    if (!target->named) target->name = "gcp-" + std::to_string(out->points.size());
  }
  for (const auto& c : target->clicks) {
    if (c.image == click.image) {
      *error = At(source, click.line) + "GCP '" + target->name + "' is clicked twice in " + click.image + " (lines " +
               std::to_string(c.line) + " and " + std::to_string(click.line) + ")";
      return false;
    }
  }
  target->clicks.push_back(click);
  return true;
}

// Two names clicked at (nearly) the same pixel of one image: one point under two names.
bool CheckDistinctClicks(const GcpList& list, const std::string& source, std::string* error) {
  constexpr double kSamePixel = 2.0;
  for (size_t a = 0; a < list.points.size(); ++a) {
    for (size_t b = a + 1; b < list.points.size(); ++b) {
      for (const auto& ca : list.points[a].clicks) {
        for (const auto& cb : list.points[b].clicks) {
          if (ca.image == cb.image && (ca.pixel - cb.pixel).norm() < kSamePixel) {
            *error = At(source, cb.line) + "'" + list.points[b].name + "' and '" + list.points[a].name + "' (line " +
                     std::to_string(ca.line) + ") are clicked at the same pixel of " + ca.image +
                     ": one point under two names?";
            return false;
          }
        }
      }
    }
  }
  return true;
}

}  // namespace

bool ParseGcpList(std::istream& in, const std::string& source, GcpList* out, std::string* error) {
  *out = GcpList{};
  std::string text;
  int line = 0;
  while (out->crs_line.empty() && std::getline(in, text)) {
    ++line;
    const std::string t = Trim(text);
    if (!t.empty() && t[0] != '#') out->crs_line = t;
  }
  if (out->crs_line.empty()) {
    *error = source + ": empty (the first line must be the CRS, e.g. EPSG:32615)";
    return false;
  }
  while (std::getline(in, text)) {
    ++line;
    const std::string t = Trim(text);
    if (t.empty() || t[0] == '#') continue;
    GcpEntry row;
    GcpClick click;
    click.line = line;
    if (!ParseRow(t, At(source, line), &row, &click, error)) return false;
    if (!AddClick(row, click, source, out, error)) return false;
  }
  if (out->points.empty()) {
    *error = source + ": no GCP rows after the CRS line";
    return false;
  }
  return CheckDistinctClicks(*out, source, error);
}

bool ReadGcpList(const std::string& path, GcpList* out, std::string* error) {
  std::ifstream in(path);
  if (!in) {
    *error = "cannot read the GCP file " + path;
    return false;
  }
  return ParseGcpList(in, path, out, error);
}

// ---- CRS ----

struct GcpCrs::Impl {
  OGRSpatialReference srs, wgs84;
  std::unique_ptr<OGRCoordinateTransformation> to_wgs84, from_wgs84;
};

GcpCrs::GcpCrs() : impl_(std::make_unique<Impl>()) {}
GcpCrs::~GcpCrs() = default;

std::string GcpCrs::name() const {
  return epsg_ > 0 ? "EPSG:" + std::to_string(epsg_) : line_;
}

namespace {

int EpsgOf(OGRSpatialReference* srs) {
  if (srs->GetAuthorityName(nullptr) == nullptr) srs->AutoIdentifyEPSG();
  const char* auth = srs->GetAuthorityName(nullptr);
  const char* code = srs->GetAuthorityCode(nullptr);
  if (auth == nullptr || code == nullptr || std::string(auth) != "EPSG") return 0;
  return std::atoi(code);
}

}  // namespace

bool GcpCrs::Init(const std::string& crs_line, std::vector<Eigen::Vector3d>* points, std::string* error) {
  line_ = crs_line;
  auto& s = *impl_;
  if (s.srs.SetFromUserInput(crs_line.c_str()) != OGRERR_NONE) {
    *error = "the GCP file's CRS '" + crs_line + "' is not one GDAL knows (give e.g. EPSG:32615 or a proj4 string)";
    return false;
  }
  s.srs.SetAxisMappingStrategy(OAMS_TRADITIONAL_GIS_ORDER);
  s.wgs84.SetWellKnownGeogCS("WGS84");
  s.wgs84.SetAxisMappingStrategy(OAMS_TRADITIONAL_GIS_ORDER);
  if (s.srs.IsGeographic()) {
    // Degrees: the points move to the UTM zone of their centroid (x = longitude, y = latitude in GIS order).
    Eigen::Vector3d mean = Eigen::Vector3d::Zero();
    for (const auto& p : *points) mean += p;
    mean /= static_cast<double>(std::max<size_t>(1, points->size()));
    if (std::abs(mean.y()) > 84.0 || std::abs(mean.x()) > 180.0) {
      *error = "the GCPs' mean latitude/longitude (" + std::to_string(mean.y()) + ", " + std::to_string(mean.x()) +
               ") is outside UTM's range: are x and y in the right order (x = longitude)?";
      return false;
    }
    const int utm_epsg = UtmEpsg(mean.y(), mean.x());
    OGRSpatialReference geo = s.srs;
    std::unique_ptr<OGRCoordinateTransformation> to_utm;
    s.srs.Clear();
    s.srs.importFromEPSG(utm_epsg);
    s.srs.SetAxisMappingStrategy(OAMS_TRADITIONAL_GIS_ORDER);
    to_utm.reset(OGRCreateCoordinateTransformation(&geo, &s.srs));
    for (auto& p : *points) {
      double x = p.x(), y = p.y();
      if (!to_utm || !to_utm->Transform(1, &x, &y)) {
        *error = "cannot project the GCPs to UTM from '" + crs_line + "'";
        return false;
      }
      p.x() = x;
      p.y() = y;
    }
    from_geographic_ = true;
  } else if (!s.srs.IsProjected()) {
    *error = "the GCP file's CRS '" + crs_line + "' is neither geographic nor projected";
    return false;
  } else if (std::abs(s.srs.GetLinearUnits() - 1.0) > 1e-9) {
    *error = "the GCP file's CRS '" + crs_line + "' is not in metres: give the GCPs in a metre-based CRS (e.g. UTM)";
    return false;
  }
  epsg_ = EpsgOf(&s.srs);
  char* wkt = nullptr;
  s.srs.exportToWkt(&wkt);
  wkt_ = wkt ? wkt : "";
  CPLFree(wkt);
  s.to_wgs84.reset(OGRCreateCoordinateTransformation(&s.srs, &s.wgs84));
  s.from_wgs84.reset(OGRCreateCoordinateTransformation(&s.wgs84, &s.srs));
  if (!s.to_wgs84 || !s.from_wgs84) {
    *error = "PROJ cannot transform between WGS 84 and the GCP file's CRS '" + crs_line + "'";
    return false;
  }
  return true;
}

std::optional<Eigen::Vector2d> GcpCrs::FromLatLon(double lat_deg, double lon_deg) const {
  double x = lon_deg, y = lat_deg;
  if (!impl_->from_wgs84 || !impl_->from_wgs84->Transform(1, &x, &y)) return std::nullopt;
  return Eigen::Vector2d(x, y);
}

std::optional<Eigen::Vector2d> GcpCrs::ToLatLon(const Eigen::Vector2d& xy) const {
  double x = xy.x(), y = xy.y();
  if (!impl_->to_wgs84 || !impl_->to_wgs84->Transform(1, &x, &y)) return std::nullopt;
  return Eigen::Vector2d(y, x);
}

// ---- binding ----

namespace {

bool BindPoint(const GcpEntry& e, const Eigen::Vector3d& world, const std::map<std::string, const ImageInfo*>& by_name,
               ControlPoint* cp, GcpBinding* out, std::string* error) {
  cp->name = e.name;
  cp->world = world;
  for (const auto& c : e.clicks) {
    const auto it = by_name.find(c.image);
    if (it == by_name.end()) {
      *error = "GCP file line " + std::to_string(c.line) + ": image '" + c.image + "' is not a frame of this session";
      return false;
    }
    const ImageInfo& im = *it->second;
    if (c.pixel.x() < -0.5 || c.pixel.y() < -0.5 || c.pixel.x() > im.width - 0.5 || c.pixel.y() > im.height - 0.5) {
      std::ostringstream m;
      m << "GCP file line " << c.line << ": pixel (" << c.pixel.x() << ", " << c.pixel.y() << ") is outside " << c.image
        << " (" << im.width << " x " << im.height << ")";
      *error = m.str();
      return false;
    }
    if (im.slot < 0) {
      ++out->clicks_skipped;
      out->warnings.push_back("GCP '" + e.name + "' in " + c.image + ": the frame is not in the reconstruction");
      continue;
    }
    cp->observations.emplace_back(im.slot, c.pixel);
  }
  return true;
}

}  // namespace

bool BindGcps(const GcpList& list, const std::vector<Eigen::Vector3d>& world, const Eigen::Vector2d& offset,
              const std::vector<ImageInfo>& images, const std::vector<std::string>& checkpoint_names, GcpBinding* out,
              std::string* error) {
  *out = GcpBinding{};
  std::map<std::string, const ImageInfo*> by_name;
  for (const auto& im : images) by_name[im.name] = &im;
  std::set<std::string> names;
  for (const auto& p : list.points) names.insert(p.name);
  for (const auto& c : checkpoint_names) {
    if (!names.count(c)) {
      *error = "--checkpoints: no GCP named '" + c + "' in the GCP file";
      return false;
    }
  }
  const std::set<std::string> checks(checkpoint_names.begin(), checkpoint_names.end());
  int usable_control = 0;
  for (size_t i = 0; i < list.points.size(); ++i) {
    ControlPoint cp;
    const Eigen::Vector3d local = world[i] - Eigen::Vector3d(offset.x(), offset.y(), 0.0);
    if (!BindPoint(list.points[i], local, by_name, &cp, out, error)) return false;
    cp.checkpoint = checks.count(cp.name) > 0;
    if (cp.observations.size() < 2) {
      out->warnings.push_back("GCP '" + cp.name + "' is seen in fewer than two used frames: not used");
      continue;
    }
    if (!cp.checkpoint) ++usable_control;
    out->points.push_back(std::move(cp));
  }
  if (usable_control < 3) {
    *error = "the GCP file gives " + std::to_string(usable_control) +
             " control points clicked in two or more used frames (checkpoints do not count): at least 3 are needed";
    return false;
  }
  return true;
}

}  // namespace uavm::sfm
