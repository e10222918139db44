#pragma once
#include <atomic>
#include <memory>
#include <mutex>
#include <nlohmann/json.hpp>
#include <string>
#include <thread>

#include "core/tiles/tile_set.h"
#include "firmware_app/access_gate.h"

namespace httplib {
class Server;
struct Request;
struct Response;
}  // namespace httplib

namespace uavm::app {

struct TileSnapshot;

// What /status.json reports; filled by the frame loop.
struct LiveStatus {
  std::string state = "starting";  // starting | flying | finishing | done
  int frames_in = 0;
  int registered = 0;
  int dropped = 0;
  double fps = 0;
  double median_frame_ms = 0;
  double rss_mib = 0;
  double peak_rss_mib = 0;  // over every phase so far (VmHWM, never reset)
  double budget_mib = 0;
  std::string last_error;
  double uptime_s = 0;
};

// The operator's live view over HTTP (cpp-httplib): GET /live.jpg (the latest live preview), /status.json and / (a
// Leaflet page showing the growing picture, laid on the map once the picture is georeferenced; the live tile pyramid
// once one is published), and the pyramid itself for map clients (firmware_app/tile_routes.h: /tiles/{z}/{x}/{y}.png,
// /tiles.json, /wmts/1.0.0/WMTSCapabilities.xml, /tiles.xml, /footprints.geojson). Bounded: a fixed pool
// of worker threads and a short queue; a request that finds both full is answered 503 at once by the accepting thread.
// The frame loop only swaps a pointer (JPEG) or copies a small struct (status, skipped if a reader holds the lock): it
// never waits for a client.
class LiveServer {
 public:
  struct Options {
    std::string host = "127.0.0.1";
    int port = 8080;  // 0 = any free port (see port())
    // Sized for tile clients (a browser opens ~6 connections, GDAL several, a few of each at once): a queued connection
    // costs only its socket; still bounded, 503 beyond.
    int threads = 4;
    int queue = 64;
    std::string leaflet_dir = "/usr/share/javascript/leaflet";
    // The live page's default base map under the tiles, an XYZ template (e.g.
    // https://tile.openstreetmap.org/{z}/{x}/{y}.png; /?basemap=... overrides it). Empty: none, the page works offline.
    std::string basemap_url;
    // Access (firmware_app/access_gate.h): with a token every route, the page and Leaflet's files included, needs it
    // (Authorization: Bearer, ?token= for clients that take only a URL, or the cookie a browser gets when it opened
    // the page with ?token=); empty: open to whoever reaches the port. Answers never name a path.
    std::string token;
    AccessGate::Options access;
    // HTTPS (cpp-httplib with OpenSSL): PEM certificate (chain) and private key files; empty: plain HTTP.
    std::string cert_file;
    std::string key_file;
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
  // The live tile pyramid's description (null: none) and the frames' footprints (a GeoJSON FeatureCollection, in the
  // tiles' coordinates): pointer swaps, never waiting for a client.
  void PublishTiles(std::shared_ptr<const TileSetInfo> tiles);
  void PublishFootprints(std::shared_ptr<const std::string> geojson);

  [[nodiscard]] long served() const { return served_.load(); }
  [[nodiscard]] long refused() const { return refused_.load(); }
  // What the token check refused (zeros without a token).
  [[nodiscard]] AccessGate::Counters access_counters() const;
  // Connections a worker is serving now, and connections waiting for one (status.json; tests wait on them).
  struct PoolGauge {
    std::atomic<long> working{0};
    std::atomic<long> queued{0};
  };
  [[nodiscard]] long working() const { return gauge_.working.load(); }
  [[nodiscard]] long queued() const { return gauge_.queued.load(); }

 private:
  TileSnapshot TileSnapshotNow();
  nlohmann::json StatusJson();
  void ServeJpeg(httplib::Response& res);
  // Before any route: true lets the request through; false has set the 401 or 429.
  [[nodiscard]] bool Admit(const httplib::Request& req, httplib::Response& res);

  PoolGauge gauge_;                   // before server_: its pool's workers write here until they are joined
  std::unique_ptr<AccessGate> gate_;  // null: no token; before server_, whose handlers use it
  bool tls_ = false;
  std::string cookie_name_;  // the page's token cookie, named after the port (set before the server listens)
  std::unique_ptr<httplib::Server> server_;
  std::thread listener_;
  int port_ = 0;
  std::mutex jpeg_mutex_;
  std::shared_ptr<const std::string> jpeg_;
  std::shared_ptr<const nlohmann::json> georef_;
  long jpeg_seq_ = 0;
  std::mutex tiles_mutex_;  // held only for pointer copies
  std::shared_ptr<const TileSetInfo> tiles_;
  std::shared_ptr<const std::string> footprints_;
  std::mutex status_mutex_;
  LiveStatus status_;
  std::atomic<long> served_{0};
  std::atomic<long> refused_{0};
};

// "HOST:PORT" -> host, port. Returns false when malformed.
[[nodiscard]] bool ParseHostPort(const std::string& text, std::string* host, int* port);

}  // namespace uavm::app
