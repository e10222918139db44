#include "hal/telemetry/gpsd_source.h"

#include <spdlog/spdlog.h>

#include <atomic>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <mutex>
#include <optional>
#include <thread>

#include "core/util/clock.h"

// Last: libgps defines many short macros (MODE_SET, TIME_SET, ...).
#include <gps.h>

namespace uavm::hal {

namespace {

static_assert(GPSD_API_MAJOR_VERSION >= 9, "libgps with fix.altMSL / altHAE and timespec times (gpsd >= 3.20)");

constexpr double kMinSpeedForCourseMps = 1.0;  // below this the course over ground is noise, not a heading
// gpsd's eph is a 95 % horizontal radius; the track holds 1-sigma (a circular normal's R95 is 2.45 sigma).
constexpr double kR95ToSigma = 1.0 / 2.448;
constexpr int kMaxConnectAttempts = 60;  // in a row, backing off to 5 s: ~5 min without a daemon, then give up
constexpr auto kFirstBackoff = std::chrono::milliseconds(500);
constexpr auto kMaxBackoff = std::chrono::milliseconds(5000);
constexpr int kWaitUs = 200'000;  // gps_waiting's timeout: how soon the reader notices Stop()

class GpsdSource final : public TelemetrySource {
 public:
  GpsdSource(std::string host, int port, const TelemetryOptions& options)
      : host_(std::move(host)),
        port_(std::to_string(port)),
        options_(options),
        track_(TelemetryTrack::kLiveCapacity, options.max_gap_ns, options.max_hold_ns),
        gps_(std::make_unique<gps_data_t>()) {}
  ~GpsdSource() override { Stop(); }

  // Connects in the reader thread: a daemon that is not up yet (boot order) is waited for, not a start-up error.
  Status Start(std::string* /*error*/) override {
    thread_ = std::thread([this] { ReadLoop(); });
    return Status::kOk;
  }
  void Stop() override {
    stop_ = true;
    if (thread_.joinable()) thread_.join();
  }
  std::optional<InterpolatedPose> PoseFor(const Frame& frame) override;
  TelemetryReport Report() const override;
  std::string Describe() const override { return "gpsd " + host_ + ":" + port_; }

 private:
  void ReadLoop();
  // Opens the daemon and asks for JSON reports; false (errno's reason logged by the caller) when it cannot.
  [[nodiscard]] bool Connect();
  // Reads reports until Stop() (false) or until the daemon goes away (true); `heard`: it said something.
  [[nodiscard]] bool ReadSession(bool* heard);
  // After a failed attempt: false when giving up, else logs the first failure and backs off.
  [[nodiscard]] bool RetryLater(int* failures, std::chrono::milliseconds* backoff, const char* why);
  void AddReport(const gps_fix_t& fix, int64_t now_ns);
  void SleepUnlessStopped(std::chrono::milliseconds d) const;

