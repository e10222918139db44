#pragma once
#include <cstdint>
#include <string>

#include "hal/telemetry/telemetry_source.h"

namespace uavm::hal {

// Says in the log when telemetry stops placing frames, why, and when it places them again, so that a gap (a lost link,
// no GPS fix, a log that does not cover the frames) is never silent; report.json has the counters. One line per gap,
// not per frame.
class TelemetryWatch {
 public:
  // After each PoseFor(): whether it placed the frame, and the source's report just after.
  void Saw(const std::string& frame_name, bool placed, const TelemetryReport& report);
  [[nodiscard]] uint64_t gaps() const { return gaps_; }

  // Why telemetry could not place a frame, from what the counters did since `before`.
  [[nodiscard]] static std::string Reason(const TelemetryReport& before, const TelemetryReport& after);

 private:
  TelemetryReport last_;
  bool in_gap_ = false;
  uint64_t gaps_ = 0;
  uint64_t without_in_gap_ = 0;
};

}  // namespace uavm::hal
