#include "firmware_app/live_server.h"

#include <httplib.h>
#include <pthread.h>
#include <spdlog/spdlog.h>
#include <sys/socket.h>

#include <chrono>
#include <condition_variable>
#include <deque>
#include <functional>
#include <nlohmann/json.hpp>
#include <optional>
#include <string_view>
#include <vector>

#include "core/util/clock.h"
#include "firmware_app/tile_routes.h"

namespace uavm::app {

namespace {

// Set while a request the pool had no room for is answered: handlers reply 503 at once.
thread_local bool t_overflow = false;

// httplib's own ThreadPool queues without limit; this one holds at most `capacity` waiting connections. A connection
// beyond that is answered 503 by the accepting thread itself over plain HTTP (at once: the request is read and a few
// bytes written). Over TLS the handshake comes first and a client may stall it for the read timeout: there the
// overflow goes to one thread of its own, with a queue of kOverflowQueue, so that accepting never waits on a client;
// beyond that queue too the accepting thread answers (a flood, bounded by the timeouts).
class BoundedPool : public httplib::TaskQueue {
 public:
  static constexpr size_t kOverflowQueue = 8;
  BoundedPool(int threads, int capacity, LiveServer::PoolGauge* gauge, bool overflow_thread)
      : capacity_(static_cast<size_t>(capacity)), gauge_(gauge) {
    for (int i = 0; i < threads; ++i) workers_.emplace_back([this] { Work(&jobs_, false); });
    if (overflow_thread) overflow_worker_ = std::thread([this] { Work(&overflow_, true); });
  }
  ~BoundedPool() override { shutdown(); }

  void enqueue(std::function<void()> fn) override {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      if (!stop_ && jobs_.size() < capacity_) {
        jobs_.push_back(std::move(fn));
        ++gauge_->queued;
        cv_.notify_all();
        return;
      }
      if (!stop_ && overflow_worker_.joinable() && overflow_.size() < kOverflowQueue) {
        overflow_.push_back(std::move(fn));
        cv_.notify_all();
        return;
      }
    }
    // Full: the connection is still answered (closing it is httplib's job inside fn), but with a 503 from here.
    t_overflow = true;
    fn();
    t_overflow = false;
  }

  void shutdown() override {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      if (stop_) return;
      stop_ = true;
    }
    cv_.notify_all();
    for (auto& t : workers_) t.join();
    if (overflow_worker_.joinable()) overflow_worker_.join();
  }

 private:
  // Serves `queue` until shutdown; the overflow queue's connections are answered 503 (and not counted as working).
  void Work(std::deque<std::function<void()>>* queue, bool overflow) {
    pthread_setname_np(pthread_self(), overflow ? "uavm-http-ovf" : "uavm-http");  // bench/http_load.sh: uavm-http
    t_overflow = overflow;
    for (;;) {
      std::function<void()> fn;
      {
        std::unique_lock<std::mutex> lock(mutex_);
        cv_.wait(lock, [&] { return stop_ || !queue->empty(); });
        if (queue->empty()) return;
        fn = std::move(queue->front());
        queue->pop_front();
        if (!overflow) {
          ++gauge_->working;  // before `queued` drops, so that the two never both miss this connection
          --gauge_->queued;
        }
      }
      fn();
      if (!overflow) --gauge_->working;
    }
  }

  size_t capacity_;
  std::mutex mutex_;
  std::condition_variable cv_;
  std::deque<std::function<void()>> jobs_;
  std::deque<std::function<void()>> overflow_;
  std::vector<std::thread> workers_;
  std::thread overflow_worker_;
  bool stop_ = false;
  LiveServer::PoolGauge* gauge_;  // borrowed: the LiveServer outlives its httplib server and this pool
};

