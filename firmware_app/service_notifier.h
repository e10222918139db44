#pragma once
#include <atomic>
#include <chrono>
#include <cstdint>
#include <string>
#include <thread>

namespace uavm::app {

// The onboard program's side of a systemd Type=notify service (sd_notify from libsystemd): READY=1 once the source
// and the session are open, WATCHDOG=1 while it makes progress, a STATUS= line an operator sees in
// `systemctl status`, STOPPING=1 when it winds down. Outside systemd (no NOTIFY_SOCKET) every call does nothing.
class ServiceNotifier {
 public:
  ServiceNotifier();
  [[nodiscard]] bool under_systemd() const { return under_systemd_; }
  // The watchdog interval systemd asked for (WatchdogSec=), 0 when none.
  [[nodiscard]] int64_t watchdog_interval_us() const { return watchdog_us_; }

  void Ready(const std::string& status);
  // From the frame loop: a WATCHDOG=1 and a STATUS= line, at most every half watchdog interval (or every second).
  void Progress(int frames, int registered, double rss_mib, double peak_rss_mib);
  void Status(const std::string& status);
  void Stopping(const std::string& status);
  // One WATCHDOG=1 now (from the heartbeat thread as well: sd_notify is thread-safe).
  void Watchdog();

 private:
  bool under_systemd_ = false;
  int64_t watchdog_us_ = 0;
  std::chrono::steady_clock::time_point last_progress_{};
};

// Keeps the watchdog fed during a long phase that has no frame loop (the end-of-flight solves and compositing are
// bounded, but can outlast WatchdogSec). Scoped: the heartbeat stops when the phase ends, so a hang outside such a
// phase is still caught.
class WatchdogHeartbeat {
 public:
  explicit WatchdogHeartbeat(ServiceNotifier* notifier);  // borrows: the notifier outlives the heartbeat
  ~WatchdogHeartbeat();
  WatchdogHeartbeat(const WatchdogHeartbeat&) = delete;
  WatchdogHeartbeat& operator=(const WatchdogHeartbeat&) = delete;

 private:
  ServiceNotifier* notifier_;
  std::atomic<bool> stop_{false};
  std::thread thread_;
};

}  // namespace uavm::app
