#include "core/sfm/session_radiometry.h"

#include <array>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>
#include <sstream>
#include <vector>

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

// radiometry.csv: frame,name,gain_b,gain_g,gain_r.
bool ReadGains(const std::string& path, RadiometryModel* model, std::string* why) {
  std::ifstream in(path);
  std::string line;
  if (!in || !std::getline(in, line) || line.rfind("frame,name,gain_b,gain_g,gain_r", 0) != 0) {
    *why = path + ": missing or not a gains table";
    return false;
  }
  while (std::getline(in, line)) {
    if (line.empty()) continue;
    std::stringstream row(line);
    std::string field;
    std::vector<std::string> fields;
    while (std::getline(row, field, ',')) fields.push_back(field);
    cv::Vec3d log_gain;
    bool ok = fields.size() >= 5;
    for (int c = 0; ok && c < 3; ++c) {
      char* end = nullptr;
      const double g = std::strtod(fields[fields.size() - 3 + static_cast<size_t>(c)].c_str(), &end);
      ok = end != nullptr && *end == '\0' && g > 0.0 && std::isfinite(g);
      log_gain[c] = ok ? std::log(g) : 0.0;
    }
    char* end = nullptr;
    const long id = ok ? std::strtol(fields[0].c_str(), &end, 10) : -1;
    if (!ok || end == nullptr || *end != '\0' || id < 0) {
      *why = path + ": a malformed row: " + line;
      return false;
    }
    model->log_gain[static_cast<int>(id)] = log_gain;
  }
  return true;
}

}  // namespace

bool ReadSessionRadiometry(const Session& session, RadiometryModel* model, std::string* why) {
  *model = RadiometryModel{};
  nlohmann::json report;
  try {
    std::ifstream in(session.root + "/report.json");
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
  if (!ReadGains(session.root + "/radiometry.csv", model, why)) return false;
  model->ok = true;
  return true;
}

std::function<void(size_t, cv::Mat*)> SessionRadiometryCorrection(const std::string& session_dir,
                                                                  const Reconstruction& rec, std::string* why) {
  Session session;
  auto model = std::make_shared<RadiometryModel>();
  if (!ReadSession(session_dir, &session, why) || !ReadSessionRadiometry(session, model.get(), why)) return {};
  std::map<int, double> heading_of;
  for (const auto& f : session.frames)
    if (f.has_transform) heading_of[f.index] = HeadingOf(f.mosaic_from_frame, cv::Size(f.width, f.height));
  auto headings = std::make_shared<std::vector<double>>();
  for (const auto& im : rec.images) {
    const auto it = heading_of.find(im.frame_index);
    headings->push_back(it != heading_of.end() ? it->second : 0.0);
  }
  return [model, headings, &rec](size_t i, cv::Mat* bgr) {
    CorrectRadiometry(*model, rec.images[i].frame_index, (*headings)[i], bgr->size(), cv::Point2d(), bgr);
  };
}

}  // namespace uavm::sfm