// The live page: Leaflet (served from Debian's libjs-leaflet) with the live picture, re-fetched when the status says a
// new one is out. The picture, not a growing tile set: it is what the frame loop already encodes every few frames, so
// the view costs the flight nothing more. Georeferenced, the picture (not north-up) is laid on a web-mercator map by
// a CSS affine transform through three of its corners, which arrive with the picture itself (X-Georef-Corners) so that
// a picture never gets another's place; otherwise it is shown in its own pixel frame (CRS.Simple).
// Once the flight publishes its tile pyramid (status.json "tiles"), the page shows the tiles instead (web mercator, or
// CRS.Simple for a local set), the frames' footprints and the set's outline; a new layer with a `?v=` bump replaces
// the old one once loaded (no flicker; the server ignores the query). The optional base map (?basemap=, else
// Options::basemap_url) lies under them.
const char* kLivePage = R"HTML(<!DOCTYPE html>
<html><head><meta charset="utf-8"><title>uavmosaic live</title>
<link rel="stylesheet" href="/leaflet/leaflet.css"><script src="/leaflet/leaflet.js"></script>
<style>html,body,#map{margin:0;height:100%;background:#000}
#s{position:absolute;z-index:1000;left:50px;top:8px;background:rgba(255,255,255,.85);padding:3px 8px;
font:12px monospace;border-radius:4px}</style></head>
<body><div id="map"></div><div id="s">waiting for the first picture&hellip;</div>
<script>
var map = null, geo = null, layer = null, seq = -1, followed = true, url = null;
// Tile mode: the published set, its shown and loading layers, the footprints and the set's outline.
var tset = null, tiles = null, pending = null, prints = null, outline = null, shown = '', epoch = 0;
var basemap = new URLSearchParams(location.search).get('basemap') || /*BASEMAP*/"";
// An image on the map by its corners [top-left, top-right, bottom-right, bottom-left] (lat, lon).
var Placed = L.Layer.extend({
  onAdd: function (m) {
    this._el = L.DomUtil.create('img', 'leaflet-image-layer');
    this._el.style.position = 'absolute';
    this._el.style.transformOrigin = '0 0';
    m.getPanes().overlayPane.appendChild(this._el);
    m.on('zoomend viewreset', this._place, this);
  },
  onRemove: function (m) { L.DomUtil.remove(this._el); m.off('zoomend viewreset', this._place, this); },
  show: function (img, corners) { this._img = img; this._c = corners; this._el.src = img.src; this._place(); },
  _place: function () {
    if (!this._img) return;
    var m = this._map, w = this._img.naturalWidth, h = this._img.naturalHeight;
    var p0 = m.latLngToLayerPoint(this._c[0]), p1 = m.latLngToLayerPoint(this._c[1]);
    var p3 = m.latLngToLayerPoint(this._c[3]);
    this._el.style.width = w + 'px';
    this._el.style.height = h + 'px';
    this._el.style.transform = 'matrix(' + [(p1.x - p0.x) / w, (p1.y - p0.y) / w, (p3.x - p0.x) / h,
      (p3.y - p0.y) / h, p0.x, p0.y].join(',') + ')';
  }
});
function makeMap(georeferenced, t) {
  if (map) map.remove();
  geo = georeferenced;
  layer = null;
  followed = true;
  map = geo ? L.map('map', {zoomSnap: 0, zoomAnimation: false, maxZoom: 24})
            : L.map('map', {crs: L.CRS.Simple, zoomSnap: 0, zoomAnimation: false,
                            minZoom: t ? t.min_zoom - 8 : -4, maxZoom: t ? t.max_zoom + 4 : 18});
  if (!geo) return;
  L.control.scale({imperial: false}).addTo(map);
  var host = basemap.replace(/^[a-z]+:\/\/([^/]+).*$/i, '$1').replace(/[^A-Za-z0-9.:-]/g, '');
  if (basemap) L.tileLayer(basemap, {maxZoom: 24, maxNativeZoom: 19, zIndex: 0, attribution: 'base map: ' + host})
    .addTo(map);
}
function tileBounds(t) { return L.latLngBounds([[t.bounds[1], t.bounds[0]], [t.bounds[3], t.bounds[2]]]); }
function makeTileMap(t) {
  makeMap(t.geographic, t);
  tset = t; tiles = null; pending = null; shown = ''; ++epoch;
  prints = L.geoJSON(null, {style: {color: '#ffeb3b', weight: 1, opacity: 0.8, fill: false}, interactive: false})
    .addTo(map);
  outline = L.rectangle(tileBounds(t), {color: '#4fc3f7', weight: 1, fill: false, dashArray: '4 4',
                                        interactive: false}).addTo(map);
  map.fitBounds(tileBounds(t), {animate: false});
}
// Fit the newest footprints (else the whole set) while the operator has not taken the view.
function follow(t) {
  if (!followed) return;
  var f = prints.getLayers(), b = null;
  for (var i = Math.max(0, f.length - 3); i < f.length; ++i) {
    if (!f[i].getBounds) continue;
    var fb = f[i].getBounds();
    b = b ? b.extend(fb) : L.latLngBounds(fb.getSouthWest(), fb.getNorthEast());
  }
  map.fitBounds(b ? b.pad(0.25) : tileBounds(t), {animate: false, maxZoom: t.max_zoom});
}
function showTiles(t) {
  if (!tset || tset.generation !== t.generation || geo !== t.geographic) makeTileMap(t);
  var key = t.generation + '.' + t.updated_ns + '.' + t.frames;
  if (key === shown || pending) return;
  shown = key; tset = t;
  outline.setBounds(tileBounds(t));
  var next = L.tileLayer('/tiles/{z}/{x}/{y}.png?v=' + key, {minNativeZoom: t.min_zoom, maxNativeZoom: t.max_zoom,
    minZoom: map.getMinZoom(), maxZoom: map.getMaxZoom(), bounds: tileBounds(t), noWrap: true, zIndex: 1});
  var e = epoch, swap = function () {
    if (e !== epoch || pending !== next) return;
    if (tiles) map.removeLayer(tiles);
    tiles = next; pending = null;
  };
  pending = next;
  next.on('load', swap);
  setTimeout(swap, 3000);  // no 'load' when no tile is in view
  next.addTo(map);
  fetch('/footprints.geojson').then(function (r) { return r.json(); }).then(function (g) {
    if (e !== epoch) return;
    prints.clearLayers();
    prints.addData(g);
    follow(t);
  }).catch(function () {});
}
// The view follows the growing mosaic until the operator pans or zooms.
document.getElementById('map').addEventListener('pointerdown', function () { followed = false; });
document.getElementById('map').addEventListener('wheel', function () { followed = false; });
function picture(img, corners) {
  if (tset) return;  // the tiles took over meanwhile
  if (map === null || geo !== !!corners) makeMap(!!corners);
  var b = corners ? L.latLngBounds(corners) : L.latLngBounds([[-img.naturalHeight, 0], [0, img.naturalWidth]]);
  if (corners) {
    if (!layer) layer = new Placed().addTo(map);
    if (followed) map.fitBounds(b, {animate: false});
    layer.show(img, corners);
  } else {
    if (!layer) layer = L.imageOverlay(img.src, b).addTo(map);
    else { layer.setBounds(b); layer.setUrl(img.src); }
    if (followed) map.fitBounds(b, {animate: false});
  }
}
function show(st) {
  var g = st.georef || {};
  document.getElementById('s').textContent = st.state + ' | frames ' + st.frames_in + ' | registered ' +
    st.registered + ' | dropped ' + st.dropped + ' | ' + st.fps.toFixed(1) + ' fps | RSS ' +
    st.rss_mib.toFixed(0) + '/' + st.budget_mib.toFixed(0) + ' MiB (peak ' + st.peak_rss_mib.toFixed(0) + ')' +
    (g.georeferenced ? ' | ' + g.crs + ', RMS ' + g.rms_m.toFixed(1) + ' m over ' + g.frames_used + ' frames'
                     : ' | not georeferenced' + (g.reason ? ': ' + g.reason : '')) +
    (st.tiles ? ' | tiles z' + st.tiles.min_zoom + '-' + st.tiles.max_zoom + ', ' + st.tiles.frames + ' frames' +
                (st.tiles.final ? ', final' : '') : '') +
    (st.last_error ? ' | ' + st.last_error : '');
  if (st.tiles) { showTiles(st.tiles); return; }
  if (tset) { tset = null; map.remove(); map = null; seq = -1; }  // tiles withdrawn: back to the picture
  if (st.jpeg_seq === seq || st.jpeg_seq === 0) return;
  seq = st.jpeg_seq;
  fetch('/live.jpg?seq=' + seq).then(function (r) {
    var corners = JSON.parse(r.headers.get('X-Georef-Corners') || 'null');
    return r.blob().then(function (blob) {
      var img = new Image();
      img.onload = function () {
        picture(img, corners);
        if (url) URL.revokeObjectURL(url);
        url = img.src;
      };
      img.src = URL.createObjectURL(blob);
    });
  }).catch(function () {});
}
function poll() {
  fetch('/status.json').then(function (r) { return r.json(); }).then(show).catch(function () {})
    .finally(function () { setTimeout(poll, 1000); });
}
poll();
</script></body></html>
)HTML";

