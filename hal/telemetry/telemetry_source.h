#pragma once
#include <atomic>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <thread>

#include "core/frame/frame.h"
#include "hal/common/frame_source.h"
#include "hal/telemetry/geo_txt.h"
#include "hal/telemetry/mavlink.h"
#include "hal/telemetry/mavlink_signing.h"
#include "hal/telemetry/system_filter.h"
#include "hal/telemetry/tlog.h"
#include "hal/telemetry/track.h"

namespace uavm::hal {

struct TelemetryOptions {
  // Camera frames: how much later a frame's timestamp is than the moment the telemetry describes (the camera's
  // exposure-to-delivery latency minus the link's); the frame is looked up at timestamp - latency.
  int64_t latency_ns = 0;
  int64_t max_gap_ns = 2'000'000'000;   // fixes further apart than this do not place a frame between them
  int64_t max_hold_ns = 1'000'000'000;  // a frame after the newest fix takes it only within this
  // Replayed stills against a log: EXIF DateTimeOriginal is the camera's local time, the log's is UTC; this is
  // local - UTC in seconds (e.g. 3600 for CET). With camera trigger messages (frames matched by image number) it only
  // serves to tell a log of another flight.
  double exif_utc_offset_s = 0;
  // MAVLink sources: whose packets are taken (hal/telemetry/system_filter.h); 0 = the first autopilot heard.
  int system_id = 0;
  int component_id = 0;
  // MAVLink sources: the signing key (hal/telemetry/mavlink_signing.h); empty: signatures are not checked.
  std::string signing_key_file;
};

// What telemetry did for the flight: report.json "telemetry".
struct TelemetryReport {
  std::string kind;   // mavlink-udp, mavlink-serial, gpsd, tlog, geo
  std::string match;  // how frames found their pose: time, sequence, name
  uint64_t frames_asked = 0;
  uint64_t frames_placed = 0;   // got a position
  uint64_t frames_without = 0;  // telemetry could not say (stale, lost, no fix, not in the file): image-only
  TrackCounters track;
  mavlink::ParserCounters parser;
  mavlink::SystemFilterCounters system;  // MAVLink sources: whose packets were taken, what was ignored
  mavlink::SigningCounters signing;      // MAVLink sources with a signing key: what was refused, and why
  uint64_t resync_bytes = 0;
  bool log_truncated = false;
  bool log_overlaps_frames = true;    // false: a log of another flight (times that do not meet the frames')
  uint64_t triggers = 0;              // camera triggers in a log (frames matched by their image number)
  uint64_t triggers_missing = 0;      // frames whose trigger is not in the log (lost, or more frames than triggers)
  uint64_t triggers_without_fix = 0;  // frames whose trigger has no position (the autopilot had no GPS fix)
  uint64_t link_losses = 0;           // live links that reconnect (gpsd): connections lost during the flight
};

// Telemetry beside the frame source (an interface like FrameSource): where the vehicle was when each frame was taken.
// Start() opens the link or reads the file; PoseFor() is called once per frame, in order, from the capture thread.
// Status codes, no exceptions; a source that loses its link keeps answering nullopt (counted), the flight goes on.
class TelemetrySource {
 public:
  virtual ~TelemetrySource() = default;
  [[nodiscard]] virtual Status Start(std::string* error) = 0;
  virtual void Stop() {}
  [[nodiscard]] virtual std::optional<InterpolatedPose> PoseFor(const Frame& frame) = 0;
  [[nodiscard]] virtual TelemetryReport Report() const = 0;
  [[nodiscard]] virtual std::string Describe() const = 0;
  // Tells the ground station how the mapper is doing (a MAVLink STATUSTEXT back over the link: QGroundControl and
  // Mission Planner show it in their message log). Links only; never blocks, best effort.
  virtual void SendStatus(const std::string& /*text*/) {}
};

// --telemetry KIND:ARG: mavlink-udp:HOST:PORT (listen), mavlink-serial:DEVICE:BAUD, gpsd:HOST:PORT (connect),
// tlog:FILE, geo:FILE. Null with a reason in `error` for a malformed spec, or for gpsd in a build without libgps
// (start-up).
[[nodiscard]] std::unique_ptr<TelemetrySource> MakeTelemetrySource(const std::string& spec,
                                                                   const TelemetryOptions& options, std::string* error);

// Writes `pose` into the frame's metadata (what georeferencing and frames.csv read), replacing EXIF GPS: telemetry
// is the flight controller's filtered position, EXIF the camera's copy of it, when there is one.
void ApplyPose(const InterpolatedPose& pose, FrameMetadata* metadata);

// UNIX time (ns) of an EXIF "YYYY:MM:DD HH:MM:SS" taken as UTC; nullopt when it does not parse.
[[nodiscard]] std::optional<int64_t> ExifTimeUtcNs(const std::string& datetime);

}  // namespace uavm::hal
