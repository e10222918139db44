#include "hal/telemetry/telemetry_source.h"

#include <arpa/inet.h>
#include <fcntl.h>
#include <netdb.h>
#include <poll.h>
#include <spdlog/spdlog.h>
#include <sys/socket.h>
#include <termios.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstring>
#include <ctime>
#include <mutex>
#include <thread>
#include <vector>

#include "core/util/clock.h"
#ifdef UAVM_HAVE_GPSD
#include "hal/telemetry/gpsd_source.h"
#endif

namespace uavm::hal {

namespace {

constexpr double kRadToDeg = 180.0 / M_PI;

PositionFix FixOf(const mavlink::GlobalPositionInt& g, int64_t t_ns) {
  return {t_ns,         g.lat_deg, g.lon_deg, g.alt_msl_m, g.relative_alt_m,
          std::nullopt, g.vx_mps,  g.vy_mps,  -g.vz_mps};  // NED
}
PositionFix FixOf(const mavlink::GpsRawInt& g, int64_t t_ns) {
  return {t_ns, g.lat_deg, g.lon_deg, g.alt_msl_m, std::nullopt, g.h_acc_m, std::nullopt, std::nullopt, std::nullopt};
}
AttitudeSample AttitudeOf(const mavlink::Attitude& a, int64_t t_ns) {
  return {t_ns, a.roll_rad * kRadToDeg, a.pitch_rad * kRadToDeg, a.yaw_rad * kRadToDeg};
}

// Feeds decoded messages into a track. GLOBAL_POSITION_INT (the autopilot's fused estimate, with height above
// take-off) wins over GPS_RAW_INT (the receiver's raw fix) once the link has shown it sends it.
class TrackFeeder {
 public:
  explicit TrackFeeder(TelemetryTrack* track) : track_(track) {}
  void Add(const mavlink::Message& m, int64_t t_ns) {
    if (const auto* g = std::get_if<mavlink::GlobalPositionInt>(&m)) {
      have_fused_ = true;
      track_->AddFix(FixOf(*g, t_ns), !(g->lat_deg == 0 && g->lon_deg == 0));
    } else if (const auto* r = std::get_if<mavlink::GpsRawInt>(&m)) {
      if (!have_fused_) track_->AddFix(FixOf(*r, t_ns), r->fix_type >= 3);
    } else if (const auto* a = std::get_if<mavlink::Attitude>(&m)) {
      track_->AddAttitude(AttitudeOf(*a, t_ns));
    }
  }

 private:
  TelemetryTrack* track_;  // borrowed
  bool have_fused_ = false;
};

class GeoSource final : public TelemetrySource {
 public:
  explicit GeoSource(std::string path) : path_(std::move(path)) {}
  Status Start(std::string* error) override { return geo_.Load(path_, error) ? Status::kOk : Status::kError; }
  std::optional<InterpolatedPose> PoseFor(const Frame& frame) override {
    ++report_.frames_asked;
    const GeoTag* tag = geo_.Find(frame.source_name);
    if (tag == nullptr) {
      ++report_.frames_without;
      return std::nullopt;
    }
    ++report_.frames_placed;
    InterpolatedPose p;
    p.lat_deg = tag->lat_deg;
    p.lon_deg = tag->lon_deg;
    p.alt_msl_m = tag->alt_m.value_or(0.0);
    p.h_acc_m = tag->h_acc_m;
    p.yaw_deg = tag->kappa_deg;
    return p;
  }
  TelemetryReport Report() const override {
    TelemetryReport r = report_;
    r.kind = "geo";
    r.match = "name";
    return r;
  }
  std::string Describe() const override { return "geo.txt " + path_ + " (" + geo_.crs() + ")"; }

