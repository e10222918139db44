#pragma once
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "core/geometry/transform.h"

namespace uavm::sfm {

// One row of frames.csv joined with transforms.csv (README "Session directory").
struct SessionFrame {
  int index = -1;
  std::string filename;
  std::string stored_file;  // path relative to the session directory: frames/<stored_file column>
  int width = 0, height = 0;
  bool registered = false;
  std::optional<double> latitude_deg, longitude_deg, altitude_m, relative_altitude_m;
  std::optional<double> focal_length_mm;
  bool has_transform = false;
  Mat3 mosaic_from_frame = Mat3::Identity();  // original-resolution pixels -> mosaic pixels
};

struct SessionEdge {
  int src = -1, tgt = -1;
  int inliers = 0;
  bool used = false;
};

struct SessionCorrespondence {
  int src = -1, tgt = -1;
  double x_src = 0, y_src = 0, x_tgt = 0, y_tgt = 0;
};

// The onboard program's lens (camera.yaml, README "Session directory"): where the bundle adjustment's distortion
// starts. k's are normalised by focal_px (original pixels).
struct SessionLens {
  double focal_px = 0.0;
  double k1 = 0.0, k2 = 0.0, p1 = 0.0, p2 = 0.0;
  std::string source;  // configuration, database, self-calibrated, none
};

struct Session {
  std::string root;
  std::optional<SessionLens> lens;   // none for sessions without camera.yaml
  std::vector<SessionFrame> frames;  // in frames.csv order
  std::vector<SessionEdge> edges;
  std::vector<SessionCorrespondence> correspondences;  // may be empty when the file is absent
  [[nodiscard]] const SessionFrame* Find(int index) const;
};

// Reads frames.csv, transforms.csv (via core/session), graph.csv, correspondences.csv and camera.yaml of a session
// directory.
[[nodiscard]] bool ReadSession(const std::string& root, Session* session, std::string* error);

// Splits a CSV line (no quoting: the session writer never quotes).
[[nodiscard]] std::vector<std::string> SplitCsv(const std::string& line);
// Rows of a session's CSV file (frames.csv, graph.csv, radiometry.csv ...) as header-name -> cell maps.
[[nodiscard]] bool ReadCsv(const std::string& path, std::vector<std::map<std::string, std::string>>* rows,
                           std::string* error);
// A row's number under `key`; nullopt when the cell is missing, empty or not a number.
[[nodiscard]] std::optional<double> OptNum(const std::map<std::string, std::string>& row, const std::string& key);

}  // namespace uavm::sfm
