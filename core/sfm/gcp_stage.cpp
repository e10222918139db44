#include "core/sfm/gcp_stage.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <map>

#include "core/sfm/sparse_stage.h"

namespace uavm::sfm {

namespace {

std::string Basename(const std::string& p) {
  const size_t s = p.find_last_of('/');
  return s == std::string::npos ? p : p.substr(s + 1);
}

std::vector<ImageInfo> SessionImages(const Session& session, const std::vector<const SessionFrame*>& used) {
  std::map<const SessionFrame*, int> slot_of;
  for (size_t i = 0; i < used.size(); ++i) slot_of[used[i]] = static_cast<int>(i);
  std::vector<ImageInfo> out;
  for (const auto& f : session.frames) {
    const auto it = slot_of.find(&f);
    out.push_back({Basename(f.filename), f.width, f.height, it == slot_of.end() ? -1 : it->second});
  }
  return out;
}

// The flight's GPS positions in the GCP CRS against the GCPs: kilometres apart means a wrong CRS.
bool CheckNearFlight(const GcpCrs& crs, const std::vector<Eigen::Vector3d>& world, const Session& session,
                     double max_distance_km, nlohmann::json* js, std::string* error) {
  Eigen::Vector2d cam = Eigen::Vector2d::Zero();
  int n = 0;
  std::vector<Eigen::Vector2d> xy;
  for (const auto& f : session.frames) {
    if (!f.latitude_deg || !f.longitude_deg) continue;
    if (const auto p = crs.FromLatLon(*f.latitude_deg, *f.longitude_deg)) {
      xy.push_back(*p);
      cam += *p;
      ++n;
    }
  }
  if (n == 0) return true;
  cam /= n;
  double extent = 0.0;
  for (const auto& p : xy) extent = std::max(extent, (p - cam).norm());
  Eigen::Vector2d gcp = Eigen::Vector2d::Zero();
  for (const auto& w : world) gcp += w.head<2>();
  gcp /= static_cast<double>(world.size());
  const double d = (gcp - cam).norm();
  (*js)["gcp_distance_to_flight_m"] = d;
  if (d > extent + max_distance_km * 1000.0) {
    char m[512];
    std::snprintf(m, sizeof m,
                  "the GCPs lie %.1f km from the flight's GPS positions: is the CRS on the GCP file's first line "
                  "(%s) right, and x = easting/longitude, y = northing/latitude?",
                  d / 1000.0, crs.name().c_str());
    *error = m;
    return false;
  }
  return true;
}

}  // namespace

bool LoadGcpInput(const std::string& path, const std::vector<std::string>& checkpoints, const Session& session,
                  const std::vector<const SessionFrame*>& used, double max_distance_km, GcpInput* out,
                  nlohmann::json* js, std::string* error) {
  if (!ReadGcpList(path, &out->list, error)) return false;
  double z_min = std::numeric_limits<double>::infinity(), z_max = -z_min;
  for (const auto& p : out->list.points) {
    z_min = std::min(z_min, p.geo.z());
    z_max = std::max(z_max, p.geo.z());
  }
  const bool no_heights = out->list.points.size() >= 2 && z_max - z_min < 1e-6 && !out->horizontal_only;
  std::vector<Eigen::Vector3d> world;
  for (const auto& p : out->list.points) world.push_back(p.geo);
  if (!out->crs.Init(out->list.crs_line, &world, error)) return false;
  if (!CheckNearFlight(out->crs, world, session, max_distance_km, js, error)) return false;
  Eigen::Vector2d mean = Eigen::Vector2d::Zero();
  for (const auto& w : world) mean += w.head<2>();
  mean /= static_cast<double>(world.size());
  out->offset = Eigen::Vector2d(std::round(mean.x()), std::round(mean.y()));
  if (!BindGcps(out->list, world, out->offset, SessionImages(session, used), checkpoints, &out->binding, error)) {
    return false;
  }
  if (no_heights) {
    out->horizontal_only = true;
    char m[200];
    std::snprintf(m, sizeof m,
                  "every GCP has the height %.3f: taken as horizontal control only (heights from the flight's GPS)",
                  z_min);
    out->binding.warnings.emplace_back(m);
  }
  for (const auto& w : out->binding.warnings) std::fprintf(stderr, "uavmosaic-ground: warning: %s\n", w.c_str());
  return true;
}

// 7b. Ground control points: the georeferenced model moved onto the GCPs, adjusted with them, every point measured.
bool AdjustToGcps(const std::vector<const SessionFrame*>& frames, const InitialModel& init, GcpInput* gcp,
                  const ReconstructionOptions& options, Reconstruction* rec, nlohmann::json* js, std::string* error) {
  BundlePriors priors = MakeBundlePriors(frames, init, options, js);
  ControlReport report;
  const auto& cps = gcp->binding.points;
  ControlOptions control = options.control;
  control.horizontal_only = control.horizontal_only || gcp->horizontal_only;
  if (!AlignToControl(cps, control, rec, &priors.centres, &report, error)) return false;
  BundleOptions bo;
  bo.threads = options.threads;
  bo.focal_prior_sigma = priors.focal_sigma;
  bo.centre_priors = priors.centres;
  bo.refine_k3 = options.refine_k3;
  bo.control = ControlConstraints(cps, *rec, control);
  bo.control_sigma_m = control.sigma_m;
  if (control.horizontal_only) bo.control_sigma_z_m = control.free_height_sigma_m;
  bo.control_click_px = options.control.click_px;
  TieFocals(priors, bo.min_images_for_lens, rec, &bo);
  BundleSummary bs;
  if (!BundleAdjust(rec, bo, &bs, error)) return false;
  TieFocals(priors, bo.min_images_for_lens, rec, &bo);
  MeasureControl(*rec, cps, &report);
  nlohmann::json j = report.ToJson();
  j["file"] = options.gcp_file;
  j["crs"] = gcp->crs.name();
  j["clicks_in_unused_frames"] = gcp->binding.clicks_skipped;
  for (const auto& w : gcp->binding.warnings) j["warnings"].push_back(w);
  j["ba_rms_px"] = bs.rms_after_px;
  j["sigma_m"] = options.control.sigma_m;
  j["click_sigma_px"] = options.control.click_px;
  (*js)["gcp"] = j;
  (*js)["ba_rms_after_px"] = rec->ReprojectionRms();
  for (const auto& w : report.warnings) std::fprintf(stderr, "uavmosaic-ground: warning: %s\n", w.c_str());
  return true;
}

// The GCP file (none without options.gcp_file) read, checked and bound to the selected frames' image slots.
bool BindGcpFile(const SelectedFrames& sel, const ReconstructionOptions& options, std::unique_ptr<GcpInput>* gcp,
                 nlohmann::json* js, std::string* error) {
  if (options.gcp_file.empty()) return true;
  *gcp = std::make_unique<GcpInput>();
  (*gcp)->horizontal_only = options.control.horizontal_only;
  return LoadGcpInput(options.gcp_file, options.checkpoints, sel.session, sel.frames, options.gcp_max_distance_km,
                      gcp->get(), js, error);
}

}  // namespace uavm::sfm
