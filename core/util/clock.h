#pragma once
#include <cstdint>

namespace uavm {

// 64-bit monotonic nanoseconds (CLOCK_MONOTONIC): the only clock used for frame timestamps and stage timings.
[[nodiscard]] int64_t MonotonicNs();

// Measures a stage: ElapsedMs() since construction or the last Restart().
class StageTimer {
 public:
  StageTimer() : start_ns_(MonotonicNs()) {}
  void Restart() { start_ns_ = MonotonicNs(); }
  [[nodiscard]] double ElapsedMs() const { return static_cast<double>(MonotonicNs() - start_ns_) * 1e-6; }

 private:
  int64_t start_ns_;
};

}  // namespace uavm
