#include "core/sfm/control_points.h"

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "core/sfm/triangulation.h"

namespace uavm::sfm {

bool ControlOptions::Check(std::string* why) const {
  if (!(sigma_m > 0.0) || !(click_px > 0.0)) {
    *why = "GCP accuracy and click accuracy must be > 0";
    return false;
  }
  if (!(free_height_sigma_m > 0.0)) {
    *why = "the free heights' sigma must be > 0";
    return false;
  }
  return true;
}

std::optional<Eigen::Vector3d> TriangulateClicks(const Reconstruction& rec, const ControlPoint& cp) {
  std::vector<Pose> poses;
  std::vector<Eigen::Vector2d> normalized;
  for (const auto& [image, pixel] : cp.observations) {
    poses.push_back(rec.images[static_cast<size_t>(image)].pose);
    normalized.push_back(rec.CameraOf(image).Undistort(pixel));
  }
  const auto X = TriangulateDlt(poses, normalized);
  if (!X) return std::nullopt;
  for (const auto& p : poses) {
    if (p.ToCamera(*X).z() <= 0.0) return std::nullopt;
  }
  return X;
}

namespace {

void Apply(const Similarity3& s, Reconstruction* rec, std::vector<std::optional<Eigen::Vector3d>>* priors) {
  rec->Transform(s);
  for (auto& c : *priors) {
    if (c) c = s.Apply(*c);
  }
}

// A similarity about the vertical from the points' x, y: the 2-D fit, heights scaled by it about their mean (the
// flight's vertical reference kept).
bool FitHorizontal(const std::vector<Eigen::Vector3d>& src, const std::vector<Eigen::Vector3d>& dst, Similarity3* out) {
  std::vector<Eigen::Vector2d> src2, dst2;
  double mean_z = 0.0;
  for (size_t k = 0; k < src.size(); ++k) {
    src2.push_back(src[k].head<2>());
    dst2.push_back(dst[k].head<2>());
    mean_z += src[k].z() / static_cast<double>(src.size());
  }
  Similarity2 s2;
  if (!FitSimilarity<2>(src2, dst2, &s2)) return false;
  out->scale = s2.scale;
  out->rotation = Eigen::Matrix3d::Identity();
  out->rotation.topLeftCorner<2, 2>() = s2.rotation;
  out->translation << s2.translation, (1.0 - s2.scale) * mean_z;
  return true;
}

double ClickRms(const Reconstruction& rec, const ControlPoint& cp, const Eigen::Vector3d& X) {
  double sum = 0.0;
  for (const auto& [image, pixel] : cp.observations) {
    const auto m = Project(rec.CameraOf(image), rec.images[static_cast<size_t>(image)].pose, X);
    sum += m ? (*m - pixel).squaredNorm() : 1e12;
  }
  return std::sqrt(sum / static_cast<double>(std::max<size_t>(1, cp.observations.size())));
}

}  // namespace

bool AlignToControl(const std::vector<ControlPoint>& cps, const ControlOptions& options, Reconstruction* rec,
                    std::vector<std::optional<Eigen::Vector3d>>* centre_priors, ControlReport* report,
                    std::string* error) {
  std::vector<Eigen::Vector3d> src, dst;
  std::vector<std::string> names;
  for (const auto& cp : cps) {
    if (cp.checkpoint) continue;
    const auto X = TriangulateClicks(*rec, cp);
    if (!X) {
      report->warnings.push_back("GCP '" + cp.name + "' does not triangulate from its clicks: left out");
      continue;
    }
    src.push_back(*X);
    dst.push_back(cp.world);
    names.push_back(cp.name);
  }
  report->horizontal_only = options.horizontal_only;
  const bool fitted = src.size() >= 3 && (options.horizontal_only ? FitHorizontal(src, dst, &report->alignment)
                                                                  : FitSimilarity<3>(src, dst, &report->alignment));
  if (!fitted) {
    *error = "the GCPs cannot place the reconstruction: " + std::to_string(src.size()) +
             " control points triangulate (3 not on one line are needed)";
    return false;
  }
  report->gsd_m = rec->MedianGsd() * report->alignment.scale;
  const double suspicious = std::max(options.suspicious_m, options.suspicious_gsd * report->gsd_m);
  double sum = 0.0;
  for (size_t k = 0; k < src.size(); ++k) {
    const Eigen::Vector3d d = report->alignment.Apply(src[k]) - dst[k];
    const double e = options.horizontal_only ? d.head<2>().norm() : d.norm();
    sum += e * e;
    if (e > suspicious) {
      char m[256];
      std::snprintf(m, sizeof m,
                    "GCP '%s' is %.2f m from its survey after the alignment: a misclick, a wrong "
                    "coordinate or the wrong CRS?",
                    names[k].c_str(), e);
      report->warnings.emplace_back(m);
    }
  }
  report->alignment_rms_m = std::sqrt(sum / static_cast<double>(src.size()));
  Apply(report->alignment, rec, centre_priors);
  return true;
}

std::vector<BundleOptions::Control> ControlConstraints(const std::vector<ControlPoint>& cps, const Reconstruction& rec,
                                                       const ControlOptions& options) {
  std::vector<BundleOptions::Control> out;
  for (const auto& cp : cps) {
    if (cp.checkpoint) continue;
    Eigen::Vector3d world = cp.world;
    if (options.horizontal_only) {
      const auto X = TriangulateClicks(rec, cp);
      if (!X) continue;  // said by AlignToControl
      world.z() = X->z();
    }
    out.push_back({world, cp.observations});
  }
  return out;
}

void MeasureControl(const Reconstruction& rec, const std::vector<ControlPoint>& cps, ControlReport* report) {
  report->points.clear();
  for (const auto& cp : cps) {
    ControlPointError e;
    e.surveyed = cp.world;
    e.name = cp.name;
    e.checkpoint = cp.checkpoint;
    e.clicks = static_cast<int>(cp.observations.size());
    if (const auto X = TriangulateClicks(rec, cp)) {
      e.triangulated = true;
      e.error_m = *X - cp.world;
      if (report->horizontal_only) e.error_m.z() = 0.0;  // the survey has no height to check
      e.reprojection_px = ClickRms(rec, cp, *X);
    }
    report->points.push_back(e);
  }
}

nlohmann::json ControlReport::ToJson() const {
  nlohmann::json pts = nlohmann::json::array();
  Eigen::Vector3d sq[2] = {Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero()};
  int n[2] = {0, 0};
  for (const auto& p : points) {
    nlohmann::json j = {{"name", p.name},
                        {"role", p.checkpoint ? "checkpoint" : "control"},
                        {"clicks", p.clicks},
                        {"triangulated", p.triangulated},
                        {"position_local", {p.surveyed.x(), p.surveyed.y(), p.surveyed.z()}}};
    if (p.triangulated) {
      j["error_m"] = {p.error_m.x(), p.error_m.y(),
                      horizontal_only ? nlohmann::json(nullptr) : nlohmann::json(p.error_m.z())};
      j["error_gsd"] = gsd_m > 0 ? p.error_m.norm() / gsd_m : 0.0;
      j["click_rms_px"] = p.reprojection_px;
      const int k = p.checkpoint ? 1 : 0;
      sq[k] += p.error_m.cwiseAbs2();
      ++n[k];
    }
    pts.push_back(j);
  }
  auto rms = [&](int k) {
    if (n[k] == 0) return nlohmann::json(nullptr);
    const Eigen::Vector3d r = (sq[k] / n[k]).cwiseSqrt();
    const double total = std::sqrt(sq[k].sum() / n[k]);
    return nlohmann::json{
        {"points", n[k]},   {"x_m", r.x()},
        {"y_m", r.y()},     {"z_m", horizontal_only ? nlohmann::json(nullptr) : nlohmann::json(r.z())},
        {"total_m", total}, {"total_gsd", gsd_m > 0 ? total / gsd_m : 0.0}};
  };
  return {{"points", pts},
          {"control_rms", rms(0)},
          {"checkpoint_rms", rms(1)},
          {"gsd_m", gsd_m},
          {"alignment", {{"scale", alignment.scale}, {"rms_m", alignment_rms_m}}},
          {"warnings", warnings},
          {"horizontal_only", horizontal_only},
          {"errors_are", "point triangulated from its clicks with the adjusted cameras, minus its survey"}};
}

}  // namespace uavm::sfm