// httplib listens with a backlog of 5: a burst of connections (a browser opens ~6, GDAL several, a few clients at
// once) would overflow it, and a dropped SYN costs its client a 1 s retransmit. Raised by listening again after bind.
constexpr int kListenBacklog = 64;

// The bounded pool, short timeouts, and the listening socket's descriptor once bound (-1 until then).
std::shared_ptr<int> Configure(httplib::Server* s, const LiveServer::Options& o, LiveServer::PoolGauge* gauge) {
  const int threads = o.threads, queue = o.queue;
  s->new_task_queue = [threads, queue, gauge, tls = !o.cert_file.empty()] {
    return new BoundedPool(threads, queue, gauge, tls);
  };
  // Short timeouts and no long keep-alive: a slow or idle client must not hold one of the few workers.
  s->set_keep_alive_max_count(4);
  s->set_keep_alive_timeout(1);
  s->set_read_timeout(2, 0);
  s->set_write_timeout(2, 0);
  s->set_payload_max_length(4096);
  auto fd = std::make_shared<int>(-1);
  s->set_socket_options([fd](socket_t sock) {
    httplib::default_socket_options(sock);
    *fd = sock;  // the last socket tried is the one bound
  });
  return fd;
}

// The value of cookie `name` in a Cookie header ("a=1; b=2"); nullopt when absent.
std::optional<std::string> CookieValue(const std::string& header, std::string_view name) {
  for (size_t at = 0; at < header.size();) {
    const size_t end = std::min(header.find(';', at), header.size());
    std::string_view item(header.data() + at, end - at);
    while (!item.empty() && item.front() == ' ') item.remove_prefix(1);
    if (item.size() > name.size() && item.substr(0, name.size()) == name && item[name.size()] == '=')
      return std::string(item.substr(name.size() + 1));
    at = end + 1;
  }
  return std::nullopt;
}

