#include "hal/sim/sim_telemetry.h"

#include <netdb.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <thread>

#include "core/util/clock.h"

namespace uavm::hal {

namespace {

constexpr double kLeadS = 1.0;  // telemetry before the first frame and after the last
constexpr double kDegToRad = M_PI / 180.0;
constexpr uint8_t kSysId = 1;
constexpr uint8_t kCompId = 1;             // MAV_COMP_ID_AUTOPILOT1
constexpr int64_t kLateNs = 2'000'000;     // a packet later than this holds the flight's clock
constexpr int64_t kSettleNs = 20'000'000;  // a frame comes this long after the last packet sent before it

// Whether flight time t_s falls in the plan's span [from, to) of the flight (fractions of first frame -> last).
bool InSpan(const SimSource& source, double t_s, double from, double to) {
  if (!(to > from)) return false;
  const size_t n = source.NumFrames();
  const double first = source.FrameTime(0), last = source.FrameTime(n > 0 ? n - 1 : 0);
  const double f = last > first ? (t_s - first) / (last - first) : 0.0;
  return f >= from && f < to;
}

uint32_t BootMs(double t_s) {
  return static_cast<uint32_t>(std::llround((t_s + SimTelemetry::kBootS) * 1e3));
}

}  // namespace

SimTelemetry::SimTelemetry(const SimSource* source, size_t first_frame, size_t end_frame)
    : source_(source), next_frame_(first_frame), end_frame_(end_frame) {
  const double hz = source->plan().telemetry_hz;
  const double first = source->FrameTime(first_frame) - kLeadS;
  const double last = source->FrameTime(end_frame > first_frame ? end_frame - 1 : first_frame) + kLeadS;
  slot_ = static_cast<int64_t>(std::floor(first * hz));
  end_slot_ = static_cast<int64_t>(std::ceil(last * hz)) + 1;
}

uint64_t SimTelemetry::UnixUs(double t_s) {
  return static_cast<uint64_t>(static_cast<int64_t>(kSimEpochUnixUs) + std::llround(t_s * 1e6));
}

void SimTelemetry::Add(double t_s, const mavlink::Message& m, std::vector<TimedPacket>* out) {
  std::string bytes = mavlink::Encode(m, seq_++, kSysId, kCompId);
  if (const auto& key = source_->signing_key()) {
    signing_timestamp_ = std::max(mavlink::SigningTimestamp(UnixUs(t_s)), signing_timestamp_ + 1);
    bytes = mavlink::Sign(bytes, *key, 0, signing_timestamp_);
  }
  out->push_back({t_s, std::move(bytes)});
}

void SimTelemetry::AddFix(double t_s, std::vector<TimedPacket>* out) {
  const SimPlan& plan = source_->plan();
  const SimFix fix = source_->FixAt(t_s, static_cast<uint64_t>(slot_));
  const bool no_fix = InSpan(*source_, t_s, plan.gps_no_fix_from, plan.gps_no_fix_to);
  mavlink::GlobalPositionInt g;
  g.time_boot_ms = BootMs(t_s);
  g.lat_deg = no_fix ? 0.0 : fix.gps_position.lat_deg;
  g.lon_deg = no_fix ? 0.0 : fix.gps_position.lon_deg;
  g.alt_msl_m = fix.altitude_m;
  g.relative_alt_m = fix.altitude_m;
  g.vx_mps = fix.north_mps;  // MAVLink's NED frame
  g.vy_mps = fix.east_mps;
  g.heading_deg = fix.heading_deg;
  Add(t_s, g, out);
  mavlink::GpsRawInt r;
  r.time_usec = static_cast<uint64_t>(g.time_boot_ms) * 1000;
  r.lat_deg = g.lat_deg;
  r.lon_deg = g.lon_deg;
  r.alt_msl_m = g.alt_msl_m;
  r.fix_type = no_fix ? 1 : 3;
  r.satellites = 14;
  r.eph = 0.9;
  if (plan.gps_noise_m > 0) r.h_acc_m = plan.gps_noise_m;
  if (plan.gps_noise_m > 0) r.v_acc_m = 1.5 * plan.gps_noise_m;
  Add(t_s, r, out);
  const double yaw = std::remainder(fix.heading_deg, 360.0);  // (-180, 180]
  Add(t_s, mavlink::Attitude{g.time_boot_ms, fix.roll_deg * kDegToRad, fix.pitch_deg * kDegToRad, yaw * kDegToRad},
      out);
}

void SimTelemetry::AddCameraFeedback(size_t frame, std::vector<TimedPacket>* out) {
  const double t_s = source_->FrameTime(frame);
  const SimFix fix = source_->FixAt(t_s, static_cast<uint64_t>(slot_));
  const SimPlan& plan = source_->plan();
  const bool no_fix = InSpan(*source_, t_s, plan.gps_no_fix_from, plan.gps_no_fix_to);
  mavlink::CameraFeedback c;
  c.time_usec = UnixUs(t_s);
  c.lat_deg = no_fix ? 0.0 : fix.gps_position.lat_deg;
  c.lon_deg = no_fix ? 0.0 : fix.gps_position.lon_deg;
  c.alt_msl_m = fix.altitude_m;
  c.alt_rel_m = fix.altitude_m;
  c.roll_deg = fix.roll_deg;
  c.pitch_deg = fix.pitch_deg;
  c.yaw_deg = fix.heading_deg;
  c.image_index = static_cast<uint16_t>(frame + 1);
  Add(t_s, c, out);
}

bool SimTelemetry::NextSlot(std::vector<TimedPacket>* out) {
  out->clear();
  if (slot_ >= end_slot_) return false;
  const int hz = source_->plan().telemetry_hz;
  const double t_s = static_cast<double>(slot_) / hz;
  if (slot_ % hz == 0) {
    // AUTO (custom mode 3), MAV_TYPE_QUADROTOR, MAV_AUTOPILOT_ARDUPILOTMEGA, armed + auto + custom mode,
    // MAV_STATE_ACTIVE.
    Add(t_s, mavlink::Heartbeat{3, 2, 3, 0x80 | 0x04 | 0x01, 4}, out);
    Add(t_s, mavlink::SystemTime{UnixUs(t_s), BootMs(t_s)}, out);
  }
  AddFix(t_s, out);
  const double next_s = static_cast<double>(slot_ + 1) / hz;
  while (next_frame_ < end_frame_ && source_->FrameTime(next_frame_) < next_s - 1e-9) {
    AddCameraFeedback(next_frame_, out);
    ++next_frame_;
  }
  ++slot_;
  // A lost link: nothing of this tick reaches the ground station (the frames are still taken).
  if (InSpan(*source_, t_s, source_->plan().telemetry_lost_from, source_->plan().telemetry_lost_to)) out->clear();
  return true;
}

std::string SimTlog(const SimSource& source, size_t first_frame, size_t end_frame) {
  SimTelemetry telemetry(&source, first_frame, end_frame);
  std::string out;
  std::vector<TimedPacket> slot;
  while (telemetry.NextSlot(&slot)) {
    for (const TimedPacket& p : slot) {
      const uint64_t us = SimTelemetry::UnixUs(p.t_s);
      for (int shift = 56; shift >= 0; shift -= 8) out.push_back(static_cast<char>((us >> shift) & 0xFF));
      out += p.bytes;
    }
  }
  return out;
}

SimUdpLink::SimUdpLink(const SimSource* source) : source_(source), telemetry_(source, 0, source->NumFrames()) {}

SimUdpLink::~SimUdpLink() {
  if (fd_ >= 0) close(fd_);
}

bool SimUdpLink::Open(const std::string& host_port, std::string* error) {
  const auto colon = host_port.rfind(':');
  addrinfo hints{};
  hints.ai_family = AF_UNSPEC;
  hints.ai_socktype = SOCK_DGRAM;
  addrinfo* res = nullptr;
  if (colon == std::string::npos ||
      getaddrinfo(host_port.substr(0, colon).c_str(), host_port.substr(colon + 1).c_str(), &hints, &res) != 0 ||
      res == nullptr) {
    *error = "sim: mavlink_udp: cannot resolve '" + host_port + "' (expected HOST:PORT)";
    return false;
  }
  fd_ = socket(res->ai_family, res->ai_socktype | SOCK_CLOEXEC, 0);
  std::copy_n(reinterpret_cast<const uint8_t*>(res->ai_addr), res->ai_addrlen, reinterpret_cast<uint8_t*>(&to_));
  to_len_ = res->ai_addrlen;
  freeaddrinfo(res);
  if (fd_ < 0) *error = "sim: mavlink_udp: cannot open a UDP socket";
  return fd_ >= 0;
}

int64_t SimUdpLink::WallNs(double t_s) const {
  return offset_ns_ + std::llround(t_s * 1e9);
}

void SimUdpLink::SendPaced(const TimedPacket& p) {
  const int64_t due = WallNs(p.t_s);
  const int64_t now = MonotonicNs();
  if (due > now) {
    std::this_thread::sleep_for(std::chrono::nanoseconds(due - now));
  } else if (now - due > kLateNs) {
    offset_ns_ += now - due;  // the consumer held the flight up: its clock waits, the stream never bursts
  }
  // Best effort, as a flight controller's link: nobody listening is not an error.
  (void)sendto(fd_, p.bytes.data(), p.bytes.size(), MSG_DONTWAIT, reinterpret_cast<const sockaddr*>(&to_), to_len_);
}

int64_t SimUdpLink::DeliverFrame(size_t i) {
  const double delivered_s = source_->FrameTime(i) + source_->plan().camera_latency_ms * 1e-3;
  if (!started_) {
    ended_ = !telemetry_.NextSlot(&pending_);
    offset_ns_ = MonotonicNs() - (pending_.empty() ? 0 : std::llround(pending_.front().t_s * 1e9));
    started_ = true;
  }
  while (!ended_) {
    if (pending_next_ == pending_.size()) {
      pending_next_ = 0;
      ended_ = !telemetry_.NextSlot(&pending_);
      continue;
    }
    if (pending_[pending_next_].t_s > delivered_s + 1e-9) break;
    SendPaced(pending_[pending_next_++]);
  }
  // The frame's own moment on the stream's clock; handed over a little later, so that the receiver has read what
  // was sent before it.
  const int64_t stamp = WallNs(delivered_s);
  const int64_t wait = stamp + kSettleNs - MonotonicNs();
  if (wait > 0) std::this_thread::sleep_for(std::chrono::nanoseconds(wait));
  return stamp;
}

}  // namespace uavm::hal