  std::string host_, port_;
  TelemetryOptions options_;
  TelemetryTrack track_;
  std::unique_ptr<gps_data_t> gps_;  // large (sky view, device list): on the heap; reader thread only
  std::optional<double> takeoff_alt_m_;
  std::optional<double> last_alt_m_;  // the last 3-D altitude, which a 2-D fix holds
  std::atomic<bool> stop_{false};
  std::atomic<uint64_t> link_losses_{0};
  std::thread thread_;
  mutable std::mutex mutex_;  // report_
  TelemetryReport report_;
};

std::optional<InterpolatedPose> GpsdSource::PoseFor(const Frame& frame) {
  auto pose = track_.At(frame.timestamp_ns - options_.latency_ns);
  if (pose) {
    // The course fills yaw only (AddReport); a receiver does not know roll and pitch.
    pose->roll_deg.reset();
    pose->pitch_deg.reset();
  }
  std::lock_guard lock(mutex_);
  ++report_.frames_asked;
  ++(pose ? report_.frames_placed : report_.frames_without);
  return pose;
}

TelemetryReport GpsdSource::Report() const {
  std::lock_guard lock(mutex_);
  TelemetryReport r = report_;
  r.kind = "gpsd";
  r.match = "time";
  r.track = track_.counters();
  r.link_losses = link_losses_;
  return r;
}

bool GpsdSource::Connect() {
  errno = 0;
  if (gps_open(host_.c_str(), port_.c_str(), gps_.get()) != 0) return false;
  if (gps_stream(gps_.get(), WATCH_ENABLE | WATCH_JSON, nullptr) != 0) {
    (void)gps_close(gps_.get());
    return false;
  }
  return true;
}

void GpsdSource::SleepUnlessStopped(std::chrono::milliseconds d) const {
  const auto until = std::chrono::steady_clock::now() + d;
  while (!stop_ && std::chrono::steady_clock::now() < until) std::this_thread::sleep_for(std::chrono::milliseconds(50));
}

bool GpsdSource::RetryLater(int* failures, std::chrono::milliseconds* backoff, const char* why) {
  if (++*failures >= kMaxConnectAttempts) {
    spdlog::error("gpsd {}:{}: no daemon after {} attempts, giving up: frames go on image-only", host_, port_,
                  *failures);
    return false;
  }
  if (*failures == 1) spdlog::warn("gpsd {}:{}: {}, retrying", host_, port_, why);
  SleepUnlessStopped(*backoff);
  *backoff = std::min(*backoff * 2, kMaxBackoff);
  return true;
}

void GpsdSource::ReadLoop() {
  int failures = 0;
  auto backoff = kFirstBackoff;
  while (!stop_) {
    if (!Connect()) {
      if (!RetryLater(&failures, &backoff, gps_errstr(errno))) return;
      continue;
    }
    bool heard = false;
    const bool lost = ReadSession(&heard);
    (void)gps_close(gps_.get());
    if (!lost) return;  // Stop()
    // A daemon that closes before saying anything (its VERSION comes first) is still a failed attempt, not a lost
    // link: backing off keeps a dying or refusing daemon from a tight reconnect loop.
    if (!heard) {
      if (!RetryLater(&failures, &backoff, "connection closed at once")) return;
      continue;
    }
    failures = 0;
    backoff = kFirstBackoff;
    ++link_losses_;
    spdlog::warn("gpsd {}:{}: connection lost ({} so far), reconnecting; frames without fixes go on image-only", host_,
                 port_, link_losses_.load());
  }
}

bool GpsdSource::ReadSession(bool* heard) {
  while (!stop_) {
    if (!gps_waiting(gps_.get(), kWaitUs)) continue;  // quiet (or a signal): the read below finds a closed socket
    gps_->set = 0;                                    // what this report sets, not what earlier ones did
    const int n = gps_read(gps_.get(), nullptr, 0);
    if (n < 0) return true;
    if (n > 0 && !*heard) {
      *heard = true;
      spdlog::info("gpsd {}:{}: connected", host_, port_);
    }
    // MODE_SET: a TPV report (the fix); SKY, DEVICE, VERSION and the like carry no position.
    if ((gps_->set & MODE_SET) != 0) AddReport(gps_->fix, MonotonicNs());
  }
  (void)gps_stream(gps_.get(), WATCH_DISABLE, nullptr);
  return false;
}

void GpsdSource::AddReport(const gps_fix_t& fix, int64_t now_ns) {
  PositionFix p;
  p.t_ns = now_ns;
  p.lat_deg = fix.latitude;
  p.lon_deg = fix.longitude;
  const bool has_position = fix.mode >= MODE_2D && std::isfinite(fix.latitude) && std::isfinite(fix.longitude);
  // altMSL when the receiver gives the geoid separation, else the ellipsoidal height: a receiver reports one or the
  // other throughout, so the height above take-off (a difference) is right either way.
  const double alt = std::isfinite(fix.altMSL) ? fix.altMSL : fix.altHAE;
  if (has_position && fix.mode >= MODE_3D && std::isfinite(alt)) {
    // Take-off reference: the first good 3-D fix's altitude (the receiver has no barometer or home position; the
    // program is started on the ground).
    if (!takeoff_alt_m_) {
      takeoff_alt_m_ = alt;
      spdlog::info("gpsd {}:{}: take-off altitude {:.1f} m (first 3-D fix)", host_, port_, alt);
    }
    last_alt_m_ = alt;
  }
  // A 2-D fix holds the last 3-D altitude; before any, it has no height to give and places nothing.
  const bool usable = has_position && last_alt_m_.has_value();
  if (usable) {
    p.alt_msl_m = *last_alt_m_;
    p.relative_alt_m = *last_alt_m_ - *takeoff_alt_m_;
    if (std::isfinite(fix.eph)) p.h_acc_m = fix.eph * kR95ToSigma;
    if (std::isfinite(fix.speed) && std::isfinite(fix.track)) {
      p.north_mps = fix.speed * std::cos(fix.track * M_PI / 180.0);
      p.east_mps = fix.speed * std::sin(fix.track * M_PI / 180.0);
      if (std::isfinite(fix.climb)) p.up_mps = fix.climb;
    }
  }
  track_.AddFix(p, usable);
  // Course over ground as the heading, only while moving; the track keeps a heading for max_gap after the last one.
  if (usable && std::isfinite(fix.track) && std::isfinite(fix.speed) && fix.speed > kMinSpeedForCourseMps)
    track_.AddAttitude({now_ns, 0.0, 0.0, fix.track});
}

}  // namespace

std::unique_ptr<TelemetrySource> MakeGpsdSource(const std::string& host, int port, const TelemetryOptions& options) {
  return std::make_unique<GpsdSource>(host, port, options);
}

}  // namespace uavm::hal
