#include "firmware_app/capture.h"

#include "core/util/clock.h"
#include "core/util/trigger_schedule.h"
#include "hal/telemetry/telemetry_watch.h"

namespace uavm::app {

namespace {

// An input OpenCV cannot process (e.g. a degenerate size) is skipped like a corrupt file, never fatal.
void MarkUnprocessable(const std::exception& e, Item* item) {
  item->status = hal::Status::kSkipped;
  item->message = std::string("cannot process frame: ") + e.what();
}

}  // namespace

void LoadFrames(const RunConfig& config, hal::FrameSource* source, hal::TelemetrySource* telemetry,
                const FramePreparer* preparer, const std::unordered_set<std::string>& seen, int delivered,
                BoundedQueue<Item>* loaded, CaptureOutcome* outcome) {
  hal::TelemetryWatch telemetry_watch;
  TriggerSchedule camera(std::chrono::milliseconds(config.replay_interval_ms));
  for (;;) {
    if (config.max_frames > 0 && delivered >= config.max_frames) break;
    if (StopSignal() != 0) break;
    Item item;
    std::string err;
    hal::Frame frame;
    camera.Wait();  // a real-time replay's next trigger (not part of the decode)
    StageTimer decode_timer;
    item.status = source->Next(&frame, &err);
    const double decode_ms = decode_timer.ElapsedMs();
    item.name = frame.source_name;
    if (item.status == hal::Status::kEndOfStream) break;
    if (item.status == hal::Status::kError) {
      outcome->source_failed = true;
      outcome->source_error = err;
      break;
    }
    item.message = err;
    if (seen.count(item.name) != 0) continue;  // accepted or skipped before the interruption
    if (item.status == hal::Status::kOk) {
      try {
        // The session's rule for frames of one colour, applied here before any work is spent on them: a black or
        // saturated frame needs no position to be refused; another needs its position (the telemetry's) to be kept.
        const Flatness flatness = MeasureFlatness(frame.image);
        if (!flatness.blank && telemetry) {
          const auto pose = telemetry->PoseFor(frame);
          if (pose) hal::ApplyPose(*pose, &frame.metadata);
          telemetry_watch.Saw(frame.source_name, pose.has_value(), telemetry->Report());
        }
        if (const char* why = WhyNotRegistrable(flatness, frame.metadata)) {
          item.status = hal::Status::kSkipped;
          item.message = why;
        } else {
          ++delivered;
          item.prepared = preparer->PrepareImages(std::move(frame), flatness);
          item.prepared.decode_ms = decode_ms;
        }
      } catch (const std::exception& e) {
        MarkUnprocessable(e, &item);
      }
    }
    if (!loaded->Push(std::move(item))) break;
  }
  loaded->Close();
}

void DetectFrames(const FramePreparer* preparer, BoundedQueue<Item>* loaded, BoundedQueue<Item>* queue) {
  while (auto item = loaded->Pop()) {
    if (item->status == hal::Status::kOk) {
      try {
        preparer->DetectFeatures(&item->prepared);
      } catch (const std::exception& e) {
        MarkUnprocessable(e, &*item);
      }
    }
    if (!queue->Push(std::move(*item))) {
      loaded->Close();
      break;
    }
  }
  queue->Close();
}

}  // namespace uavm::app
