#pragma once
#include <deque>
#include <memory>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "core/frame/frame.h"
#include "core/geometry/transform.h"
#include "core/registration/registration_engine.h"

namespace uavm {

// The session's record of one frame (the engine keeps the registration's, under the same id). Every frame of the
// flight has one until its end, so it holds nothing it can derive, and no metadata where the frame has none.
struct SessionFrame {
  int id = -1;
  std::string name;
  std::string stored_file;  // path inside the session's frames/
  cv::Size original_size;
  int64_t timestamp_ns = 0;
  cv::Size work_size;

  // The working copy's pixels from the original's: the resize between the two sizes.
  [[nodiscard]] Mat3 work_from_original() const {
    return ResizeMap(static_cast<double>(work_size.width) / original_size.width,
                     static_cast<double>(work_size.height) / original_size.height);
  }
  // What the frame carried (position, attitude, camera); empty for a simulated or a bare camera frame, which holds
  // none (~240 bytes a frame).
  [[nodiscard]] const FrameMetadata& metadata() const { return metadata_ != nullptr ? *metadata_ : kNone; }
  void set_metadata(const FrameMetadata& metadata) {
    metadata_ = metadata.Empty() ? nullptr : std::make_unique<const FrameMetadata>(metadata);
  }

 private:
  static inline const FrameMetadata kNone{};
  std::unique_ptr<const FrameMetadata> metadata_;
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
