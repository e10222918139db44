#pragma once
#include <map>
#include <nlohmann/json.hpp>
#include <string>
#include <utility>
#include <vector>

#include "core/sfm/session_import.h"

namespace uavm::sfm {

// 1. The frames the reconstruction uses: registered, with a stored file and at least one used graph edge.
struct SelectedFrames {
  Session session;
  std::vector<const SessionFrame*> frames;  // into session.frames, in frames.csv order; position = image slot
  std::map<int, size_t> slot_of;            // session index -> image slot
  // Registered frames left out of the reconstruction, with the reason (summary.json "frames_not_used").
  std::vector<std::pair<const SessionFrame*, std::string>> left_out;
};

[[nodiscard]] bool SelectFrames(const std::string& session_dir, SelectedFrames* out, std::string* error);
// sel.left_out as summary.json's "frames_not_used": index, file and reason of each.
[[nodiscard]] nlohmann::json LeftOutJson(const SelectedFrames& sel);

}  // namespace uavm::sfm
