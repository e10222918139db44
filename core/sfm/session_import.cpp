#include "core/sfm/session_import.h"

#include <yaml-cpp/yaml.h>

#include <filesystem>
#include <map>
#include <sstream>

#include "core/session/session_dir.h"

namespace uavm::sfm {

const SessionFrame* Session::Find(int index) const {
  for (const auto& f : frames) {
    if (f.index == index) return &f;
  }
  return nullptr;
}

std::vector<std::string> SplitCsv(const std::string& line) {
  std::vector<std::string> cells;
  std::string cell;
  std::stringstream ss(line);
  while (std::getline(ss, cell, ',')) cells.push_back(cell);
  if (!line.empty() && line.back() == ',') cells.emplace_back();
  return cells;
}

bool ReadCsv(const std::string& path, std::vector<std::map<std::string, std::string>>* rows, std::string* error) {
  std::string text;
  if (!ReadTextFile(path, &text, error)) return false;
  std::istringstream in(text);
  std::string line;
  if (!std::getline(in, line)) {
    *error = path + ": empty";
    return false;
  }
  if (!line.empty() && line.back() == '\r') line.pop_back();
  const auto header = SplitCsv(line);
  rows->clear();
  while (std::getline(in, line)) {
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (line.empty()) continue;
    const auto cells = SplitCsv(line);
    std::map<std::string, std::string> row;
    for (size_t i = 0; i < header.size() && i < cells.size(); ++i) row[header[i]] = cells[i];
    rows->push_back(std::move(row));
  }
  return true;
}

std::optional<double> OptNum(const std::map<std::string, std::string>& row, const std::string& key) {
  const auto it = row.find(key);
  if (it == row.end() || it->second.empty()) return std::nullopt;
  try {
    return std::stod(it->second);
  } catch (const std::exception&) {
    return std::nullopt;
  }
}

namespace {

// camera.yaml when there is one (sessions before the lens have none: no lens, not an error).
bool ReadLens(const std::string& path, std::optional<SessionLens>* lens, std::string* error) {
  lens->reset();
  std::error_code ec;
  if (!std::filesystem::exists(path, ec)) return true;
  try {
    const YAML::Node root = YAML::LoadFile(path);
    const YAML::Node c = root["camera"];
    SessionLens l;
    l.focal_px = c["focal_px"].as<double>();
    l.k1 = c["k1"].as<double>(0.0);
    l.k2 = c["k2"].as<double>(0.0);
    l.p1 = c["p1"].as<double>(0.0);
    l.p2 = c["p2"].as<double>(0.0);
    l.source = root["source"].as<std::string>("");
    if (!(l.focal_px > 0)) throw YAML::Exception(YAML::Mark::null_mark(), "focal_px must be > 0");
    *lens = l;
    return true;
  } catch (const std::exception& e) {
    *error = path + ": " + e.what();
    return false;
  }
}

// correspondences.csv when it can be read (optional: empty otherwise).
std::vector<SessionCorrespondence> ReadCorrespondences(const std::string& path) {
  std::vector<SessionCorrespondence> out;
  std::vector<std::map<std::string, std::string>> rows;
  std::string ignored;
  if (!ReadCsv(path, &rows, &ignored)) return out;
  for (const auto& r : rows) {
    SessionCorrespondence c;
    c.src = static_cast<int>(OptNum(r, "src").value_or(-1));
    c.tgt = static_cast<int>(OptNum(r, "tgt").value_or(-1));
    c.x_src = OptNum(r, "x_src").value_or(0);
    c.y_src = OptNum(r, "y_src").value_or(0);
    c.x_tgt = OptNum(r, "x_tgt").value_or(0);
    c.y_tgt = OptNum(r, "y_tgt").value_or(0);
    out.push_back(c);
  }
  return out;
}

}  // namespace

bool ReadSession(const std::string& root, Session* session, std::string* error) {
  session->root = root;
  std::vector<std::map<std::string, std::string>> rows;
  if (!ReadCsv(root + "/frames.csv", &rows, error)) return false;
  session->frames.clear();
  for (const auto& r : rows) {
    SessionFrame f;
    const auto index = OptNum(r, "index");
    if (!index) {
      *error = "frames.csv: a row without index";
      return false;
    }
    f.index = static_cast<int>(*index);
    f.filename = r.count("filename") ? r.at("filename") : "";
    f.stored_file = r.count("stored_file") ? r.at("stored_file") : "";
    // frames.csv names the file inside frames/.
    if (!f.stored_file.empty() && f.stored_file.find('/') == std::string::npos)
      f.stored_file = "frames/" + f.stored_file;
    f.width = static_cast<int>(OptNum(r, "width").value_or(0));
    f.height = static_cast<int>(OptNum(r, "height").value_or(0));
    f.registered = r.count("registered") && r.at("registered") == "1";
    f.latitude_deg = OptNum(r, "latitude_deg");
    f.longitude_deg = OptNum(r, "longitude_deg");
    f.altitude_m = OptNum(r, "altitude_m");
    f.relative_altitude_m = OptNum(r, "relative_altitude_m");
    f.focal_length_mm = OptNum(r, "focal_length_mm");
    session->frames.push_back(f);
  }
  std::string text;
  if (ReadTextFile(root + "/transforms.csv", &text, error)) {
    std::vector<TransformRow> trows;
    if (!ParseTransformsCsv(text, &trows, error)) return false;
    for (const auto& t : trows) {
      for (auto& f : session->frames) {
        if (f.index == t.index && t.registered) {
          f.has_transform = true;
          f.mosaic_from_frame = t.mosaic_from_frame;
        }
      }
    }
  }
  if (!ReadCsv(root + "/graph.csv", &rows, error)) return false;
  session->edges.clear();
  for (const auto& r : rows) {
    SessionEdge e;
    e.src = static_cast<int>(OptNum(r, "src").value_or(-1));
    e.tgt = static_cast<int>(OptNum(r, "tgt").value_or(-1));
    e.inliers = static_cast<int>(OptNum(r, "inliers").value_or(0));
    e.used = r.count("used") && r.at("used") == "1";
    if (e.src >= 0 && e.tgt >= 0) session->edges.push_back(e);
  }
  if (!ReadLens(root + "/camera.yaml", &session->lens, error)) return false;
  session->correspondences = ReadCorrespondences(root + "/correspondences.csv");
  return true;
}

}  // namespace uavm::sfm
