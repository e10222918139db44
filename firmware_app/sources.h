#pragma once
// The program's sources: frames (replay, simulation, V4L2, libcamera), telemetry (--telemetry), and the session's
// stored frames read back for a resume.
#include <memory>
#include <nlohmann/json.hpp>
#include <string>

#include "core/pipeline/flight_session.h"
#include "firmware_app/app.h"
#include "hal/common/frame_source.h"
#include "hal/replay/replay_source.h"
#include "hal/telemetry/telemetry_source.h"

namespace uavm::app {

// The frame source `config.source` names; null with the reason in `error`.
[[nodiscard]] std::unique_ptr<hal::FrameSource> MakeSource(const RunConfig& config, std::string* error);

// --telemetry, started before the first frame (a listening link must hear the fixes before the frames they place).
// Null without --telemetry; `failed` when it was asked for and cannot start (start-up: a usage error).
[[nodiscard]] std::unique_ptr<hal::TelemetrySource> StartTelemetry(const RunConfig& config, bool* failed);

// report.json "telemetry".
[[nodiscard]] nlohmann::json TelemetryJson(const hal::TelemetryReport& r);

// A resumed session's frames/ read back through hal's replay (decoded with their EXIF).
class ReplayStoredFrames final : public StoredFrameReader {
 public:
  [[nodiscard]] bool Open(const std::string& frames_dir, std::string* error) override;
  [[nodiscard]] Status Next(Frame* frame) override;

 private:
  std::unique_ptr<hal::ReplaySource> replay_;
};

}  // namespace uavm::app
