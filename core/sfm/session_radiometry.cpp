#include "core/sfm/session_radiometry.h"

#include <array>
#include <cmath>
#include <fstream>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "core/session/session_dir.h"
#include "core/sfm/session_import.h"

namespace uavm::sfm {

namespace {

template <size_t N>
bool ReadArray(const nlohmann::json& j, std::array<double, N>* out) {
  if (!j.is_array() || j.size() != N) return false;
  for (size_t k = 0; k < N; ++k) {
    if (!j[k].is_number()) return false;
    (*out)[k] = j[k].get<double>();
  }
  return true;
}

// report.json's "radiometry" block: the shading terms the onboard solve kept.
bool ReadShading(const nlohmann::json& r, RadiometryModel* model, std::string* why) {
  model->vignetting = r.value("vignetting", false);
  const auto& falloff = r.at("log_falloff_c1_c2_bgr");
  for (size_t c = 0; c < 3; ++c)
    if (!ReadArray(falloff.at(c), &model->log_falloff[c])) {
      *why = "report.json: radiometry.log_falloff_c1_c2_bgr is not 3 x 2 numbers";
      return false;
    }
  model->flat_field = r.value("flat_field", false);
  if (model->flat_field && !ReadArray(r.at("log_flat_u_v_uu-vv_uv_ur2_vr2"), &model->log_flat)) {
    *why = "report.json: radiometry's flat field is not 6 numbers";
    return false;
  }
  const auto& hot = r.at("hotspot");
  model->hotspot.found = hot.value("found", false);
  if (model->hotspot.found) {
    std::array<double, 2> at{};
    if (!ReadArray(hot.at("antisolar_half_diagonals"), &at) ||
        !ReadArray(hot.at("log_weights"), &model->hotspot.weights)) {
      *why = "report.json: radiometry's hotspot is incomplete";
      return false;
    }
    model->hotspot.antisolar_u = at[0];
    model->hotspot.antisolar_v = at[1];
  }
  return true;
}

// radiometry.csv: frame,name,gain_b,gain_g,gain_r (core/sfm/session_import's CSV reader).
bool ReadGains(const std::string& path, RadiometryModel* model, std::string* why) {
  std::vector<std::map<std::string, std::string>> rows;
  if (!ReadCsv(path, &rows, why)) return false;
  for (const auto& row : rows) {
    const std::optional<double> id = OptNum(row, "frame");
    cv::Vec3d log_gain;
    bool ok = id && *id >= 0;
    int c = 0;
    for (const char* key : {"gain_b", "gain_g", "gain_r"}) {
      const std::optional<double> g = OptNum(row, key);
      ok = ok && g && *g > 0.0 && std::isfinite(*g);
      log_gain[c++] = ok ? std::log(*g) : 0.0;
    }
    if (!ok) {
      *why = path + ": a row without a frame number and three positive gains";
      return false;
    }
    model->log_gain[static_cast<int>(*id)] = log_gain;
  }
  return true;
}

}  // namespace

bool ReadSessionRadiometry(const std::string& session_dir, RadiometryModel* model, std::string* why) {
  *model = RadiometryModel{};
  nlohmann::json report;
  try {
    std::ifstream in(session_dir + "/report.json");
    if (!in) {
      *why = "the session has no report.json";
      return false;
    }
    report = nlohmann::json::parse(in);
    if (!report.contains("radiometry") || !report["radiometry"].value("corrected", false)) {
      *why = "the onboard program did not correct the flight's radiometry";
      return false;
    }
    if (!ReadShading(report["radiometry"], model, why)) return false;
  } catch (const nlohmann::json::exception& e) {
    *why = std::string("report.json: ") + e.what();
    return false;
  }
  if (!ReadGains(session_dir + "/radiometry.csv", model, why)) return false;
  model->ok = true;
  return true;
}

std::function<void(size_t, cv::Mat*)> SessionRadiometryCorrection(const std::string& session_dir,
                                                                  const Reconstruction& rec, std::string* why) {
  auto model = std::make_shared<RadiometryModel>();
  if (!ReadSessionRadiometry(session_dir, model.get(), why)) return {};
  // Each frame's heading from its onboard map (transforms.csv; the rotation does not depend on the image's scale). A
  // frame without one turns the hotspot as a frame along the mosaic's axes.
  std::string text, unread;
  std::vector<TransformRow> rows;
  if (!ReadTextFile(session_dir + "/transforms.csv", &text, &unread) || !ParseTransformsCsv(text, &rows, &unread))
    rows.clear();
  std::map<int, const TransformRow*> row_of;
  for (const auto& row : rows)
    if (row.registered) row_of[row.index] = &row;
  auto headings = std::make_shared<std::vector<double>>();
  for (const auto& im : rec.images) {
    const auto it = row_of.find(im.frame_index);
    if (it == row_of.end()) {
      headings->push_back(0.0);
      continue;
    }
    const Camera& cam = rec.CameraOf(im);
    headings->push_back(HeadingOf(it->second->mosaic_from_frame, cv::Size(cam.width, cam.height)));
  }
  return [model, headings, &rec](size_t i, cv::Mat* bgr) {
    CorrectRadiometry(*model, rec.images[i].frame_index, (*headings)[i], bgr->size(), cv::Point2d(), bgr);
  };
}

}  // namespace uavm::sfm
