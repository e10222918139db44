#pragma once
// The capture side of the flight loop: a load thread (frames from the source, decoded, and their working copies) and
// a detect thread (their features, overlapping the previous frame's matching), joined by bounded queues.
#include <string>
#include <unordered_set>

#include "core/pipeline/flight_session.h"
#include "core/util/bounded_queue.h"
#include "firmware_app/app.h"
#include "hal/common/frame_source.h"
#include "hal/telemetry/telemetry_source.h"

namespace uavm::app {

// One captured item: a frame, or the record of an input the source skipped.
struct Item {
  hal::Status status = hal::Status::kOk;
  std::string name;
  std::string message;
  PreparedFrame prepared;
};

struct CaptureOutcome {
  bool source_failed = false;
  std::string source_error;
};

// The load thread: frames from the source (decoded, placed by `telemetry` when given) and their working copies, into
// `loaded` until the source ends, max_frames, a stop signal or a closed queue; inputs in `seen` (the journal's) are
// passed over. A stage of its own, so that the next frame's decode runs while this one's SIFT does (SIFT keeps about
// 1.6 of two cores busy; the decode and resize fill the rest).
void LoadFrames(const RunConfig& config, hal::FrameSource* source, hal::TelemetrySource* telemetry,
                const FramePreparer* preparer, const std::unordered_set<std::string>& seen, int delivered,
                BoundedQueue<Item>* loaded, CaptureOutcome* outcome);

// The detect thread: each loaded frame's features, into the flight queue. When the flight loop closes that queue
// (storage failed), `loaded` is closed too and the load thread stops.
void DetectFrames(const FramePreparer* preparer, BoundedQueue<Item>* loaded, BoundedQueue<Item>* queue);

}  // namespace uavm::app
