#pragma once
#include <atomic>
#include <memory>
#include <mutex>
#include <nlohmann/json.hpp>
#include <string>
#include <thread>

namespace httplib {
class Server;
}

namespace uavm::app {

// What /status.json reports; filled by the frame loop.
struct LiveStatus {
  std::string state = "starting";  // starting | flying | finishing | done
  int frames_in = 0;
  int registered = 0;
  int dropped = 0;
  double fps = 0;
  double median_frame_ms = 0;
  double rss_mib = 0;
  double budget_mib = 0;
  std::string last_error;
  double uptime_s = 0;
};

// The operator's live view over HTTP (cpp-httplib): GET /live.jpg (the latest live preview), /status.json and / (a
// Leaflet page showing the growing picture, laid on the map once the picture is georeferenced). Bounded: a fixed pool
// of worker threads and a short queue; a request that finds both full is answered 503 at once by the accepting thread.
// The frame loop only swaps a pointer (JPEG) or copies a small struct (status, skipped if a reader holds the lock): it
// never waits for a client.
class LiveServer {
 public:
  struct Options {
    std::string host = "127.0.0.1";
    int port = 8080;  // 0 = any free port (see port())
    int threads = 2;
    int queue = 4;
    std::string leaflet_dir = "/usr/share/javascript/leaflet";
  };
  LiveServer();
  ~LiveServer();
  LiveServer(const LiveServer&) = delete;
  LiveServer& operator=(const LiveServer&) = delete;

  [[nodiscard]] bool Start(const Options& options, std::string* error);
  void Stop();
  [[nodiscard]] int port() const { return port_; }

  // A new picture and its georeference (status.json "georef", the corners /live.jpg carries; null: none), swapped
  // together so that a reader gets a matching pair.
  void PublishJpeg(std::shared_ptr<const std::string> jpeg, std::shared_ptr<const nlohmann::json> georef = nullptr);
  // Non-blocking unless `wait`: dropped if a reader holds the lock (the next frame publishes again).
  void PublishStatus(const LiveStatus& status, bool wait = false);

  [[nodiscard]] long served() const { return served_.load(); }
  [[nodiscard]] long refused() const { return refused_.load(); }

 private:
  std::unique_ptr<httplib::Server> server_;
  std::thread listener_;
  int port_ = 0;
  std::mutex jpeg_mutex_;
  std::shared_ptr<const std::string> jpeg_;
  std::shared_ptr<const nlohmann::json> georef_;
  long jpeg_seq_ = 0;
  std::mutex status_mutex_;
  LiveStatus status_;
  std::atomic<long> served_{0};
  std::atomic<long> refused_{0};
};

// "HOST:PORT" -> host, port. Returns false when malformed.
[[nodiscard]] bool ParseHostPort(const std::string& text, std::string* host, int* port);

}  // namespace uavm::app
