#pragma once
#include <chrono>
#include <optional>
#include <thread>

namespace uavm {

// A camera's trigger times: input i is due i x interval after the first. Wait() returns at the next input's time,
// at once when it is already overdue (a camera does not wait for a slow reader: whatever a frame cost, the next one
// keeps its time). Replays use it to run at the onboard cadence instead of on a backlog.
class TriggerSchedule {
 public:
  explicit TriggerSchedule(std::chrono::milliseconds interval) : interval_(interval) {}
  void Wait() {
    if (interval_.count() <= 0) return;
    if (!first_) first_ = std::chrono::steady_clock::now();
    std::this_thread::sleep_until(*first_ + interval_ * triggers_++);
  }

 private:
  std::chrono::milliseconds interval_;
  std::optional<std::chrono::steady_clock::time_point> first_;
  long long triggers_ = 0;
};

}  // namespace uavm
