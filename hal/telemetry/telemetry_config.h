#pragma once
// The telemetry's configuration keys (`telemetry:` in the onboard program's YAML config), in the units an operator
// writes them: hal's own, checked here, turned into TelemetryOptions for the sources. The program's other keys are
// core's (core/pipeline/options.h), which passes this section over.
#include <string>

#include "hal/telemetry/telemetry_source.h"

namespace uavm::hal {

struct TelemetryConfig {
  double latency_ms = 0.0;         // a camera frame is looked up at its timestamp minus this
  double max_gap_s = 2.0;          // fixes further apart than this place no frame between them
  double max_hold_s = 1.0;         // a frame after the newest fix (link lost) takes it only within this
  double exif_utc_offset_s = 0.0;  // replayed stills: EXIF local time minus UTC
  // MAVLink: the vehicle whose telemetry is taken (hal/telemetry/system_filter.h); 0 = the first autopilot heard.
  double system_id = 0;
  double component_id = 0;
  // MAVLink signing (hal/telemetry/mavlink_signing.h): the 32-byte key's file; empty: signatures not checked.
  std::string signing_key_file;

  [[nodiscard]] bool Check(std::string* why) const;
  [[nodiscard]] TelemetryOptions ToOptions() const;
};

inline constexpr const char* kTelemetrySection = "telemetry";

// Reads the `telemetry:` section of YAML `text` (other sections are not this unit's); `origin` names the text in
// messages. An unknown key, a wrong type or a value Check() refuses is an error, and so is a signing key file that
// does not hold a key; no section leaves `config` as is.
[[nodiscard]] bool ParseTelemetryConfigYaml(const std::string& text, const std::string& origin, TelemetryConfig* config,
                                            std::string* error);
// The section as YAML (`telemetry:` and its keys), for --print-config and the session's config.yaml.
[[nodiscard]] std::string ToYaml(const TelemetryConfig& config);

}  // namespace uavm::hal
