#include "core/sfm/frame_selection.h"

#include <set>

namespace uavm::sfm {

bool SelectFrames(const std::string& session_dir, SelectedFrames* out, std::string* error) {
  if (!ReadSession(session_dir, &out->session, error)) return false;
  std::set<int> in_graph;
  for (const auto& e : out->session.edges) {
    if (e.used) {
      in_graph.insert(e.src);
      in_graph.insert(e.tgt);
    }
  }
  for (const auto& f : out->session.frames) {
    if (f.registered && f.has_transform && in_graph.count(f.index) && !f.stored_file.empty()) {
      out->frames.push_back(&f);
    }
  }
  if (out->frames.size() < 2) {
    *error = "fewer than two registered frames with used graph edges in " + session_dir;
    return false;
  }
  for (size_t i = 0; i < out->frames.size(); ++i) out->slot_of[out->frames[i]->index] = i;
  return true;
}

nlohmann::json LeftOutJson(const SelectedFrames& sel) {
  nlohmann::json j = nlohmann::json::array();
  for (const auto& [f, why] : sel.left_out) j.push_back({{"index", f->index}, {"file", f->filename}, {"reason", why}});
  return j;
}

}  // namespace uavm::sfm
