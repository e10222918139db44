#include "firmware_app/flight_status.h"

#include <spdlog/spdlog.h>

#include <chrono>
#include <thread>

#include "core/util/clock.h"
#include "core/util/memory.h"

namespace uavm::app {

FlightStatus::FlightStatus(const FlightSession& session, double budget_mib) : session_(session) {
  status_.budget_mib = budget_mib;
  run_start_ns_ = MonotonicNs();
}

FlightStatus::~FlightStatus() {
  subscriptions_.clear();  // the view's tile worker must stop calling into the server first
}

bool CheckLiveViewAccess(const RunConfig& config, std::string* why) {
  if (config.http.empty()) return true;
  std::string host, token;
  int port = 0;
  if (!ParseHostPort(config.http, &host, &port)) {
    *why = "--http: expected HOST:PORT, got '" + config.http + "'";
    return false;
  }
  if (!config.http_token_file.empty() && !ReadAccessToken(config.http_token_file, &token, why)) return false;
  if (config.http_cert_file.empty() != config.http_key_file.empty()) {
    *why = "--http-cert and --http-key go together (HTTPS needs the certificate and its private key)";
    return false;
  }
  if (token.empty() && !IsLoopbackHost(host) && !config.http_no_auth) {
    *why = "--http " + config.http +
           ": the live view (the map, the session's files) would be open to anyone on the network; give it an access "
           "token with --http-token-file FILE (README, deploy), or --http-no-auth where the network is trusted";
    return false;
  }
  if (token.empty() && !IsLoopbackHost(host))
    spdlog::warn("--http {} --http-no-auth: the live view is open to anyone who reaches the port", config.http);
  return true;
}

int FlightStatus::StartServer(const RunConfig& config, LiveView* view) {
  serving_ = !config.http.empty();
  run_start_ns_ = MonotonicNs();
  if (!serving_) return kExitOk;
  std::string error;
  LiveServer::Options lo;
  lo.leaflet_dir = session_.options().leaflet_dir;
  lo.basemap_url = config.basemap;
  if (!ParseHostPort(config.http, &lo.host, &lo.port)) {
    spdlog::error("--http: expected HOST:PORT, got '{}'", config.http);
    return kExitUsage;
  }
  if (!config.http_token_file.empty() && !ReadAccessToken(config.http_token_file, &lo.token, &error)) {
    spdlog::error("{}", error);
    return kExitUsage;
  }
  lo.cert_file = config.http_cert_file;
  lo.key_file = config.http_key_file;
  if (!server_.Start(lo, &error)) {
    spdlog::error("--http: {}", error);
    return kExitUsage;
  }
  subscriptions_.push_back(
      view->OnPreview([this](std::shared_ptr<const std::string> jpeg, std::shared_ptr<const nlohmann::json> georef) {
        server_.PublishJpeg(std::move(jpeg), std::move(georef));
      }));
  subscriptions_.push_back(
      view->OnTiles([this](std::shared_ptr<const TileSetInfo> t) { server_.PublishTiles(std::move(t)); }));
  subscriptions_.push_back(
      view->OnFootprints([this](std::shared_ptr<const std::string> g) { server_.PublishFootprints(std::move(g)); }));
  run_start_ns_ = MonotonicNs();  // the run's uptime starts with the server up
  return kExitOk;
}

void FlightStatus::Publish(const char* state, bool wait) {
  status_.state = state;
  status_.frames_in = static_cast<int>(session_.frames_in());
  status_.uptime_s = static_cast<double>(MonotonicNs() - run_start_ns_) * 1e-9;
  status_.fps = status_.uptime_s > 0 ? status_.frames_in / status_.uptime_s : 0.0;
  status_.median_frame_ms = session_.stage_stats().Get("frame_total").median;
  status_.rss_mib = CurrentRssMiB();
  status_.peak_rss_mib = PeakRssMiB();
  status_.last_error = line_.last_error();
  if (serving_) server_.PublishStatus(status_, wait);
}

void FlightStatus::FrameDone(int registered_live, size_t dropped) {
  status_.registered = registered_live;
  status_.dropped = static_cast<int>(dropped);
  Publish("flying", false);
  if (line_.tty())
    line_.Update(fmt::format("{} frames | {:.1f} fps | {} registered | {} dropped | {:.0f} ms/frame | RSS {:.0f} MiB",
                             status_.frames_in, status_.fps, registered_live, status_.dropped, status_.median_frame_ms,
                             status_.rss_mib));
}

void FlightStatus::LogEvery10Frames(int registered_live) const {
  if (session_.frames_in() % 10 == 0 && !line_.tty())
    spdlog::info("{} frames, median {:.0f} ms/frame, {:.1f} fps, {} registered, RSS {:.0f} MiB", session_.frames_in(),
                 session_.stage_stats().Get("frame_total").median, status_.fps, registered_live, CurrentRssMiB());
}

void FlightStatus::Linger(double seconds) const {
  if (!serving_ || !(seconds > 0)) return;
  spdlog::info("live view: the finished map stays served for {:.0f} s (SIGTERM ends it)", seconds);
  const int64_t end = MonotonicNs() + static_cast<int64_t>(seconds * 1e9);
  while (StopSignal() == 0 && MonotonicNs() < end) std::this_thread::sleep_for(std::chrono::milliseconds(100));
}

}  // namespace uavm::app
