#include "hal/telemetry/track.h"

#include <algorithm>
#include <cmath>

namespace uavm::hal {

namespace {

double Lerp(double a, double b, double w) {
  return a + (b - a) * w;
}

// Angles interpolate the short way round (yaw 359 -> 1 passes through 0, not 180).
double LerpDeg(double a, double b, double w) {
  const double d = std::remainder(b - a, 360.0);
  return std::remainder(a + d * w, 360.0);
}

std::optional<double> LerpOpt(const std::optional<double>& a, const std::optional<double>& b, double w) {
  if (a && b) return Lerp(*a, *b, w);
  return a ? a : b;
}

// A held fix moved on by its ground velocity to time t (metres to degrees on the local sphere: within a second of
// flight the approximation is far below a GPS error).
void CarryOn(const PositionFix& f, int64_t t, InterpolatedPose* p) {
  if (!f.north_mps || !f.east_mps) return;
  constexpr double kMetresPerDeg = 6371008.8 * M_PI / 180.0;
  const double dt = static_cast<double>(t - f.t_ns) * 1e-9;
  p->lat_deg += *f.north_mps * dt / kMetresPerDeg;
  p->lon_deg += *f.east_mps * dt / (kMetresPerDeg * std::cos(f.lat_deg * M_PI / 180.0));
  if (!f.up_mps) return;
  p->alt_msl_m += *f.up_mps * dt;
  if (p->relative_alt_m) *p->relative_alt_m += *f.up_mps * dt;
}

}  // namespace

template <typename T>
void TelemetryTrack::Ring<T>::Push(const T& v, uint64_t* overwritten) {
  if (size == items.size()) {
    head = (head + 1) % items.size();
    --size;
    ++*overwritten;
  }
  items[(head + size) % items.size()] = v;
  ++size;
}

template <typename T>
size_t TelemetryTrack::Before(const Ring<T>& r, int64_t t) {
  // Binary search over the ring in time order.
  size_t lo = 0, hi = r.size;
  while (lo < hi) {
    const size_t mid = (lo + hi) / 2;
    if (r[mid].t_ns <= t)
      lo = mid + 1;
    else
      hi = mid;
  }
  return lo == 0 ? r.size : lo - 1;
}

void TelemetryTrack::AddFix(const PositionFix& fix, bool has_3d_fix) {
  std::lock_guard lock(mutex_);
  if (!has_3d_fix) {
    ++counters_.no_fix;
    if (fixes_.size == 0 || fix.t_ns >= fixes_[fixes_.size - 1].t_ns) fix_lost_after_newest_ = true;
    return;
  }
  if (fixes_.size > 0 && fix.t_ns < fixes_[fixes_.size - 1].t_ns) {
    ++counters_.out_of_order;
    return;
  }
  fixes_.Push(fix, &counters_.overwritten);
  fix_lost_after_newest_ = false;
  ++counters_.fixes;
}

void TelemetryTrack::AddAttitude(const AttitudeSample& a) {
  std::lock_guard lock(mutex_);
  if (attitudes_.size > 0 && a.t_ns < attitudes_[attitudes_.size - 1].t_ns) return;
  attitudes_.Push(a, &counters_.overwritten);
  ++counters_.attitudes;
}

std::optional<InterpolatedPose> TelemetryTrack::At(int64_t t) {
  std::lock_guard lock(mutex_);
  ++counters_.queries;
  if (fixes_.size == 0) {
    ++counters_.outside;
    return std::nullopt;
  }
  const size_t i = Before(fixes_, t);
  const PositionFix* a = i == fixes_.size ? nullptr : &fixes_[i];
  const PositionFix* b = i == fixes_.size ? &fixes_[0] : (i + 1 < fixes_.size ? &fixes_[i + 1] : nullptr);
  // Outside the fixes: only a fix within max_hold of t may stand for it, carried on by its velocity; never past a
  // report that the receiver lost its fix.
  if (a == nullptr || b == nullptr) {
    const PositionFix* only = a != nullptr ? a : b;
    const bool fix_lost_since = a != nullptr && fix_lost_after_newest_;
    if (std::llabs(only->t_ns - t) > std::min(max_hold_ns_, max_gap_ns_) || fix_lost_since) {
      ++counters_.outside;
      return std::nullopt;
    }
    a = b = only;
  } else if (b->t_ns - a->t_ns > max_gap_ns_) {
    ++counters_.stale;
    return std::nullopt;
  }
  const double w = b->t_ns > a->t_ns ? static_cast<double>(t - a->t_ns) / static_cast<double>(b->t_ns - a->t_ns) : 0;
  InterpolatedPose p;
  p.lat_deg = Lerp(a->lat_deg, b->lat_deg, w);
  p.lon_deg = Lerp(a->lon_deg, b->lon_deg, w);
  p.alt_msl_m = Lerp(a->alt_msl_m, b->alt_msl_m, w);
  p.relative_alt_m = LerpOpt(a->relative_alt_m, b->relative_alt_m, w);
  p.h_acc_m = LerpOpt(a->h_acc_m, b->h_acc_m, w);
  if (a == b) CarryOn(*a, t, &p);
  const size_t k = Before(attitudes_, t);
  if (k != attitudes_.size) {
    const AttitudeSample& x = attitudes_[k];
    const AttitudeSample& y = k + 1 < attitudes_.size ? attitudes_[k + 1] : x;
    if (t - x.t_ns <= max_gap_ns_ && y.t_ns - x.t_ns <= max_gap_ns_) {
      const double v = y.t_ns > x.t_ns ? static_cast<double>(t - x.t_ns) / static_cast<double>(y.t_ns - x.t_ns) : 0;
      p.roll_deg = Lerp(x.roll_deg, y.roll_deg, v);
      p.pitch_deg = Lerp(x.pitch_deg, y.pitch_deg, v);
      p.yaw_deg = LerpDeg(x.yaw_deg, y.yaw_deg, v);
    }
  }
  ++counters_.answered;
  return p;
}

TrackCounters TelemetryTrack::counters() const {
  std::lock_guard lock(mutex_);
  return counters_;
}

std::pair<int64_t, int64_t> TelemetryTrack::span() const {
  std::lock_guard lock(mutex_);
  if (fixes_.size == 0) return {0, 0};
  return {fixes_[0].t_ns, fixes_[fixes_.size - 1].t_ns};
}

}  // namespace uavm::hal