 private:
  std::string path_;
  GeoTxt geo_;
  TelemetryReport report_;
};

// A camera trigger in a log: CAMERA_FEEDBACK (ArduPilot) or CAMERA_IMAGE_CAPTURED (the MAVLink camera protocol).
struct Trigger {
  int64_t image_index = 0;
  uint64_t time_utc_us = 0;              // 0 when the autopilot did not know the time
  std::optional<InterpolatedPose> pose;  // none: the autopilot had no position (lat = lon = 0)
};

std::optional<InterpolatedPose> TriggerPose(double lat, double lon, double alt_msl, double alt_rel) {
  if (lat == 0 && lon == 0) return std::nullopt;
  InterpolatedPose t;
  t.lat_deg = lat;
  t.lon_deg = lon;
  t.alt_msl_m = alt_msl;
  t.relative_alt_m = alt_rel;
  return t;
}

Trigger TriggerOf(const mavlink::CameraFeedback& c) {
  Trigger t{c.image_index, c.time_usec, TriggerPose(c.lat_deg, c.lon_deg, c.alt_msl_m, c.alt_rel_m)};
  if (t.pose) {
    t.pose->roll_deg = c.roll_deg;
    t.pose->pitch_deg = c.pitch_deg;
    t.pose->yaw_deg = c.yaw_deg;
  }
  return t;
}

Trigger TriggerOf(const mavlink::CameraImageCaptured& c) {
  Trigger t{c.image_index, c.time_utc_usec, TriggerPose(c.lat_deg, c.lon_deg, c.alt_msl_m, c.relative_alt_m)};
  if (t.pose) {  // yaw of the camera's attitude quaternion (w x y z, NED)
    const auto& q = c.q;
    if (q[0] != 0 || q[1] != 0 || q[2] != 0 || q[3] != 0)
      t.pose->yaw_deg =
          std::atan2(2.0 * (q[0] * q[3] + q[1] * q[2]), 1.0 - 2.0 * (q[2] * q[2] + q[3] * q[3])) * kRadToDeg;
  }
  return t;
}

// The signature check of telemetry.signing_key_file; null (and no error) without one.
bool MakeSignatureCheck(const TelemetryOptions& options, std::unique_ptr<mavlink::SignatureCheck>* check,
                        std::string* error, mavlink::SigningKey* key_out = nullptr) {
  if (options.signing_key_file.empty()) return true;
  mavlink::SigningKey key{};
  if (!mavlink::ReadSigningKey(options.signing_key_file, &key, error)) return false;
  *check = std::make_unique<mavlink::SignatureCheck>(key);
  if (key_out != nullptr) *key_out = key;
  spdlog::info("telemetry: MAVLink signing on: unsigned, wrongly signed and replayed packets are refused");
  return true;
}

// A replayed flight's log: frames find their pose by camera trigger when the log has trigger messages (frame index i
// takes the trigger numbered first + i, so a trigger lost from the log costs one frame, not a shift of all those
// after it), else by EXIF time against the log's UTC time.
class TlogSource final : public TelemetrySource {
 public:
  TlogSource(std::string path, const TelemetryOptions& options) : path_(std::move(path)), options_(options) {}
  Status Start(std::string* error) override;
  std::optional<InterpolatedPose> PoseFor(const Frame& frame) override;
  TelemetryReport Report() const override {
    TelemetryReport r = report_;
    r.kind = "tlog";
    r.match = triggers_.empty() ? "time" : "sequence";
    r.triggers = triggers_.size();
    if (track_) r.track = track_->counters();
    return r;
  }
  std::string Describe() const override { return "telemetry log " + path_; }

 private:
  [[nodiscard]] std::optional<InterpolatedPose> ByTrigger(const Frame& frame);
  [[nodiscard]] std::optional<InterpolatedPose> ByTime(const Frame& frame);
  [[nodiscard]] std::optional<int64_t> FrameUtcNs(const Frame& frame) const;
  void WarnNotCovered(const Frame& frame, int64_t apart_ns, const char* what);