// The page with the operator's default base map (a JS string literal; '<' escaped so that it cannot end the script).
std::string LivePage(const std::string& basemap) {
  std::string page = kLivePage;
  std::string literal = nlohmann::json(basemap).dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
  for (size_t i = 0; (i = literal.find('<', i)) != std::string::npos;) literal.replace(i, 1, "\\u003c");
  const std::string mark = "/*BASEMAP*/\"\"";
  page.replace(page.find(mark), mark.size(), literal);
  return page;
}

}  // namespace

LiveServer::LiveServer() = default;
LiveServer::~LiveServer() {
  Stop();
}

bool ParseHostPort(const std::string& text, std::string* host, int* port) {
  const auto colon = text.rfind(':');
  if (colon == std::string::npos || colon == 0) return false;
  try {
    size_t used = 0;
    const int p = std::stoi(text.substr(colon + 1), &used);
    if (used != text.size() - colon - 1 || p < 0 || p > 65535) return false;
    *port = p;
  } catch (const std::exception&) {
    return false;
  }
  *host = text.substr(0, colon);
  return true;
}

bool LiveServer::Admit(const httplib::Request& req, httplib::Response& res) {
  if (!gate_) return true;
  std::optional<std::string> presented;
  bool from_query = false, from_cookie = false;
  const std::string authorization = req.get_header_value("Authorization");
  if (authorization.rfind("Bearer ", 0) == 0) {
    presented = authorization.substr(7);
  } else if (req.has_param("token")) {
    presented = req.get_param_value("token");
    from_query = true;
  } else {
    presented = CookieValue(req.get_header_value("Cookie"), cookie_name_);
    from_cookie = presented.has_value();
  }
  const int64_t now = MonotonicNs();
  // A stale cookie (a tab left open after the token changed polls every second) is no guess: it must not lock the
  // operator's own address out.
  switch (gate_->Check(req.remote_addr, presented, now, /*guess=*/!from_cookie)) {
    case AccessGate::Verdict::kAllowed:
      // A browser that opened the page with ?token= keeps it for the page's own requests (pictures, tiles, scripts).
      if (from_query)
        res.set_header("Set-Cookie", cookie_name_ + "=" + *presented + "; Path=/; HttpOnly; SameSite=Strict" +
                                         (tls_ ? "; Secure" : ""));
      return true;
    case AccessGate::Verdict::kRateLimited:
      res.status = 429;
      res.set_header("Retry-After", std::to_string(std::max(1, gate_->RetryAfterSeconds(req.remote_addr, now))));
      res.set_header("Connection", "close");
      res.set_content("too many wrong access tokens: try again later\n", "text/plain");
      return false;
    case AccessGate::Verdict::kUnauthorized:
      break;
  }
  res.status = 401;
  res.set_header("WWW-Authenticate", "Bearer realm=\"uavmosaic\"");
  if (from_cookie) res.set_header("Set-Cookie", cookie_name_ + "=; Path=/; Max-Age=0");  // forget the stale one
  res.set_content("this live view needs its access token (Authorization: Bearer TOKEN, or ?token=TOKEN)\n",
                  "text/plain");
  return false;
}

