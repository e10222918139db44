#pragma once
#include <deque>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "core/frame/frame.h"
#include "core/geometry/transform.h"
#include "core/registration/registration_engine.h"

namespace uavm {

// The session's record of one frame (the engine keeps the registration's, under the same id).
struct SessionFrame {
  int id = -1;
  std::string name;
  std::string stored_file;  // path inside the session's frames/
  cv::Size original_size;
  int64_t timestamp_ns = 0;
  Mat3 work_from_original = Mat3::Identity();
  cv::Size work_size;
  FrameMetadata metadata;
};

struct SkippedInput {
  std::string file;
  std::string reason;
};

// What the flight has recorded so far, read by its followers (the live view, the end of the flight): every frame's
// session record, the inputs skipped, and a read-only view of the engine's registration (maps, components, edges).
// Written only by the FlightSession that owns it (Append, AddSkipped); per-frame reads are by id, never a scan.
class FlightRecord {
 public:
  // Borrows the engine, which must outlive the record.
  explicit FlightRecord(const RegistrationEngine* engine) : engine_(engine) {}

  [[nodiscard]] size_t size() const { return frames_.size(); }
  [[nodiscard]] const SessionFrame& frame(int id) const { return frames_.at(static_cast<size_t>(id)); }
  [[nodiscard]] const std::deque<SessionFrame>& frames() const { return frames_; }
  [[nodiscard]] const std::vector<SkippedInput>& skipped() const { return skipped_; }
  [[nodiscard]] const RegistrationEngine& engine() const { return *engine_; }

  // The FlightSession's: a new frame's record (its id is the engine's), and an input the source could not give.
  SessionFrame& Append() { return frames_.emplace_back(); }
  void AddSkipped(SkippedInput skipped) { skipped_.push_back(std::move(skipped)); }

 private:
  const RegistrationEngine* engine_;  // borrowed
  std::deque<SessionFrame> frames_;   // grows chunk by chunk: no doubling copy in a long flight
  std::vector<SkippedInput> skipped_;
};

}  // namespace uavm
