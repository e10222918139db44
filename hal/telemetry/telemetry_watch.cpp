#include "hal/telemetry/telemetry_watch.h"

#include <spdlog/spdlog.h>

namespace uavm::hal {

std::string TelemetryWatch::Reason(const TelemetryReport& before, const TelemetryReport& after) {
  if (!after.log_overlaps_frames) return "the log does not cover the frames' time (another flight?)";
  if (after.triggers_missing > before.triggers_missing) return "its camera trigger is not in the log";
  if (after.triggers_without_fix > before.triggers_without_fix || after.track.no_fix > before.track.no_fix)
    return "no GPS fix";
  if (after.link_losses > before.link_losses) return "the link was lost";
  if (after.track.stale > before.track.stale || after.track.outside > before.track.outside)
    return "no recent position (telemetry.max_hold_s / max_gap_s): the link is lost or silent";
  return "not in the telemetry";
}

void TelemetryWatch::Saw(const std::string& frame_name, bool placed, const TelemetryReport& report) {
  if (!placed && !in_gap_) {
    in_gap_ = true;
    ++gaps_;
    without_in_gap_ = 0;
    spdlog::warn("telemetry: no position for frame {}: {}; frames go on without telemetry until it returns", frame_name,
                 Reason(last_, report));
  } else if (placed && in_gap_) {
    in_gap_ = false;
    spdlog::warn("telemetry: positions again from frame {} ({} frames without)", frame_name, without_in_gap_);
  }
  if (!placed) ++without_in_gap_;
  // The counters at the last placed frame: a gap's reason is what changed since.
  if (placed) last_ = report;
}

}  // namespace uavm::hal
