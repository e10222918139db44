#pragma once
#include <string>
#include <vector>

#include "core/pipeline/flight_session.h"
#include "core/pipeline/live_view.h"
#include "core/util/signal.h"
#include "firmware_app/app.h"
#include "firmware_app/live_server.h"
#include "firmware_app/status_line.h"

namespace uavm::app {

// --http's access options: a token file that holds a token, a certificate with its key, and no off-loopback bind
// without a token unless --http-no-auth says the network is trusted. False with the reason (exit 2).
[[nodiscard]] bool CheckLiveViewAccess(const RunConfig& config, std::string* why);

// What the flight shows of itself: the terminal's status line and the live server's status, pictures and tiles.
class FlightStatus {
 public:
  FlightStatus(const FlightSession& session, double budget_mib);
  ~FlightStatus();
  FlightStatus(const FlightStatus&) = delete;
  FlightStatus& operator=(const FlightStatus&) = delete;

  // The live server (off without --http), subscribed to `view`'s pictures and tiles. kExitOk, or the exit code.
  [[nodiscard]] int StartServer(const RunConfig& config, LiveView* view);
  void Publish(const char* state, bool wait);
  // After each frame: the live view's status, the status line (a TTY) or a log line every 10 frames.
  void FrameDone(int registered_live, size_t dropped);
  void LogEvery10Frames(int registered_live) const;
  // The finished map stays served (a client that kept the URL gets the end-of-flight tiles) until `seconds` have
  // passed or a stop signal comes.
  void Linger(double seconds) const;

  LiveStatus& status() { return status_; }
  StatusLine& line() { return line_; }

 private:
  const FlightSession& session_;  // borrowed
  StatusLine line_;
  LiveServer server_;
  std::vector<Connection> subscriptions_;  // to the live view: dropped before the server stops
  bool serving_ = false;
  int64_t run_start_ns_ = 0;
  LiveStatus status_;
};

}  // namespace uavm::app
