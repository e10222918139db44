#pragma once
#include <sys/socket.h>

#include <cstdint>
#include <string>
#include <vector>

#include "hal/sim/sim_source.h"
#include "hal/telemetry/mavlink.h"

namespace uavm::hal {

// One MAVLink v2 packet of a simulated flight's telemetry at flight time t_s (frame i is taken at i *
// frame_interval_s).
struct TimedPacket {
  double t_s = 0.0;
  std::string bytes;
};

// The flight controller's MAVLink stream of a simulated flight (plan gps: 1), as ArduPilot sends it to a ground
// station, from system 1 component 1 with the encoder of hal/telemetry/mavlink.h:
//   at telemetry_hz: GLOBAL_POSITION_INT (position, height above take-off, velocity, heading), GPS_RAW_INT (a 3-D fix
//     with its accuracy, gps_noise_m) and ATTITUDE (roll and pitch with attitude_noise_deg, yaw = the heading);
//   at 1 Hz: HEARTBEAT (an armed ArduPilot quadcopter) and SYSTEM_TIME;
//   at each frame's instant: CAMERA_FEEDBACK with the frame's own fix (img_idx = ArduPilot's image count: 1 for the
//     first frame of the flight), so that a replay matches frames by trigger sequence.
// The plan's faults: over telemetry_lost_* nothing is sent; over gps_no_fix_* the fixes and triggers carry no position.
// Positions follow SimSource::FixAt (take-off at sea level: altitude MSL = height above take-off). The stream starts
// 1 s before the first frame and ends 1 s after the last; flight time 0 is kSimEpochUnixUs (UTC). With the plan's
// mavlink_signing_key_file every packet is signed (link id 0), its timestamp its flight time's, made newer than the
// last one's when several go in one tick.
class SimTelemetry {
 public:
  static constexpr uint64_t kSimEpochUnixUs = 1717243200ULL * 1000000ULL;  // 2024-06-01 12:00:00 UTC
  static constexpr double kBootS = 120.0;  // the autopilot had been up for this long at flight time 0

  // Frames [first_frame, end_frame) of `source` (open, borrowed).
  SimTelemetry(const SimSource* source, size_t first_frame, size_t end_frame);
  // The packets of the next telemetry tick, in time order; false after the end of the stream.
  [[nodiscard]] bool NextSlot(std::vector<TimedPacket>* out);
  [[nodiscard]] static uint64_t UnixUs(double t_s);

 private:
  void AddFix(double t_s, std::vector<TimedPacket>* out);
  void AddCameraFeedback(size_t frame, std::vector<TimedPacket>* out);
  void Add(double t_s, const mavlink::Message& m, std::vector<TimedPacket>* out);

  const SimSource* source_;  // borrowed
  size_t next_frame_;
  size_t end_frame_;
  int64_t slot_;
  int64_t end_slot_;
  uint8_t seq_ = 0;
  uint64_t signing_timestamp_ = 0;  // the last one signed: each packet's is newer (the receiver refuses replays)
};

// The whole stream of frames [first_frame, end_frame) as a telemetry log as QGroundControl and MAVProxy write it
// (.tlog: each packet after its time, 8 bytes big-endian UNIX microseconds).
[[nodiscard]] std::string SimTlog(const SimSource& source, size_t first_frame, size_t end_frame);

// The live stream (plan mavlink_udp): the telemetry goes over UDP in real time, in step with the frames. Frame i is
// delivered camera_latency_ms after it was taken: DeliverFrame(i) sends every packet up to that moment, each when its
// flight time comes, and returns the frame's timestamp on the monotonic clock (the telemetry's clock at the
// receiver: a receiver that looks the frame up at timestamp - camera_latency_ms finds the fix the frame was taken
// at). When the consumer falls behind (a packet is late), the flight's clock waits for it: the stream never bursts.
class SimUdpLink {
 public:
  explicit SimUdpLink(const SimSource* source);
  ~SimUdpLink();
  SimUdpLink(const SimUdpLink&) = delete;
  SimUdpLink& operator=(const SimUdpLink&) = delete;
  [[nodiscard]] bool Open(const std::string& host_port, std::string* error);
  [[nodiscard]] int64_t DeliverFrame(size_t i);

 private:
  void SendPaced(const TimedPacket& p);
  [[nodiscard]] int64_t WallNs(double t_s) const;

  const SimSource* source_;  // borrowed
  SimTelemetry telemetry_;
  std::vector<TimedPacket> pending_;
  size_t pending_next_ = 0;
  bool ended_ = false;
  int fd_ = -1;
  sockaddr_storage to_{};
  socklen_t to_len_ = 0;
  bool started_ = false;
  int64_t offset_ns_ = 0;  // monotonic ns of flight time 0
};

}  // namespace uavm::hal
