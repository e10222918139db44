#pragma once
// The live tile pyramid over the live HTTP server (firmware_app/live_server.h): GET /tiles/{z}/{x}/{y}.png, the
// descriptions map clients read first (/tiles.json TileJSON 3.0.0, /wmts/1.0.0/WMTSCapabilities.xml OGC WMTS 1.0.0,
// /tiles.xml GDAL's WMS/TMS service description) and /footprints.geojson. The answers are built here as plain Replies
// from an immutable snapshot, so that the rules are testable without a server and no lock is held while they are made.
#include <atomic>
#include <cstdint>
#include <functional>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <string_view>

#include "core/tiles/tile_set.h"

namespace httplib {
class Server;
struct Response;
}  // namespace httplib

namespace uavm::app {

struct TileKey {
  int z = 0;
  int64_t x = 0;
  int64_t y = 0;
};

// "/tiles/Z/X/Y.png" (the decoded path, the query already split off by httplib) -> the tile's indices. Strict: three
// parts of 1-9 decimal digits without sign or leading zero, ".png"; anything else is malformed (false).
[[nodiscard]] bool ParseTilePath(std::string_view path, TileKey* key);

// Whether the tile lies on the set's grid: z in [min_zoom, max_zoom]; x, y in [0, 2^z) (geographic) or within the
// local map's extent.
[[nodiscard]] bool TileInRange(const TileSetInfo& tiles, const TileKey& key);

// A route's answer, independent of httplib.
struct Reply {
  int status = 200;
  std::string body;
  std::string content_type = "text/plain";
  std::string etag;           // quoted; empty: none
  std::string cache_control;  // empty: none
};

[[nodiscard]] Reply TileReply(const TileSetInfo* tiles, std::string_view path, std::string_view if_none_match);
// Where the descriptions send their clients: "http(s)://HOST[:PORT]", and what each URL they give ends with: the
// access token's query ("?token=..."), for a client that authenticated with it and follows only URLs (GDAL, QGIS).
struct ServiceUrl {
  std::string base;
  std::string query;
};
[[nodiscard]] Reply TileJsonReply(const TileSetInfo* tiles, const ServiceUrl& url, std::string_view if_none_match);
[[nodiscard]] Reply WmtsReply(const TileSetInfo* tiles, const ServiceUrl& url);
[[nodiscard]] Reply GdalWmsReply(const TileSetInfo* tiles, const ServiceUrl& url);
[[nodiscard]] Reply FootprintsReply(const std::string* geojson);

// status.json "tiles": the set's description, or null.
[[nodiscard]] nlohmann::json TilesStatus(const TileSetInfo* tiles);

// "http://HOST" (https:// with `tls`) from the request's Host header when it is a plain host[:port] (it ends up in XML
// and JSON documents), else from `fallback_host` (the address the server listens on).
[[nodiscard]] std::string BaseUrl(std::string_view host_header, const std::string& fallback_host, bool tls = false);

// Whether an If-None-Match header value names `etag` (a list, weak validators, "*").
[[nodiscard]] bool EtagMatches(std::string_view if_none_match, std::string_view etag);

// What the routes read: pointer copies taken under the server's lock.
struct TileSnapshot {
  std::shared_ptr<const TileSetInfo> tiles;
  std::shared_ptr<const std::string> footprints;
};
struct TileRouteHooks {
  std::function<TileSnapshot()> snapshot;
  std::function<bool(httplib::Response&)> busy;  // true: the pool is full and a 503 was set
  std::atomic<long>* served = nullptr;
  std::string fallback_host;  // "HOST:PORT" the server listens on
  bool tls = false;           // the documents' URLs are https://
  bool gated = false;         // an access token guards the server: a query token that passed is carried on
};
void AddTileRoutes(httplib::Server* server, const TileRouteHooks& hooks);

}  // namespace uavm::app