AccessGate::Counters LiveServer::access_counters() const {
  return gate_ ? gate_->counters() : AccessGate::Counters{};
}

bool LiveServer::Start(const Options& o, std::string* error) {
  tls_ = !o.cert_file.empty() || !o.key_file.empty();
  if (tls_) {
    auto secure = std::make_unique<httplib::SSLServer>(o.cert_file.c_str(), o.key_file.c_str());
    if (!secure->is_valid()) {
      *error = "cannot load the TLS certificate " + o.cert_file + " and its key " + o.key_file +
               " (PEM files; the key must match the certificate)";
      return false;
    }
    server_ = std::move(secure);
  } else {
    server_ = std::make_unique<httplib::Server>();
  }
  gate_ = o.token.empty() ? nullptr : std::make_unique<AccessGate>(o.token, o.access);
  cookie_name_ = "uavm_token";  // made per port once bound: two servers on one host must not share it
  auto& s = *server_;
  const auto listen_fd = Configure(&s, o, &gauge_);
  s.set_pre_routing_handler([this](const httplib::Request& req, httplib::Response& res) {
    return Admit(req, res) ? httplib::Server::HandlerResponse::Unhandled : httplib::Server::HandlerResponse::Handled;
  });
  const auto busy = [this](httplib::Response& res) {
    if (!t_overflow) return false;
    ++refused_;
    res.status = 503;
    res.set_header("Retry-After", "1");
    res.set_header("Connection", "close");  // no keep-alive on the accepting thread
    res.set_content("busy\n", "text/plain");
    return true;
  };
  s.Get("/live.jpg", [this, busy](const httplib::Request&, httplib::Response& res) {
    if (!busy(res)) ServeJpeg(res);
  });
  s.Get("/status.json", [this, busy](const httplib::Request&, httplib::Response& res) {
    if (busy(res)) return;
    ++served_;
    res.set_header("Cache-Control", "no-store");
    res.set_content(StatusJson().dump(), "application/json");
  });
  s.Get("/", [this, busy, page = LivePage(o.basemap_url)](const httplib::Request&, httplib::Response& res) {
    if (busy(res)) return;
    ++served_;
    res.set_content(page, "text/html");
  });
  if (!s.set_mount_point("/leaflet", o.leaflet_dir))
    spdlog::warn("live view: Leaflet not found in {} (install libjs-leaflet)", o.leaflet_dir);
  port_ = o.port == 0 ? s.bind_to_any_port(o.host) : (s.bind_to_port(o.host, o.port) ? o.port : -1);
  if (port_ <= 0) {
    *error = "cannot listen on " + o.host + ":" + std::to_string(o.port);
    server_.reset();
    return false;
  }
  if (*listen_fd >= 0) ::listen(*listen_fd, kListenBacklog);
  cookie_name_ = "uavm_token_" + std::to_string(port_);  // cookies are per host, not per port
  AddTileRoutes(&s, {[this] { return TileSnapshotNow(); }, busy, &served_, o.host + ":" + std::to_string(port_), tls_,
                     gate_ != nullptr});
  listener_ = std::thread([this] {
    pthread_setname_np(pthread_self(), "uavm-http-acc");
    server_->listen_after_bind();
  });
  // httplib's stop() does nothing before its loop runs (the loop would then accept for ever): Stop() right after
  // Start() must not hang.
  for (int i = 0; i < 2000 && !server_->is_running(); ++i) std::this_thread::sleep_for(std::chrono::milliseconds(1));
  spdlog::info("live view on {}://{}:{}/ (/live.jpg, /status.json, /tiles.json){}", tls_ ? "https" : "http", o.host,
               port_, gate_ ? ", with an access token" : "");
  return true;
}

