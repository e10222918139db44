#include "firmware_app/live_server.h"

#include <httplib.h>
#include <pthread.h>
#include <spdlog/spdlog.h>

#include <condition_variable>
#include <deque>
#include <functional>
#include <nlohmann/json.hpp>
#include <vector>

namespace uavm::app {

namespace {

// Set while the accepting thread itself answers a request the pool had no room for: handlers reply 503 at once.
thread_local bool t_overflow = false;

// httplib's own ThreadPool queues without limit; this one holds at most `capacity` waiting connections.
class BoundedPool : public httplib::TaskQueue {
 public:
  BoundedPool(int threads, int capacity) : capacity_(static_cast<size_t>(capacity)) {
    for (int i = 0; i < threads; ++i) workers_.emplace_back([this] { Work(); });
  }
  ~BoundedPool() override { shutdown(); }

  void enqueue(std::function<void()> fn) override {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      if (!stop_ && jobs_.size() < capacity_) {
        jobs_.push_back(std::move(fn));
        cv_.notify_one();
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
  }

 private:
  void Work() {
    pthread_setname_np(pthread_self(), "uavm-http");  // bench/http_load.sh measures these threads' CPU
    for (;;) {
      std::function<void()> fn;
      {
        std::unique_lock<std::mutex> lock(mutex_);
        cv_.wait(lock, [&] { return stop_ || !jobs_.empty(); });
        if (jobs_.empty()) return;
        fn = std::move(jobs_.front());
        jobs_.pop_front();
      }
      fn();
    }
  }

  size_t capacity_;
  std::mutex mutex_;
  std::condition_variable cv_;
  std::deque<std::function<void()>> jobs_;
  std::vector<std::thread> workers_;
  bool stop_ = false;
};

// The live page: Leaflet (served from Debian's libjs-leaflet) with the live picture, re-fetched when the status says a
// new one is out. The picture, not a growing tile set: it is what the frame loop already encodes every few frames, so
// the view costs the flight nothing more. Georeferenced, the picture (not north-up) is laid on a web-mercator map by
// a CSS affine transform through three of its corners, which arrive with the picture itself (X-Georef-Corners) so that
// a picture never gets another's place; otherwise it is shown in its own pixel frame (CRS.Simple).
const char* kLivePage = R"HTML(<!DOCTYPE html>
<html><head><meta charset="utf-8"><title>uavmosaic live</title>
<link rel="stylesheet" href="/leaflet/leaflet.css"><script src="/leaflet/leaflet.js"></script>
<style>html,body,#map{margin:0;height:100%;background:#000}
#s{position:absolute;z-index:1000;left:50px;top:8px;background:rgba(255,255,255,.85);padding:3px 8px;
font:12px monospace;border-radius:4px}</style></head>
<body><div id="map"></div><div id="s">waiting for the first picture&hellip;</div>
<script>
var map = null, geo = null, layer = null, seq = -1, followed = true, url = null;
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
function makeMap(georeferenced) {
  if (map) map.remove();
  geo = georeferenced;
  layer = null;
  followed = true;
  map = geo ? L.map('map', {zoomSnap: 0, zoomAnimation: false, maxZoom: 24})
            : L.map('map', {crs: L.CRS.Simple, minZoom: -4, zoomSnap: 0});
  if (geo) L.control.scale({imperial: false}).addTo(map);
}
// The view follows the growing mosaic until the operator pans or zooms.
document.getElementById('map').addEventListener('pointerdown', function () { followed = false; });
document.getElementById('map').addEventListener('wheel', function () { followed = false; });
function picture(img, corners) {
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
    st.rss_mib.toFixed(0) + '/' + st.budget_mib.toFixed(0) + ' MiB' +
    (g.georeferenced ? ' | ' + g.crs + ', RMS ' + g.rms_m.toFixed(1) + ' m over ' + g.frames_used + ' frames'
                     : ' | not georeferenced' + (g.reason ? ': ' + g.reason : '')) +
    (st.last_error ? ' | ' + st.last_error : '');
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

bool LiveServer::Start(const Options& o, std::string* error) {
  server_ = std::make_unique<httplib::Server>();
  auto& s = *server_;
  const int threads = o.threads, queue = o.queue;
  s.new_task_queue = [threads, queue] { return new BoundedPool(threads, queue); };
  // Short timeouts and no long keep-alive: a slow or idle client must not hold one of the few workers.
  s.set_keep_alive_max_count(4);
  s.set_keep_alive_timeout(1);
  s.set_read_timeout(2, 0);
  s.set_write_timeout(2, 0);
  s.set_payload_max_length(4096);
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
    if (busy(res)) return;
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
  });
  s.Get("/status.json", [this, busy](const httplib::Request&, httplib::Response& res) {
    if (busy(res)) return;
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
    ++served_;
    const nlohmann::json j = {
        {"state", st.state},
        {"frames_in", st.frames_in},
        {"registered", st.registered},
        {"dropped", st.dropped},
        {"fps", st.fps},
        {"median_frame_ms", st.median_frame_ms},
        {"rss_mib", st.rss_mib},
        {"budget_mib", st.budget_mib},
        {"last_error", st.last_error},
        {"uptime_s", st.uptime_s},
        {"jpeg_seq", seq},
        {"http_served", served_.load()},
        {"http_refused", refused_.load()},
        {"georef", georef ? *georef : nlohmann::json{{"georeferenced", false}, {"reason", "no picture yet"}}}};
    res.set_header("Cache-Control", "no-store");
    res.set_content(j.dump(), "application/json");
  });
  s.Get("/", [this, busy](const httplib::Request&, httplib::Response& res) {
    if (busy(res)) return;
    ++served_;
    res.set_content(kLivePage, "text/html");
  });
  if (!s.set_mount_point("/leaflet", o.leaflet_dir))
    spdlog::warn("live view: Leaflet not found in {} (install libjs-leaflet)", o.leaflet_dir);
  port_ = o.port == 0 ? s.bind_to_any_port(o.host) : (s.bind_to_port(o.host, o.port) ? o.port : -1);
  if (port_ <= 0) {
    *error = "cannot listen on " + o.host + ":" + std::to_string(o.port);
    server_.reset();
    return false;
  }
  listener_ = std::thread([this] {
    pthread_setname_np(pthread_self(), "uavm-http-acc");
    server_->listen_after_bind();
  });
  spdlog::info("live view on http://{}:{}/ (/live.jpg, /status.json)", o.host, port_);
  return true;
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

void LiveServer::PublishStatus(const LiveStatus& status, bool wait) {
  std::unique_lock<std::mutex> lock(status_mutex_, std::defer_lock);
  if (wait)
    lock.lock();
  else
    (void)lock.try_lock();
  if (lock.owns_lock()) status_ = status;
}

}  // namespace uavm::app
