#include "firmware_app/sources.h"

#include <spdlog/spdlog.h>

#include <cstdio>

#include "core/session/session_dir.h"
#include "hal/common/camera_options.h"
#include "hal/sim/sim_source.h"
#include "hal/v4l2/v4l2_source.h"
#ifdef UAVM_HAVE_LIBCAMERA
#include "hal/libcamera/libcamera_source.h"
#endif

namespace uavm::app {

bool LoadConfigFile(const std::string& path, RunConfig* config, std::string* error) {
  std::string text;
  if (!ReadTextFile(path, &text, error)) {
    *error = "config " + path + ": cannot read";
    return false;
  }
  return ParseOptionsYaml(text, path, &config->pipeline, error, {hal::kTelemetrySection}) &&
         hal::ParseTelemetryConfigYaml(text, path, &config->telemetry_timing, error);
}

std::string EffectiveConfigYaml(const RunConfig& config) {
  return ToYaml(config.pipeline) + hal::ToYaml(config.telemetry_timing);
}

std::unique_ptr<hal::FrameSource> MakeSource(const RunConfig& config, std::string* error) {
  const std::string& s = config.source;
  const auto colon = s.find(':');
  const std::string scheme = colon == std::string::npos ? "" : s.substr(0, colon);
  const std::string arg = colon == std::string::npos ? s : s.substr(colon + 1);
  if (scheme == "replay") {
    hal::ReplayOptions o;
    o.path = arg;
    o.stride = config.stride;
    return std::make_unique<hal::ReplaySource>(o);
  }
  if (scheme == "sim") {
    // A simulated flight over a real image (plan YAML: see hal/sim/sim_plan.h); frames are rendered, not decoded.
    return std::make_unique<hal::SimSource>(hal::SimOptions{arg, "", "", 0});
  }
  if (scheme == "v4l2" || scheme == "libcamera") {
    if (config.replay_interval_ms > 0) {
      *error = "--replay-interval-ms paces a replay or a simulation; a camera keeps its own cadence";
      return nullptr;
    }
    // A live camera: v4l2:/dev/videoN?width=..&height=..&format=..&fps=.. (hal/common/camera_options.h).
    hal::CaptureOptions o;
    if (!hal::ParseCaptureOptions(arg, &o, error)) return nullptr;
    if (scheme == "v4l2") return std::make_unique<hal::V4l2Source>(o);
#ifdef UAVM_HAVE_LIBCAMERA
    return std::make_unique<hal::LibcameraSource>(o);
#else
    *error = "this build has no libcamera back-end (configure with -DUAVM_WITH_LIBCAMERA=ON, needs libcamera-dev)";
    return nullptr;
#endif
  }
  *error = "unknown source '" + s + "' (expected replay:PATH, sim:PLAN.yaml, v4l2:/dev/videoN or libcamera:N)";
  return nullptr;
}

int ListCameras() {
  const auto v4l2 = hal::ListV4l2Devices();
  std::printf("V4L2 (%zu nodes):\n", v4l2.size());
  for (const auto& d : v4l2) {
    std::printf("  v4l2:%s  %s (%s, %s)%s\n", d.path.c_str(), d.card.c_str(), d.driver.c_str(), d.bus.c_str(),
                d.capture ? "" : "  [no single-planar capture]");
    for (const auto& f : d.formats) std::printf("      %s\n", f.c_str());
  }
#ifdef UAVM_HAVE_LIBCAMERA
  std::string error;
  const auto cams = hal::ListLibcameraCameras(&error);
  if (!error.empty()) std::printf("libcamera: %s\n", error.c_str());
  std::printf("libcamera (%zu cameras):\n", cams.size());
  for (const auto& c : cams) std::printf("  %s\n", c.c_str());
#else
  std::printf("libcamera: not built (UAVM_WITH_LIBCAMERA=OFF)\n");
#endif
  std::fflush(stdout);
  return kExitOk;
}

std::unique_ptr<hal::TelemetrySource> StartTelemetry(const RunConfig& config, bool* failed) {
  *failed = false;
  if (config.telemetry.empty()) return nullptr;
  const hal::TelemetryOptions options = config.telemetry_timing.ToOptions();
  std::string error;
  auto source = hal::MakeTelemetrySource(config.telemetry, options, &error);
  if (source && source->Start(&error) != hal::Status::kOk) source.reset();
  if (!source) {
    spdlog::error("{}", error);
    *failed = true;
    return nullptr;
  }
  spdlog::info("telemetry: {}", source->Describe());
  return source;
}

nlohmann::json TelemetryJson(const hal::TelemetryReport& r) {
  return {{"kind", r.kind},
          {"match", r.match},
          {"frames_asked", r.frames_asked},
          {"frames_placed", r.frames_placed},
          {"frames_without", r.frames_without},
          {"fixes", r.track.fixes},
          {"no_fix", r.track.no_fix},
          {"stale", r.track.stale},
          {"outside", r.track.outside},
          {"out_of_order", r.track.out_of_order},
          {"history_overwritten", r.track.overwritten},
          {"packets", r.parser.packets},
          {"crc_errors", r.parser.crc_errors},
          {"unknown_messages", r.parser.unknown},
          {"signed_packets_unverified", r.signing.enabled ? 0 : r.parser.signed_packets},
          {"packets_cut_short", r.parser.cut_short},
          {"signing",
           {{"enabled", r.signing.enabled},
            {"accepted", r.signing.accepted},
            {"unsigned_refused", r.signing.unsigned_refused},
            {"bad_signature", r.signing.bad_signature},
            {"replayed", r.signing.replayed},
            {"new_stream_refused", r.signing.new_stream_refused}}},
          {"system_id", r.system.system_id},
          {"component_id", r.system.component_id},
          {"packets_of_other_systems", r.system.foreign},
          {"packets_before_an_autopilot", r.system.before_lock},
          {"other_autopilots", r.system.other_autopilots},
          {"bytes_skipped", r.parser.bytes_skipped + r.resync_bytes},
          {"log_truncated", r.log_truncated},
          {"log_overlaps_frames", r.log_overlaps_frames},
          {"triggers", r.triggers},
          {"triggers_missing", r.triggers_missing},
          {"triggers_without_fix", r.triggers_without_fix},
          {"link_losses", r.link_losses}};
}

bool ReplayStoredFrames::Open(const std::string& frames_dir, std::string* error) {
  hal::ReplayOptions options;
  options.path = frames_dir;
  replay_ = std::make_unique<hal::ReplaySource>(options);
  return replay_->Open(error) == hal::Status::kOk;
}

StoredFrameReader::Status ReplayStoredFrames::Next(Frame* frame) {
  std::string error;
  switch (replay_->Next(frame, &error)) {
    case hal::Status::kOk:
      return Status::kFrame;
    case hal::Status::kSkipped:
      return Status::kUnreadable;
    case hal::Status::kEndOfStream:
    case hal::Status::kError:
      break;
  }
  return Status::kEnd;
}

}  // namespace uavm::app
