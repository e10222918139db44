#pragma once
#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

namespace uavm::hal {

// One position fix as telemetry reports it, on the track's clock (ns: the monotonic clock for a live link, UNIX time
// for a replayed log).
struct PositionFix {
  int64_t t_ns = 0;
  double lat_deg = 0, lon_deg = 0;
  double alt_msl_m = 0;
  std::optional<double> relative_alt_m;  // above take-off (GLOBAL_POSITION_INT, CAMERA_FEEDBACK)
  std::optional<double> h_acc_m;         // 1-sigma horizontal accuracy when the receiver says
  // Velocity: carries the position on past the newest fix.
  std::optional<double> north_mps, east_mps, up_mps;
};
struct AttitudeSample {
  int64_t t_ns = 0;
  double roll_deg = 0, pitch_deg = 0, yaw_deg = 0;
};

// The vehicle's pose at one instant, interpolated between the fixes around it.
struct InterpolatedPose {
  double lat_deg = 0, lon_deg = 0;
  double alt_msl_m = 0;
  std::optional<double> relative_alt_m;
  std::optional<double> h_acc_m;
  std::optional<double> roll_deg, pitch_deg, yaw_deg;
};

// Why a frame got no pose: counted, reported, never silent.
struct TrackCounters {
  uint64_t fixes = 0;
  uint64_t attitudes = 0;
  uint64_t no_fix = 0;        // fixes refused: receiver without a 3-D fix
  uint64_t out_of_order = 0;  // fixes older than the newest (a clock jump): refused
  uint64_t queries = 0;
  uint64_t answered = 0;
  uint64_t stale = 0;        // the nearest fixes were more than max_gap apart (telemetry lost)
  uint64_t outside = 0;      // before the first fix or after the last (by more than max_hold)
  uint64_t overwritten = 0;  // fixes the bounded history dropped (oldest first)
};

// The recent history of the vehicle's position and attitude, bounded (the newest `capacity` of each, allocated once),
// thread-safe: a telemetry thread adds, the frame loop asks. At(t) interpolates linearly between the fixes around t; it
// refuses when they are more than max_gap apart or t lies outside them by more than max_hold, so stale telemetry never
// places a frame.
class TelemetryTrack {
 public:
  static constexpr size_t kLiveCapacity = 4096;  // ~7 min of 10 Hz fixes; a live frame is asked about within seconds
  // Beyond the newest fix (or before the oldest) the nearest fix stands for t only within max_hold_ns: a moving
  // vehicle's last known position soon says little about where it is now.
  explicit TelemetryTrack(size_t capacity = kLiveCapacity, int64_t max_gap_ns = 2'000'000'000,
                          int64_t max_hold_ns = 1'000'000'000)
      : max_gap_ns_(max_gap_ns), max_hold_ns_(max_hold_ns), fixes_(capacity), attitudes_(capacity) {}

  void AddFix(const PositionFix& fix, bool has_3d_fix = true);
  void AddAttitude(const AttitudeSample& a);
  [[nodiscard]] std::optional<InterpolatedPose> At(int64_t t_ns);
  [[nodiscard]] TrackCounters counters() const;
  // Time span of the fixes held (0, 0 when none): a log from another flight does not overlap the frames.
  [[nodiscard]] std::pair<int64_t, int64_t> span() const;

 private:
  template <typename T>
  struct Ring {
    explicit Ring(size_t capacity) : items(std::max<size_t>(1, capacity)) {}
    std::vector<T> items;
    size_t head = 0;  // index of the oldest
    size_t size = 0;
    void Push(const T& v, uint64_t* overwritten);
    [[nodiscard]] const T& operator[](size_t i) const { return items[(head + i) % items.size()]; }
  };
  // Index of the last item with t_ns <= t (size when none).
  template <typename T>
  [[nodiscard]] static size_t Before(const Ring<T>& r, int64_t t);

  mutable std::mutex mutex_;
  int64_t max_gap_ns_;
  int64_t max_hold_ns_;
  bool fix_lost_after_newest_ = false;  // a report without a fix came after the newest fix: nothing is held past it
  Ring<PositionFix> fixes_;
  Ring<AttitudeSample> attitudes_;
  TrackCounters counters_;
};

}  // namespace uavm::hal
