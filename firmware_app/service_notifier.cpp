#include "firmware_app/service_notifier.h"

#include <spdlog/fmt/fmt.h>
#include <systemd/sd-daemon.h>

#include <cstdlib>
#include <string>

namespace uavm::app {

ServiceNotifier::ServiceNotifier() {
  const char* socket = std::getenv("NOTIFY_SOCKET");
  under_systemd_ = socket != nullptr && socket[0] != '\0';
  uint64_t us = 0;
  // > 0: the watchdog is on for this process (WATCHDOG_USEC, and WATCHDOG_PID when set, name us).
  if (sd_watchdog_enabled(0, &us) > 0) watchdog_us_ = static_cast<int64_t>(us);
}

void ServiceNotifier::Ready(const std::string& status) {
  if (!under_systemd_) return;
  sd_notifyf(0, "READY=1\nSTATUS=%s", status.c_str());
  // last_progress_ stays at the epoch: the first frame's progress goes out at once, not a second later (a short
  // replay could otherwise end without one frame count in `systemctl status`).
}

void ServiceNotifier::Progress(int frames, int registered, double rss_mib, double peak_rss_mib) {
  if (!under_systemd_) return;
  const auto now = std::chrono::steady_clock::now();
  const int64_t min_gap_us = watchdog_us_ > 0 ? std::min<int64_t>(watchdog_us_ / 2, 1000000) : 1000000;
  if (now - last_progress_ < std::chrono::microseconds(min_gap_us)) return;
  last_progress_ = now;
  const std::string status =
      fmt::format("{} frames, {} registered, RSS {:.0f} MiB (peak {:.0f})", frames, registered, rss_mib, peak_rss_mib);
  sd_notifyf(0, "%sSTATUS=%s", watchdog_us_ > 0 ? "WATCHDOG=1\n" : "", status.c_str());
}

void ServiceNotifier::Status(const std::string& status) {
  if (under_systemd_) sd_notifyf(0, "STATUS=%s", status.c_str());
}

void ServiceNotifier::Stopping(const std::string& status) {
  if (under_systemd_) sd_notifyf(0, "STOPPING=1\nSTATUS=%s", status.c_str());
}

void ServiceNotifier::Watchdog() {
  if (under_systemd_ && watchdog_us_ > 0) sd_notify(0, "WATCHDOG=1");
}

WatchdogHeartbeat::WatchdogHeartbeat(ServiceNotifier* notifier) : notifier_(notifier) {
  if (notifier_ == nullptr || notifier_->watchdog_interval_us() <= 0) return;
  const auto period = std::chrono::microseconds(notifier_->watchdog_interval_us() / 3);
  thread_ = std::thread([this, period] {
    auto next = std::chrono::steady_clock::now();
    while (!stop_.load()) {
      if (std::chrono::steady_clock::now() >= next) {
        notifier_->Watchdog();
        next += period;
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
    }
  });
}

WatchdogHeartbeat::~WatchdogHeartbeat() {
  stop_.store(true);
  if (thread_.joinable()) thread_.join();
}

}  // namespace uavm::app
