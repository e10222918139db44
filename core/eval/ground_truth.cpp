#include "core/eval/ground_truth.h"

#include <yaml-cpp/yaml.h>

#include <cstdio>
#include <filesystem>
#include <sstream>

#include "core/session/session_dir.h"

namespace uavm::eval {

std::string FormatGroundTruthCsv(const std::vector<GtRow>& rows) {
  std::string out = std::string(kGroundTruthHeader) + "\n";
  char buf[1024];
  for (const auto& r : rows) {
    const Mat3 c = r.canvas_from_frame / r.canvas_from_frame(2, 2);
    const Mat3& a = r.affine;
    // %.17g: the evaluator's known-answer tests go down to 1e-6 px, so no rounding here.
    std::snprintf(buf, sizeof(buf),
                  "%d,%s,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g\n",
                  r.index, r.filename.c_str(), c(0, 0), c(0, 1), c(0, 2), c(1, 0), c(1, 1), c(1, 2), c(2, 0), c(2, 1),
                  c(2, 2), a(0, 0), a(0, 1), a(0, 2), a(1, 0), a(1, 1), a(1, 2));
    out += buf;
  }
  return out;
}

namespace {

std::vector<std::string> SplitComma(const std::string& line) {
  std::vector<std::string> out;
  std::string cur;
  for (char ch : line) {
    if (ch == ',') {
      out.push_back(cur);
      cur.clear();
    } else if (ch != '\r') {
      cur += ch;
    }
  }
  out.push_back(cur);
  return out;
}

bool ToDouble(const std::string& s, double* v) {
  if (s.empty()) return false;
  char* end = nullptr;
  *v = std::strtod(s.c_str(), &end);
  return end != nullptr && *end == '\0';
}

}  // namespace

bool ParseGroundTruthCsv(const std::string& text, std::vector<GtRow>* rows, std::string* error) {
  rows->clear();
  std::istringstream in(text);
  std::string line;
  if (!std::getline(in, line)) {
    *error = "gt.csv is empty";
    return false;
  }
  if (!line.empty() && line.back() == '\r') line.pop_back();
  if (line != kGroundTruthHeader) {
    *error = "gt.csv: unexpected header '" + line + "'";
    return false;
  }
  int line_no = 1;
  while (std::getline(in, line)) {
    ++line_no;
    if (line.empty() || line == "\r") continue;
    const auto f = SplitComma(line);
    if (f.size() != 17) {
      *error = "gt.csv line " + std::to_string(line_no) + ": expected 17 fields, got " + std::to_string(f.size());
      return false;
    }
    GtRow r;
    double v[15];
    double idx = 0;
    bool ok = ToDouble(f[0], &idx);
    for (int i = 0; i < 15 && ok; ++i) ok = ToDouble(f[static_cast<size_t>(i) + 2], &v[i]);
    if (!ok) {
      *error = "gt.csv line " + std::to_string(line_no) + ": malformed number";
      return false;
    }
    r.index = static_cast<int>(idx);
    r.filename = f[1];
    r.canvas_from_frame << v[0], v[1], v[2], v[3], v[4], v[5], v[6], v[7], v[8];
    r.affine << v[9], v[10], v[11], v[12], v[13], v[14], 0, 0, 1;
    rows->push_back(std::move(r));
  }
  return true;
}

std::string FormatGroundTruthCamera(const GtCamera& g) {
  const PinholeCamera& c = g.camera;
  const LensDistortion& d = c.distortion;
  char buf[1536];
  std::snprintf(buf, sizeof(buf),
                "# Camera of a simulated flight (uavmosaic-sim); layout in core/eval/ground_truth.h.\n"
                "# gt.csv's canvas_from_frame maps undistorted frame pixels; radial displacement at the half-diagonal: "
                "%.6g of its radius.\n"
                "camera:\n  width: %d\n  height: %d\n  focal_px: %.17g\n  cx: %.17g\n  cy: %.17g\n"
                "  k1: %.17g\n  k2: %.17g\n  p1: %.17g\n  p2: %.17g\n"
                "vignetting:  # V(r) = 1 + a1 r^2 + a2 r^4, r = distance to (cx, cy) / half_diagonal_px; [a1, a2]\n"
                "  half_diagonal_px: %.17g\n  b: [%.17g, %.17g]\n  g: [%.17g, %.17g]\n  r: [%.17g, %.17g]\n",
                c.RadialDistortionAtHalfDiagonal(), c.width, c.height, c.focal_px, c.cx, c.cy, d.k1, d.k2, d.p1, d.p2,
                g.half_diagonal_px, g.vignetting[0].a1, g.vignetting[0].a2, g.vignetting[1].a1, g.vignetting[1].a2,
                g.vignetting[2].a1, g.vignetting[2].a2);
  return buf;
}

namespace {

PinholeCamera CameraFrom(const YAML::Node& c) {
  if (!c.IsMap()) throw YAML::Exception(YAML::Mark::null_mark(), "no camera block");
  PinholeCamera camera;
  camera.width = c["width"].as<int>();
  camera.height = c["height"].as<int>();
  camera.focal_px = c["focal_px"].as<double>();
  camera.cx = c["cx"].as<double>();
  camera.cy = c["cy"].as<double>();
  camera.distortion = {c["k1"].as<double>(0.0), c["k2"].as<double>(0.0), c["p1"].as<double>(0.0),
                       c["p2"].as<double>(0.0)};
  if (camera.width < 2 || camera.height < 2 || !(camera.focal_px > 0))
    throw YAML::Exception(YAML::Mark::null_mark(), "camera width, height or focal_px out of range");
  return camera;
}

}  // namespace

bool ParseCameraBlock(const std::string& text, PinholeCamera* camera, std::string* error) {
  try {
    *camera = CameraFrom(YAML::Load(text)["camera"]);
    return true;
  } catch (const std::exception& e) {
    *error = std::string("camera: ") + e.what();
    return false;
  }
}

bool ParseGroundTruthCamera(const std::string& text, GtCamera* out, std::string* error) {
  try {
    const YAML::Node root = YAML::Load(text);
    const YAML::Node v = root["vignetting"];
    GtCamera g;
    g.camera = CameraFrom(root["camera"]);
    if (!v.IsMap()) throw YAML::Exception(YAML::Mark::null_mark(), "no vignetting block");
    g.half_diagonal_px = v["half_diagonal_px"].as<double>();
    const char* channels[3] = {"b", "g", "r"};
    for (size_t k = 0; k < 3; ++k) {
      const auto pair = v[channels[k]].as<std::vector<double>>();
      if (pair.size() != 2) throw YAML::Exception(YAML::Mark::null_mark(), "vignetting needs [a1, a2] per channel");
      g.vignetting[k] = {pair[0], pair[1]};
    }
    if (!(g.half_diagonal_px > 0)) throw YAML::Exception(YAML::Mark::null_mark(), "half_diagonal_px must be > 0");
    *out = g;
    return true;
  } catch (const std::exception& e) {
    *error = std::string("gt_camera.yaml: ") + e.what();
    return false;
  }
}

std::string FormatGroundTruthExposure(const std::vector<GtExposure>& rows) {
  std::string out = std::string(kGroundTruthExposureHeader) + "\n";
  char buf[512];
  for (const auto& r : rows) {
    std::snprintf(buf, sizeof(buf), "%d,%s,%.17g,%.17g,%.17g,%.17g,%.17g\n", r.index, r.filename.c_str(), r.gain,
                  r.offset, r.white_balance[0], r.white_balance[1], r.white_balance[2]);
    out += buf;
  }
  return out;
}

bool ParseGroundTruthExposure(const std::string& text, std::vector<GtExposure>* rows, std::string* error) {
  rows->clear();
  std::istringstream in(text);
  std::string line;
  if (std::getline(in, line) && !line.empty() && line.back() == '\r') line.pop_back();
  if (line != kGroundTruthExposureHeader) {
    *error = "gt_exposure.csv: unexpected header";
    return false;
  }
  for (int line_no = 2; std::getline(in, line); ++line_no) {
    if (line.empty() || line == "\r") continue;
    const auto f = SplitComma(line);
    double v[6];
    bool ok = f.size() == 7 && ToDouble(f[0], &v[0]);
    for (size_t i = 1; i < 6 && ok; ++i) ok = ToDouble(f[i + 1], &v[i]);
    if (!ok) {
      *error = "gt_exposure.csv line " + std::to_string(line_no) + ": expected 7 fields";
      return false;
    }
    rows->push_back({static_cast<int>(v[0]), f[1], v[1], v[2], {v[3], v[4], v[5]}});
  }
  return true;
}

bool LoadGroundTruthCamera(const std::string& gt_csv_path, std::optional<GtCamera>* camera, std::string* error) {
  camera->reset();
  const std::string path = (std::filesystem::path(gt_csv_path).parent_path() / kGroundTruthCameraFile).string();
  std::error_code ec;
  if (!std::filesystem::exists(path, ec)) return true;
  std::string text;
  GtCamera g;
  if (!ReadTextFile(path, &text, error) || !ParseGroundTruthCamera(text, &g, error)) return false;
  *camera = g;
  return true;
}

}  // namespace uavm::eval