void LiveServer::ServeJpeg(httplib::Response& res) {
  std::shared_ptr<const std::string> jpeg;
  std::shared_ptr<const nlohmann::json> georef;
  {
    std::lock_guard<std::mutex> lock(jpeg_mutex_);
    jpeg = jpeg_;
    georef = georef_;
  }
  ++served_;
  res.set_header("Cache-Control", "no-store");
  // This picture's own corners: the page places it by them, never by a status read before a newer picture came.
  res.set_header("X-Georef-Corners",
                 georef && georef->value("georeferenced", false) ? (*georef)["corners"].dump() : std::string("null"));
  if (!jpeg) {
    res.status = 503;
    res.set_header("Retry-After", "1");
    res.set_content("no picture yet\n", "text/plain");
    return;
  }
  // Streamed from the shared buffer: no copy, and the frame loop may publish a new one meanwhile.
  res.set_content_provider(jpeg->size(), "image/jpeg", [jpeg](size_t offset, size_t length, httplib::DataSink& sink) {
    return sink.write(jpeg->data() + offset, length);
  });
}

nlohmann::json LiveServer::StatusJson() {
  LiveStatus st;
  long seq = 0;
  std::shared_ptr<const nlohmann::json> georef;
  {
    std::lock_guard<std::mutex> lock(status_mutex_);
    st = status_;
  }
  {
    std::lock_guard<std::mutex> lock(jpeg_mutex_);
    seq = jpeg_seq_;
    georef = georef_;
  }
  const AccessGate::Counters access = access_counters();
  return {{"state", st.state},
          {"frames_in", st.frames_in},
          {"registered", st.registered},
          {"dropped", st.dropped},
          {"fps", st.fps},
          {"median_frame_ms", st.median_frame_ms},
          {"rss_mib", st.rss_mib},
          {"peak_rss_mib", st.peak_rss_mib},
          {"budget_mib", st.budget_mib},
          {"last_error", st.last_error},
          {"uptime_s", st.uptime_s},
          {"jpeg_seq", seq},
          {"http_served", served_.load()},
          {"http_refused", refused_.load()},
          {"http_working", gauge_.working.load()},
          {"http_queued", gauge_.queued.load()},
          {"http_access",
           {{"token", gate_ != nullptr},
            {"tls", tls_},
            {"allowed", access.allowed},
            {"unauthorized", access.unauthorized},
            {"wrong_token", access.wrong_token},
            {"rate_limited", access.rate_limited},
            {"lockouts", access.lockouts}}},
          {"georef", georef ? *georef : nlohmann::json{{"georeferenced", false}, {"reason", "no picture yet"}}},
          {"tiles", TilesStatus(TileSnapshotNow().tiles.get())}};
}

void LiveServer::Stop() {
  if (!server_) return;
  server_->stop();
  if (listener_.joinable()) listener_.join();
  server_.reset();
}

void LiveServer::PublishJpeg(std::shared_ptr<const std::string> jpeg, std::shared_ptr<const nlohmann::json> georef) {
  std::lock_guard<std::mutex> lock(jpeg_mutex_);  // held by readers only for pointer copies
  jpeg_ = std::move(jpeg);
  georef_ = std::move(georef);
  ++jpeg_seq_;
}

void LiveServer::PublishTiles(std::shared_ptr<const TileSetInfo> tiles) {
  std::lock_guard<std::mutex> lock(tiles_mutex_);
  tiles_ = std::move(tiles);
}

void LiveServer::PublishFootprints(std::shared_ptr<const std::string> geojson) {
  std::lock_guard<std::mutex> lock(tiles_mutex_);
  footprints_ = std::move(geojson);
}

TileSnapshot LiveServer::TileSnapshotNow() {
  std::lock_guard<std::mutex> lock(tiles_mutex_);
  return {tiles_, footprints_};
}

void LiveServer::PublishStatus(const LiveStatus& status, bool wait) {
  std::unique_lock<std::mutex> lock(status_mutex_, std::defer_lock);
  if (wait)
    lock.lock();
  else
    (void)lock.try_lock();
  if (lock.owns_lock()) status_ = status;
}

}  // namespace uavm::app
