#include "core/lens/lens_database.h"

#include <Eigen/Dense>
#include <cmath>
#include <memory>
#include <mutex>
#include <regex>

#ifdef UAVM_WITH_LENSFUN
#include <lensfun/lensfun.h>
#endif

namespace uavm {

LensDistortion FitRadialSamples(const std::vector<std::pair<double, double>>& ideal_distorted_px, double focal_px,
                                double* centre_scale) {
  // r_d = a0 r + a1 r^3 + a2 r^5 (linear least squares, r = r_i / focal), then with r' = s r the Brown form
  // r_d = r' (1 + k1 r'^2 + k2 r'^4): s = a0, k1 = a1 / s^3, k2 = a2 / s^5 (all normalised by focal).
  Eigen::Matrix3d ata = Eigen::Matrix3d::Zero();
  Eigen::Vector3d atb = Eigen::Vector3d::Zero();
  for (const auto& [ri, rd] : ideal_distorted_px) {
    const double r = ri / focal_px;
    const Eigen::Vector3d row(r, r * r * r, r * r * r * r * r);
    ata += row * row.transpose();
    atb += row * (rd / focal_px);
  }
  LensDistortion d;
  const Eigen::Vector3d a = ata.ldlt().solve(atb);
  const double s = a[0];
  if (!(s > 0) || !a.allFinite()) return d;
  d.k1 = a[1] / (s * s * s);
  d.k2 = a[2] / (s * s * s * s * s);
  if (centre_scale != nullptr) *centre_scale = s;
  return d;
}

#ifdef UAVM_WITH_LENSFUN

namespace {

// The database is parsed once (a few hundred ms of XML) and only read afterwards.
const lfDatabase* Database() {
  static std::once_flag once;
  static std::unique_ptr<lfDatabase> db;
  std::call_once(once, [] {
    auto d = std::make_unique<lfDatabase>();
    if (d->Load() == LF_NO_ERROR) db = std::move(d);
  });
  return db.get();
}

template <typename T>
struct LfList {
  const T** items = nullptr;
  ~LfList() { lf_free(items); }
};

// (ideal, distorted) radii along the half-diagonal through lensfun's own modifier: its models, normalisation and
// focal-length conventions stay lensfun's.
bool SampleModifier(const lfLens* lens, double crop, double focal_mm, const PinholeCamera& camera,
                    std::vector<std::pair<double, double>>* samples) {
  lfModifier modifier(lens, static_cast<float>(crop), camera.width, camera.height);
  const int flags = modifier.Initialize(lens, LF_PF_U8, static_cast<float>(focal_mm), 4.0F, 1000.0F, 1.0F,
                                        LF_RECTILINEAR, LF_MODIFY_DISTORTION, false);
  if ((flags & LF_MODIFY_DISTORTION) == 0) return false;
  constexpr int kSamples = 64;
  const double dx = camera.width - 1 - camera.cx, dy = camera.height - 1 - camera.cy;
  for (int i = 1; i <= kSamples; ++i) {
    const double t = static_cast<double>(i) / kSamples;
    alignas(16) float res[2];
    const auto xu = static_cast<float>(camera.cx + t * dx), yu = static_cast<float>(camera.cy + t * dy);
    if (!modifier.ApplyGeometryDistortion(xu, yu, 1, 1, res)) return false;
    samples->emplace_back(t * std::hypot(dx, dy), std::hypot(res[0] - camera.cx, res[1] - camera.cy));
  }
  return true;
}

// lensfun marks a calibration made on raw files in the lens's name ("..., with CHDK's DNG"; "RAW" elsewhere).
bool NamesRawFiles(const std::string& lens) {
  static const std::regex kRawWord(R"(\b(dng|raw)\b)", std::regex::icase);
  return std::regex_search(lens, kRawWord);
}

}  // namespace

bool LensDatabaseAvailable() {
  return Database() != nullptr;
}

bool LookUpLensDistortion(const std::string& make, const std::string& model, double focal_mm,
                          const PinholeCamera& camera, LensDatabaseEntry* entry, std::string* why) {
  const lfDatabase* db = Database();
  if (db == nullptr) return (*why = "lensfun's database could not be loaded"), false;
  if (make.empty() || model.empty()) return (*why = "EXIF names no camera"), false;
  LfList<lfCamera> cameras{db->FindCamerasExt(make.c_str(), model.c_str())};
  if (cameras.items == nullptr || cameras.items[0] == nullptr)
    return (*why = "lensfun does not know the camera '" + make + " " + model + "'"), false;
  const lfCamera* cam = cameras.items[0];
  LfList<lfLens> lenses{db->FindLenses(cam, nullptr, nullptr)};
  if (lenses.items == nullptr || lenses.items[0] == nullptr)
    return (*why = "lensfun has no fixed lens for '" + make + " " + model + "'"), false;
  const lfLens* lens = lenses.items[0];
  lfLensCalibDistortion calib{};
  if (!(focal_mm > 0)) focal_mm = lens->MinFocal;
  if (!lens->InterpolateDistortion(static_cast<float>(focal_mm), calib) || calib.Model == LF_DIST_MODEL_NONE)
    return (*why = "lensfun has no distortion for '" + make + " " + model + "'"), false;
  std::vector<std::pair<double, double>> samples;
  if (!SampleModifier(lens, cam->CropFactor, focal_mm, camera, &samples))
    return (*why = "lensfun's modifier refused the lens"), false;
  entry->camera = std::string(cam->Maker != nullptr ? lf_mlstr_get(cam->Maker) : "") + " " +
                  (cam->Model != nullptr ? lf_mlstr_get(cam->Model) : "");
  entry->lens = lens->Model != nullptr ? lf_mlstr_get(lens->Model) : "";
  entry->raw_files = NamesRawFiles(entry->lens);
  entry->crop_factor = cam->CropFactor;
  entry->distortion = FitRadialSamples(samples, camera.focal_px, &entry->centre_scale);
  return true;
}

#else

bool LensDatabaseAvailable() {
  return false;
}

bool LookUpLensDistortion(const std::string&, const std::string&, double, const PinholeCamera&, LensDatabaseEntry*,
                          std::string* why) {
  *why = "built without lensfun (liblensfun-dev)";
  return false;
}

#endif

}  // namespace uavm