  std::string path_;
  TelemetryOptions options_;
  std::unique_ptr<TelemetryTrack> track_;
  std::vector<Trigger> triggers_;  // in image-index order
  bool warned_overlap_ = false, warned_missing_ = false, warned_no_fix_ = false;
  TelemetryReport report_;
};

// The triggers of one kind (CAMERA_FEEDBACK wins when a log has both): in increasing image-index order, as a camera
// counts its shots; a log whose indices go back (counters reset) is refused.
bool OrderTriggers(const std::string& path, std::vector<Trigger> feedback, std::vector<Trigger> captured,
                   std::vector<Trigger>* out, std::string* error) {
  *out = feedback.empty() ? std::move(captured) : std::move(feedback);
  for (size_t i = 1; i < out->size(); ++i)
    if ((*out)[i].image_index <= (*out)[i - 1].image_index) {
      *error = "telemetry log " + path + ": camera trigger image numbers go back (" +
               std::to_string((*out)[i - 1].image_index) + " then " + std::to_string((*out)[i].image_index) +
               "): a log of several flights? cut it to this one";
      return false;
    }
  return true;
}

Status TlogSource::Start(std::string* error) {
  std::vector<std::pair<int64_t, mavlink::Message>> messages;
  std::vector<Trigger> feedback, captured;
  mavlink::TlogStats stats;
  mavlink::SystemFilter filter(options_.system_id, options_.component_id);
  std::unique_ptr<mavlink::SignatureCheck> signatures;
  if (!MakeSignatureCheck(options_, &signatures, error)) return Status::kError;
  size_t fixes = 0;
  const bool ok = mavlink::ReadTlog(
      path_,
      [&](uint64_t us, const mavlink::Packet& p) {
        if (!filter.Accept(p)) return;  // another system's (counted)
        auto m = mavlink::Decode(p);
        if (!m) return;
        if (std::holds_alternative<mavlink::GlobalPositionInt>(*m) || std::holds_alternative<mavlink::GpsRawInt>(*m))
          ++fixes;
        if (const auto* c = std::get_if<mavlink::CameraFeedback>(&*m)) return feedback.push_back(TriggerOf(*c));
        if (const auto* c = std::get_if<mavlink::CameraImageCaptured>(&*m)) {
          if (c->capture_result == 1) captured.push_back(TriggerOf(*c));  // 0: the capture failed, no image
          return;
        }
        messages.emplace_back(static_cast<int64_t>(us) * 1000, std::move(*m));
      },
      &stats, error, signatures.get());
  if (!ok || !OrderTriggers(path_, std::move(feedback), std::move(captured), &triggers_, error)) return Status::kError;
  report_.parser = stats.parser;
  report_.system = filter.counters();
  if (signatures) report_.signing = signatures->counters();
  if (stats.parser.refused_by_signing > 0)
    spdlog::warn("telemetry log {}: {} packets refused by their signature ({} unsigned, {} another key, {} replayed)",
                 path_, stats.parser.refused_by_signing, report_.signing.unsigned_refused,
                 report_.signing.bad_signature, report_.signing.replayed);
  report_.resync_bytes = stats.resync_bytes;
  report_.log_truncated = stats.truncated;
  if (stats.parser.crc_errors + stats.resync_bytes > 0)
    spdlog::warn("telemetry log {}: {} bad checksums, {} bytes skipped: the damaged packets are left out", path_,
                 stats.parser.crc_errors, stats.resync_bytes);
  if (stats.truncated) spdlog::warn("telemetry log {} is cut off at the end (a packet half written)", path_);
  // A replay holds the log's fixes (~100 B each); live links keep a bounded window.
  track_ = std::make_unique<TelemetryTrack>(fixes + 1, options_.max_gap_ns, options_.max_hold_ns);
  TrackFeeder feeder(track_.get());
  for (const auto& [t, m] : messages) feeder.Add(m, t);
  if (triggers_.empty() && track_->counters().fixes == 0) {
    *error = "telemetry log " + path_ + " has no position (GLOBAL_POSITION_INT, GPS_RAW_INT with a 3-D fix)";
    return Status::kError;
  }
  spdlog::info("telemetry log {}: {} fixes, {} camera triggers", path_, track_->counters().fixes, triggers_.size());
  return Status::kOk;
}

std::optional<int64_t> TlogSource::FrameUtcNs(const Frame& frame) const {
  const auto t = ExifTimeUtcNs(frame.metadata.datetime_original);
  if (!t) return std::nullopt;
  return *t - static_cast<int64_t>(std::llround(options_.exif_utc_offset_s * 1e9));
}

void TlogSource::WarnNotCovered(const Frame& frame, int64_t apart_ns, const char* what) {
  report_.log_overlaps_frames = false;
  if (!warned_overlap_)
    spdlog::warn(
        "telemetry log {} does not cover frame {} ({} {} s apart): another flight, or a wrong "
        "telemetry.exif_utc_offset_s? frames keep their own GPS (EXIF), if any",
        path_, frame.source_name, what, std::llabs(apart_ns) / 1000000000);
  warned_overlap_ = true;
}

std::optional<InterpolatedPose> TlogSource::ByTrigger(const Frame& frame) {
  const int64_t want = triggers_.front().image_index + static_cast<int64_t>(frame.index);
  const auto it = std::lower_bound(triggers_.begin(), triggers_.end(), want,
                                   [](const Trigger& t, int64_t i) { return t.image_index < i; });
  if (it == triggers_.end() || it->image_index != want) {
    ++report_.triggers_missing;
    if (!warned_missing_)
      spdlog::warn(
          "telemetry log {}: no camera trigger numbered {} for frame {} (lost from the log, or more frames "
          "than triggers); such frames keep their own GPS (EXIF), if any",
          path_, want, frame.source_name);
    warned_missing_ = true;
    return std::nullopt;
  }
  // A camera's clock and the autopilot's cannot be a day apart whatever the time zone (at most 14 h): beyond that the
  // log is of another flight.
  constexpr int64_t kMaxZoneNs = 14LL * 3600 * 1000000000;
  const auto frame_utc = FrameUtcNs(frame);
  if (frame_utc && it->time_utc_us > 0) {
    const int64_t apart = *frame_utc - static_cast<int64_t>(it->time_utc_us) * 1000;
    if (std::llabs(apart) > kMaxZoneNs + options_.max_gap_ns) {
      WarnNotCovered(frame, apart, "EXIF time and its camera trigger");
      return std::nullopt;
    }
  }
  if (!it->pose) {
    ++report_.triggers_without_fix;
    if (!warned_no_fix_)
      spdlog::warn("telemetry log {}: the camera trigger of frame {} has no position (no GPS fix)", path_,
                   frame.source_name);
    warned_no_fix_ = true;
  }
  return it->pose;
}

std::optional<InterpolatedPose> TlogSource::ByTime(const Frame& frame) {
  const auto utc = FrameUtcNs(frame);
  if (!utc) return std::nullopt;
  auto pose = track_->At(*utc);
  const auto [first, last] = track_->span();
  if (!pose && (*utc < first - options_.max_gap_ns || *utc > last + options_.max_gap_ns))
    WarnNotCovered(frame, *utc < first ? first - *utc : *utc - last, "EXIF time and the log");
  return pose;
}

std::optional<InterpolatedPose> TlogSource::PoseFor(const Frame& frame) {
  ++report_.frames_asked;
  const auto pose = triggers_.empty() ? ByTime(frame) : ByTrigger(frame);
  ++(pose ? report_.frames_placed : report_.frames_without);
  return pose;
}

// A live MAVLink link (UDP or serial): a thread reads it into a bounded track stamped with the monotonic clock, the
// frames' own clock.
class LinkSource final : public TelemetrySource {
 public:
  LinkSource(std::string kind, std::string target, int port_or_baud, const TelemetryOptions& options)
      : kind_(std::move(kind)),
        target_(std::move(target)),
        port_or_baud_(port_or_baud),
        options_(options),
        track_(TelemetryTrack::kLiveCapacity, options.max_gap_ns, options.max_hold_ns) {}
  ~LinkSource() override { Stop(); }
  Status Start(std::string* error) override;
  void Stop() override {
    stop_ = true;
    if (thread_.joinable()) thread_.join();
    if (fd_ >= 0) close(fd_);
    fd_ = -1;
  }
  std::optional<InterpolatedPose> PoseFor(const Frame& frame) override {
    auto pose = track_.At(frame.timestamp_ns - options_.latency_ns);
    std::lock_guard lock(mutex_);
    ++report_.frames_asked;
    ++(pose ? report_.frames_placed : report_.frames_without);
    return pose;
  }
  TelemetryReport Report() const override {
    std::lock_guard lock(mutex_);
    TelemetryReport r = report_;
    r.kind = kind_;
    r.match = "time";
    r.track = track_.counters();
    r.parser = parser_counters_;
    r.system = system_counters_;
    r.signing = signing_counters_;
    return r;
  }
  std::string Describe() const override { return kind_ + " " + target_ + ":" + std::to_string(port_or_baud_); }
  void SendStatus(const std::string& text) override;

