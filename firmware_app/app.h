#pragma once
#include <string>

#include "core/pipeline/options.h"
#include "hal/telemetry/telemetry_config.h"

namespace uavm::app {

// Documented exit codes of uavmosaic-onboard.
enum ExitCode : int {
  kExitOk = 0,
  kExitUsage = 2,              // bad command line or config
  kExitSourceError = 3,        // the source cannot be opened (missing folder, no device)
  kExitOutputError = 4,        // the output directory cannot be created or written (incl. disk full)
  kExitNothingRegistered = 5,  // the run completed but no frame could be registered
};

struct RunConfig {
  std::string source;  // replay:PATH (folder or video), sim:PLAN.yaml, v4l2:/dev/videoN?..., libcamera:N?...
  std::string out_dir;
  int max_frames = 0;  // 0 = all
  int stride = 1;
  int replay_interval_ms = 0;  // replay or sim in real time: one input per interval, as a camera (0 = at once)
  // Continue the session in out_dir from its journal: the frames it accepted are registered again from the session
  // (no detection, same result), then the source goes on after them, skipping inputs the journal already has.
  bool resume = false;
  int process_delay_ms = 0;  // test hook: sleep this long per processed frame (a slow consumer)
  std::string http;          // live view HOST:PORT (firmware_app/live_server.h); empty = off
  std::string basemap;       // live page base map URL template (online); empty = offline
  double http_linger_s = 0;  // after the flight, the final map stays served this long (or until SIGTERM)
  // Live view access (firmware_app/access_gate.h): the token's file (needed off the loopback unless http_no_auth),
  // and HTTPS's PEM certificate and key files (both or neither).
  std::string http_token_file;
  bool http_no_auth = false;
  std::string http_cert_file;
  std::string http_key_file;
  std::string telemetry;  // --telemetry KIND:ARG (hal/telemetry/telemetry_source.h); empty = EXIF GPS only
  PipelineOptions pipeline;
  hal::TelemetryConfig telemetry_timing;  // the config's `telemetry:` keys (hal's)
};

// --config FILE: core's keys into config->pipeline, the telemetry's into config->telemetry_timing.
[[nodiscard]] bool LoadConfigFile(const std::string& path, RunConfig* config, std::string* error);
// --print-config and the session's config.yaml: every key the run uses, core's and hal's.
[[nodiscard]] std::string EffectiveConfigYaml(const RunConfig& config);

// SIGINT / SIGTERM: the capture stops, and what was received is registered and composited (exit 0 when that
// succeeds). A second signal does not interrupt the compositing: use SIGKILL, then --resume.
void InstallStopHandlers();
// The stop signal received (0: none yet).
[[nodiscard]] int StopSignal();

// --list-cameras: prints what the V4L2 and libcamera back-ends see. Returns an ExitCode.
[[nodiscard]] int ListCameras();

// The onboard loop: capture thread -> bounded queue -> registration -> outputs. Returns an ExitCode.
[[nodiscard]] int Run(const RunConfig& config);

}  // namespace uavm::app