 private:
  [[nodiscard]] bool OpenUdp(std::string* error);
  [[nodiscard]] bool OpenSerial(std::string* error);
  void ReadLoop();
  // A serial link that hung up (a USB adapter unplugged, a cable pulled): counted, closed, and reopened every 0.5 s
  // until Stop(), instead of spinning on a dead descriptor.
  void ReopenSerial(const char* why);

  std::string kind_, target_;
  int port_or_baud_;
  TelemetryOptions options_;
  TelemetryTrack track_;
  int fd_ = -1;
  std::atomic<bool> stop_{false};
  std::thread thread_;
  mutable std::mutex mutex_;
  TelemetryReport report_;
  mavlink::ParserCounters parser_counters_;
  mavlink::SystemFilterCounters system_counters_;
  mavlink::SigningCounters signing_counters_;
  // With telemetry.signing_key_file: the check the reading thread runs (created by Start, before the thread), and the
  // key STATUSTEXT is signed with (a GCS that signs refuses unsigned packets).
  std::unique_ptr<mavlink::SignatureCheck> signatures_;
  std::optional<mavlink::SigningKey> signing_key_;
  sockaddr_storage peer_{};  // the vehicle's last datagram's sender (UDP): where STATUSTEXT goes
  socklen_t peer_len_ = 0;
  uint8_t status_seq_ = 0;
  uint64_t status_timestamp_ = 0;  // the last signed STATUSTEXT's
};

void LinkSource::SendStatus(const std::string& text) {
  // MAV_SEVERITY_INFO from component 191 (MAV_COMP_ID_ONBOARD_COMPUTER), system 1.
  std::string frame = mavlink::Encode(mavlink::Statustext{6, text}, status_seq_++, 1, 191);
  if (signing_key_) {
    // Newer than the last one whatever the clock does (a companion computer without a real-time clock reads 1970
    // until NTP or the GPS sets it; two messages may fall in one 10 us): the ground station refuses a replay.
    const auto now_us =
        std::chrono::duration_cast<std::chrono::microseconds>(std::chrono::system_clock::now().time_since_epoch());
    status_timestamp_ =
        std::max(mavlink::SigningTimestamp(static_cast<uint64_t>(now_us.count())), status_timestamp_ + 1);
    frame = mavlink::Sign(frame, *signing_key_, 0, status_timestamp_);
  }
  std::lock_guard lock(mutex_);
  if (fd_ < 0) return;
  if (kind_ == "mavlink-udp") {
    if (peer_len_ == 0) return;  // nobody has spoken yet: no address to answer
    (void)sendto(fd_, frame.data(), frame.size(), MSG_DONTWAIT, reinterpret_cast<const sockaddr*>(&peer_), peer_len_);
  } else {
    (void)write(fd_, frame.data(), frame.size());
  }
}

bool LinkSource::OpenUdp(std::string* error) {
  addrinfo hints{};
  hints.ai_family = AF_INET;
  hints.ai_socktype = SOCK_DGRAM;
  hints.ai_flags = AI_PASSIVE;
  addrinfo* res = nullptr;
  const std::string port = std::to_string(port_or_baud_);
  if (getaddrinfo(target_.empty() ? nullptr : target_.c_str(), port.c_str(), &hints, &res) != 0 || res == nullptr) {
    *error = "mavlink-udp: cannot resolve " + target_;
    return false;
  }
  fd_ = socket(res->ai_family, res->ai_socktype | SOCK_CLOEXEC, 0);
  const int one = 1;
  setsockopt(fd_, SOL_SOCKET, SO_REUSEADDR, &one, sizeof(one));
  const bool bound = fd_ >= 0 && bind(fd_, res->ai_addr, res->ai_addrlen) == 0;
  freeaddrinfo(res);
  if (!bound) *error = "mavlink-udp: cannot listen on " + target_ + ":" + port + ": " + std::strerror(errno);
  return bound;
}

bool LinkSource::OpenSerial(std::string* error) {
  fd_ = open(target_.c_str(), O_RDWR | O_NOCTTY | O_CLOEXEC);
  termios tio{};
  if (fd_ < 0 || tcgetattr(fd_, &tio) != 0) {
    *error = "mavlink-serial: cannot open " + target_ + ": " + std::strerror(errno);
    return false;
  }
  cfmakeraw(&tio);
  const speed_t speed = port_or_baud_ == 57600    ? B57600
                        : port_or_baud_ == 115200 ? B115200
                        : port_or_baud_ == 921600 ? B921600
                        : port_or_baud_ == 460800 ? B460800
                        : port_or_baud_ == 230400 ? B230400
                                                  : B0;
  if (speed == B0) {
    *error = "mavlink-serial: unsupported baud rate " + std::to_string(port_or_baud_);
    return false;
  }
  cfsetispeed(&tio, speed);
  cfsetospeed(&tio, speed);
  if (tcsetattr(fd_, TCSANOW, &tio) != 0) {
    *error = "mavlink-serial: cannot configure " + target_ + ": " + std::strerror(errno);
    return false;
  }
  return true;
}

Status LinkSource::Start(std::string* error) {
  mavlink::SigningKey key{};
  if (!MakeSignatureCheck(options_, &signatures_, error, &key)) return Status::kError;
  if (signatures_) signing_key_ = key;
  if (!(kind_ == "mavlink-udp" ? OpenUdp(error) : OpenSerial(error))) return Status::kError;
  thread_ = std::thread([this] { ReadLoop(); });
  return Status::kOk;
}

void LinkSource::ReadLoop() {
  mavlink::Parser parser;
  parser.RequireSignatures(signatures_.get());
  mavlink::SystemFilter filter(options_.system_id, options_.component_id);
  TrackFeeder feeder(&track_);
  std::vector<uint8_t> buf(65536);
  while (!stop_) {
    pollfd pfd{fd_, POLLIN, 0};
    if (poll(&pfd, 1, 200) <= 0) continue;  // wakes up to notice Stop()
    sockaddr_storage from{};
    socklen_t from_len = sizeof(from);
    const ssize_t n = kind_ == "mavlink-udp"
                          ? recvfrom(fd_, buf.data(), buf.size(), 0, reinterpret_cast<sockaddr*>(&from), &from_len)
                          : read(fd_, buf.data(), buf.size());
    const bool hung_up =
        (pfd.revents & (POLLHUP | POLLERR | POLLNVAL)) != 0 || n == 0 || (n < 0 && errno != EAGAIN && errno != EINTR);
    if (n <= 0 && kind_ != "mavlink-udp" && hung_up) ReopenSerial(n < 0 ? std::strerror(errno) : "hang-up");
    if (n <= 0) continue;
    const int64_t now = MonotonicNs();
    bool from_vehicle = false;
    parser.Feed(buf.data(), static_cast<size_t>(n), [&](const mavlink::Packet& p) {
      if (!filter.Accept(p)) return;  // another system's (counted)
      from_vehicle = true;
      if (auto m = mavlink::Decode(p)) feeder.Add(*m, now);
    });
    if (kind_ == "mavlink-udp") parser.EndDatagram();
    std::lock_guard lock(mutex_);
    if (from_vehicle && kind_ == "mavlink-udp") {  // STATUSTEXT goes back to the vehicle's link, not to any sender
      peer_ = from;
      peer_len_ = from_len;
    }
    parser_counters_ = parser.counters();
    system_counters_ = filter.counters();
    if (signatures_) signing_counters_ = signatures_->counters();
  }
}

void LinkSource::ReopenSerial(const char* why) {
  {
    std::lock_guard lock(mutex_);
    ++report_.link_losses;
    close(fd_);
    fd_ = -1;
  }
  spdlog::warn("telemetry: {} lost ({}); reopening it every 0.5 s, frames go on image-only meanwhile", target_, why);
  while (!stop_) {
    std::this_thread::sleep_for(std::chrono::milliseconds(500));
    std::string error;
    std::lock_guard lock(mutex_);
    if (OpenSerial(&error)) {
      spdlog::info("telemetry: {} reopened", target_);
      return;
    }
    if (fd_ >= 0) close(fd_);
    fd_ = -1;
  }
}

bool SplitLast(const std::string& s, std::string* head, int* number) {
  const auto colon = s.rfind(':');
  if (colon == std::string::npos) return false;
  *head = s.substr(0, colon);
  try {
    size_t used = 0;
    *number = std::stoi(s.substr(colon + 1), &used);
    return used == s.size() - colon - 1 && *number > 0;
  } catch (const std::exception&) {
    return false;
  }
}

std::unique_ptr<TelemetrySource> MakeGpsd(const std::string& arg, const TelemetryOptions& options, std::string* error) {
  std::string host;
  int port = 0;
  if (!SplitLast(arg, &host, &port) || host.empty() || port > 65535) {
    *error = "--telemetry gpsd: expected HOST:PORT (gpsd listens on 2947: gpsd:127.0.0.1:2947)";
    return nullptr;
  }
#ifdef UAVM_HAVE_GPSD
  return MakeGpsdSource(host, port, options);
#else
  (void)options;
  *error = "--telemetry gpsd: this build has no gpsd source (configure with -DUAVM_WITH_GPSD=ON, needs libgps-dev)";
  return nullptr;
#endif
}

}  // namespace

std::unique_ptr<TelemetrySource> MakeTelemetrySource(const std::string& spec, const TelemetryOptions& options,
                                                     std::string* error) {
  const auto colon = spec.find(':');
  const std::string kind = spec.substr(0, colon);
  const std::string arg = colon == std::string::npos ? "" : spec.substr(colon + 1);
  if (arg.empty()) {
    *error =
        "--telemetry: expected KIND:ARG (mavlink-udp:HOST:PORT, mavlink-serial:DEVICE:BAUD, gpsd:HOST:PORT, tlog:FILE, "
        "geo:FILE)";
    return nullptr;
  }
  if (kind == "geo") return std::make_unique<GeoSource>(arg);
  if (kind == "tlog") return std::make_unique<TlogSource>(arg, options);
  if (kind == "mavlink-udp" || kind == "mavlink-serial") {
    std::string target;
    int number = 0;
    if (!SplitLast(arg, &target, &number)) {
      *error = "--telemetry " + kind + ": expected " + (kind == "mavlink-udp" ? "HOST:PORT" : "DEVICE:BAUD");
      return nullptr;
    }
    return std::make_unique<LinkSource>(kind, target, number, options);
  }
  if (kind == "gpsd") return MakeGpsd(arg, options, error);
  *error = "--telemetry: unknown kind '" + kind + "' (mavlink-udp, mavlink-serial, gpsd, tlog, geo)";
  return nullptr;
}

void ApplyPose(const InterpolatedPose& pose, FrameMetadata* m) {
  m->latitude_deg = pose.lat_deg;
  m->longitude_deg = pose.lon_deg;
  m->altitude_m = pose.alt_msl_m;
  if (pose.relative_alt_m) m->relative_altitude_m = pose.relative_alt_m;
  if (pose.yaw_deg) m->flight_yaw_deg = pose.yaw_deg;
}

std::optional<int64_t> ExifTimeUtcNs(const std::string& s) {
  std::tm tm{};
  if (s.size() < 19 || std::sscanf(s.c_str(), "%d:%d:%d %d:%d:%d", &tm.tm_year, &tm.tm_mon, &tm.tm_mday, &tm.tm_hour,
                                   &tm.tm_min, &tm.tm_sec) != 6)
    return std::nullopt;
  tm.tm_year -= 1900;
  tm.tm_mon -= 1;
  const time_t t = timegm(&tm);
  if (t < 0) return std::nullopt;
  return static_cast<int64_t>(t) * 1000000000LL;
}

}  // namespace uavm::hal
