#include "firmware_app/tile_routes.h"

#include <fcntl.h>
#include <httplib.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <functional>
#include <string>
#include <string_view>

#include "firmware_app/access_gate.h"

namespace uavm::app {

namespace {

constexpr std::string_view kTilesPrefix = "/tiles/";
constexpr int kMaxZoom = 30;              // 2^z still fits the parsed range; no real grid goes beyond 24
constexpr long kMaxTileBytes = 8L << 20;  // a 256x256 RGBA PNG is far smaller; anything bigger is not a tile
// Full precision (pi * 6378137): with the OGC's 7 decimals a client that snaps windows to the grid can land a pixel
// off (GDAL 3.6's gdal_translate -projwin did, by one row).
constexpr double kWebMercatorHalf = 20037508.342789244;
constexpr double kScaleZ0 = 559082264.0287178;  // GoogleMapsCompatible scale denominator at zoom 0
constexpr const char* kNoCache = "no-cache";

// 1-9 decimal digits, no sign, no leading zero: at most 999999999, so nothing overflows and each tile has one URL.
bool ParseIndex(std::string_view s, int64_t* value) {
  if (s.empty() || s.size() > 9 || (s.size() > 1 && s[0] == '0')) return false;
  int64_t v = 0;
  for (const char c : s) {
    if (c < '0' || c > '9') return false;
    v = v * 10 + (c - '0');
  }
  *value = v;
  return true;
}

std::string Number(double v, const char* format = "%.10f") {
  char buf[64];
  std::snprintf(buf, sizeof(buf), format, v);
  return buf;
}

Reply Text(int status, std::string body) {
  Reply r;
  r.status = status;
  r.body = std::move(body);
  r.body += '\n';
  return r;
}

// The whole file and its identity (mtime, size) from one descriptor: a tile renamed over meanwhile is read whole,
// old or new, never half. No exceptions: a failure is just "missing".
bool ReadWhole(const std::string& path, std::string* data, struct stat* st) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) return false;
  bool ok = ::fstat(fd, st) == 0 && S_ISREG(st->st_mode) && st->st_size <= kMaxTileBytes;
  if (ok) {
    data->resize(static_cast<size_t>(st->st_size));
    size_t got = 0;
    while (ok && got < data->size()) {
      const ssize_t n = ::read(fd, data->data() + got, data->size() - got);
      if (n <= 0)
        ok = false;
      else
        got += static_cast<size_t>(n);
    }
  }
  ::close(fd);
  return ok;
}

std::string TileEtag(const TileSetInfo& tiles, const struct stat& st) {
  const int64_t mtime_ns = static_cast<int64_t>(st.st_mtim.tv_sec) * 1000000000LL + st.st_mtim.tv_nsec;
  return "\"" + std::to_string(tiles.generation) + "-" + std::to_string(mtime_ns) + "-" +
         std::to_string(static_cast<int64_t>(st.st_size)) + "\"";
}

std::string BodyEtag(const std::string& body) {
  char buf[32];
  std::snprintf(buf, sizeof(buf), "\"j%016zx\"", std::hash<std::string>{}(body));
  return buf;
}

// Web-mercator tile column / row of a longitude / latitude at zoom z, clamped to the grid. The lower edge's tile, or
// (`upper`) the last tile before the upper edge: an extent ending exactly on a tile boundary does not reach the next
// tile (a 1e-6 tile tolerance absorbs the rounding of bounds computed from tile edges).
int64_t TileIndex(double v, int z, bool upper) {
  const double i = upper ? std::ceil(v - 1e-6) - 1 : std::floor(v + 1e-6);
  return std::clamp(static_cast<int64_t>(i), int64_t{0}, (int64_t{1} << z) - 1);
}
int64_t LonToTileX(double lon, int z, bool upper) {
  return TileIndex((lon + 180.0) / 360.0 * std::ldexp(1.0, z), z, upper);
}
int64_t LatToTileY(double lat, int z, bool upper) {
  const double r = std::clamp(lat, -85.0511287798, 85.0511287798) * M_PI / 180.0;
  return TileIndex((1.0 - std::asinh(std::tan(r)) / M_PI) / 2.0 * std::ldexp(1.0, z), z, upper);
}

Reply NotGeoreferenced(const char* what) {
  return Text(404, std::string(what) +
                       " needs a CRS: the map is not georeferenced yet (the live tiles are a local pyramid; see "
                       "/tiles.json)");
}

std::string WmtsLimits(const TileSetInfo& t) {
  std::string s = "<TileMatrixSetLimits>\n";
  for (int z = std::max(0, t.min_zoom); z <= std::min(t.max_zoom, kMaxZoom); ++z) {
    const int64_t row0 = LatToTileY(t.north, z, false), col0 = LonToTileX(t.west, z, false);
    const int64_t row1 = std::max(row0, LatToTileY(t.south, z, true));
    const int64_t col1 = std::max(col0, LonToTileX(t.east, z, true));
    s += "<TileMatrixLimits><TileMatrix>" + std::to_string(z) + "</TileMatrix><MinTileRow>" + std::to_string(row0) +
         "</MinTileRow><MaxTileRow>" + std::to_string(row1) + "</MaxTileRow><MinTileCol>" + std::to_string(col0) +
         "</MinTileCol><MaxTileCol>" + std::to_string(col1) + "</MaxTileCol></TileMatrixLimits>\n";
  }
  return s + "</TileMatrixSetLimits>\n";
}

// The OGC well-known GoogleMapsCompatible set, levels 0..max_zoom (a client may zoom out past min_zoom; the limits
// above say where tiles exist).
std::string WmtsMatrixSet(const TileSetInfo& t) {
  std::string s =
      "<TileMatrixSet><ows:Identifier>GoogleMapsCompatible</ows:Identifier>\n"
      "<ows:SupportedCRS>urn:ogc:def:crs:EPSG::3857</ows:SupportedCRS>\n"
      "<WellKnownScaleSet>urn:ogc:def:wkss:OGC:1.0:GoogleMapsCompatible</WellKnownScaleSet>\n";
  const std::string corner = Number(-kWebMercatorHalf, "%.9f") + " " + Number(kWebMercatorHalf, "%.9f");
  for (int z = 0; z <= std::min(t.max_zoom, kMaxZoom); ++z) {
    const std::string n = std::to_string(int64_t{1} << z);
    s += "<TileMatrix><ows:Identifier>" + std::to_string(z) + "</ows:Identifier><ScaleDenominator>";
    s += Number(kScaleZ0 / std::ldexp(1.0, z), "%.10f") + "</ScaleDenominator><TopLeftCorner>";
    s += corner + "</TopLeftCorner><TileWidth>256</TileWidth><TileHeight>256</TileHeight><MatrixWidth>";
    s += n + "</MatrixWidth><MatrixHeight>";
    s += n + "</MatrixHeight></TileMatrix>\n";
  }
  return s + "</TileMatrixSet>\n";
}

std::string WmtsLayer(const TileSetInfo& t, const ServiceUrl& url) {
  return "<Layer><ows:Title>uavmosaic live map</ows:Title>\n"
         "<ows:WGS84BoundingBox><ows:LowerCorner>" +
         Number(t.west) + " " + Number(t.south) + "</ows:LowerCorner><ows:UpperCorner>" + Number(t.east) + " " +
         Number(t.north) +
         "</ows:UpperCorner></ows:WGS84BoundingBox>\n"
         "<ows:Identifier>uavmosaic</ows:Identifier>\n"
         "<Style isDefault=\"true\"><ows:Identifier>default</ows:Identifier></Style>\n"
         "<Format>image/png</Format>\n"
         "<TileMatrixSetLink><TileMatrixSet>GoogleMapsCompatible</TileMatrixSet>\n" +
         WmtsLimits(t) +
         "</TileMatrixSetLink>\n"
         "<ResourceURL format=\"image/png\" resourceType=\"tile\" template=\"" +
         url.base + "/tiles/{TileMatrix}/{TileCol}/{TileRow}.png" + url.query + "\"/>\n</Layer>\n";
}

void Send(const Reply& r, httplib::Response& res) {
  res.status = r.status;
  if (!r.etag.empty()) res.set_header("ETag", r.etag);
  if (!r.cache_control.empty()) res.set_header("Cache-Control", r.cache_control);
  if (r.status != 304) res.set_content(r.body, r.content_type);
}

}  // namespace

bool ParseTilePath(std::string_view path, TileKey* key) {
  if (path.substr(0, kTilesPrefix.size()) != kTilesPrefix) return false;
  std::string_view rest = path.substr(kTilesPrefix.size());
  const size_t a = rest.find('/');
  if (a == std::string_view::npos) return false;
  const size_t b = rest.find('/', a + 1);
  if (b == std::string_view::npos || rest.find('/', b + 1) != std::string_view::npos) return false;
  std::string_view file = rest.substr(b + 1);
  constexpr std::string_view kExt = ".png";
  if (file.size() <= kExt.size() || file.substr(file.size() - kExt.size()) != kExt) return false;
  file.remove_suffix(kExt.size());
  int64_t z = 0;
  if (!ParseIndex(rest.substr(0, a), &z) || !ParseIndex(rest.substr(a + 1, b - a - 1), &key->x) ||
      !ParseIndex(file, &key->y))
    return false;
  key->z = static_cast<int>(std::min<int64_t>(z, kMaxZoom + 1));  // beyond any grid: a 404, like any z out of range
  return true;
}

bool TileInRange(const TileSetInfo& t, const TileKey& k) {
  if (k.z < t.min_zoom || k.z > t.max_zoom || k.z > kMaxZoom || k.x < 0 || k.y < 0) return false;
  if (t.geographic) return k.x < (int64_t{1} << k.z) && k.y < (int64_t{1} << k.z);
  // Local: CRS.Simple units are map pixels / 2^max_zoom, and a tile at z spans 256 / 2^z units.
  const double per_unit = std::ldexp(1.0, k.z) / kTileSize;
  return static_cast<double>(k.x) <= std::floor(std::max(0.0, t.east) * per_unit) &&
         static_cast<double>(k.y) <= std::floor(std::max(0.0, -t.south) * per_unit);
}

Reply TileReply(const TileSetInfo* tiles, std::string_view path, std::string_view if_none_match) {
  TileKey key;
  if (!ParseTilePath(path, &key)) return Text(400, "bad tile path: expected /tiles/{z}/{x}/{y}.png");
  Reply r = Text(404, tiles ? "no such tile" : "no tile set yet");
  r.cache_control = kNoCache;
  if (!tiles || !TileInRange(*tiles, key)) return r;
  // Built from the parsed integers only: no request text reaches the filesystem.
  const std::string file =
      tiles->dir + "/" + std::to_string(key.z) + "/" + std::to_string(key.x) + "/" + std::to_string(key.y) + ".png";
  std::string data;
  struct stat st {};
  if (!ReadWhole(file, &data, &st)) return r;
  r.status = 200;
  r.etag = TileEtag(*tiles, st);
  r.cache_control = tiles->final ? "public, max-age=3600" : kNoCache;  // live tiles change: clients revalidate
  r.content_type = "image/png";
  if (EtagMatches(if_none_match, r.etag)) {
    r.status = 304;
    r.body.clear();
  } else {
    r.body = std::move(data);
  }
  return r;
}

Reply TileJsonReply(const TileSetInfo* tiles, const ServiceUrl& url, std::string_view if_none_match) {
  if (!tiles) return Text(404, "no tile set yet");
  const TileSetInfo& t = *tiles;
  const int centre_zoom = std::clamp(t.max_zoom - 2, t.min_zoom, t.max_zoom);
  const nlohmann::json j = {
      {"tilejson", "3.0.0"},
      {"name", "uavmosaic"},
      {"description", t.final ? "uavmosaic map (end of flight)" : "uavmosaic live map (growing during the flight)"},
      {"attribution", "uavmosaic aerial survey"},
      {"tiles", {url.base + "/tiles/{z}/{x}/{y}.png" + url.query}},
      {"scheme", "xyz"},
      {"minzoom", t.min_zoom},
      {"maxzoom", t.max_zoom},
      {"bounds", {t.west, t.south, t.east, t.north}},
      {"center", {(t.west + t.east) / 2, (t.south + t.north) / 2, centre_zoom}},
      {"uavmosaic",
       {{"geographic", t.geographic},
        {"crs", t.geographic ? "EPSG:3857" : "CRS.Simple"},
        {"bounds_units", t.geographic ? "WGS84 degrees"
                                      : "CRS.Simple units (lng = x / 2^maxzoom, lat = -y / 2^maxzoom in map "
                                        "pixels), not WGS84: the map is not georeferenced yet"},
        {"generation", t.generation},
        {"final", t.final},
        {"frames", t.frames},
        {"updated_ns", t.updated_ns}}}};
  Reply r;
  r.body = j.dump(2);
  r.content_type = "application/json";
  r.cache_control = kNoCache;
  r.etag = BodyEtag(r.body);
  if (EtagMatches(if_none_match, r.etag)) r.status = 304;
  return r;
}

Reply WmtsReply(const TileSetInfo* tiles, const ServiceUrl& url) {
  if (!tiles) return Text(404, "no tile set yet");
  if (!tiles->geographic) return NotGeoreferenced("WMTS");
  Reply r;
  r.body =
      "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n"
      "<Capabilities xmlns=\"http://www.opengis.net/wmts/1.0\" xmlns:ows=\"http://www.opengis.net/ows/1.1\" "
      "xmlns:xlink=\"http://www.w3.org/1999/xlink\" xmlns:xsi=\"http://www.w3.org/2001/XMLSchema-instance\" "
      "xsi:schemaLocation=\"http://www.opengis.net/wmts/1.0 "
      "http://schemas.opengis.net/wmts/1.0/wmtsGetCapabilities_response.xsd\" version=\"1.0.0\">\n"
      "<ows:ServiceIdentification><ows:Title>uavmosaic live map</ows:Title>"
      "<ows:ServiceType>OGC WMTS</ows:ServiceType><ows:ServiceTypeVersion>1.0.0</ows:ServiceTypeVersion>"
      "</ows:ServiceIdentification>\n<Contents>\n" +
      WmtsLayer(*tiles, url) + WmtsMatrixSet(*tiles) + "</Contents>\n<ServiceMetadataURL xlink:href=\"" + url.base +
      "/wmts/1.0.0/WMTSCapabilities.xml" + url.query + "\"/>\n</Capabilities>\n";
  r.content_type = "application/xml";
  r.cache_control = kNoCache;
  return r;
}

// GDAL's WMS driver, TMS mini-driver: the whole web-mercator world at TileLevel max_zoom, one tile at level 0, rows
// from the top. A tile not drawn (yet) is a 404, which GDAL reads as an empty (transparent) block.
Reply GdalWmsReply(const TileSetInfo* tiles, const ServiceUrl& url) {
  if (!tiles) return Text(404, "no tile set yet");
  if (!tiles->geographic) return NotGeoreferenced("The GDAL XYZ description");
  const std::string half = Number(kWebMercatorHalf, "%.9f");
  Reply r;
  r.body = "<GDAL_WMS>\n<Service name=\"TMS\"><ServerUrl>" + url.base + "/tiles/${z}/${x}/${y}.png" + url.query +
           "</ServerUrl></Service>\n<DataWindow><UpperLeftX>-" + half + "</UpperLeftX><UpperLeftY>" + half +
           "</UpperLeftY><LowerRightX>" + half + "</LowerRightX><LowerRightY>-" + half + "</LowerRightY><TileLevel>" +
           std::to_string(tiles->max_zoom) +
           "</TileLevel><TileCountX>1</TileCountX><TileCountY>1</TileCountY><YOrigin>top</YOrigin></DataWindow>\n"
           "<Projection>EPSG:3857</Projection><BlockSizeX>256</BlockSizeX><BlockSizeY>256</BlockSizeY>"
           "<BandsCount>4</BandsCount>\n<ZeroBlockHttpCodes>204,404</ZeroBlockHttpCodes>\n</GDAL_WMS>\n";
  r.content_type = "application/xml";
  r.cache_control = kNoCache;
  return r;
}

Reply FootprintsReply(const std::string* geojson) {
  Reply r;
  r.body = geojson ? *geojson : std::string(R"({"type":"FeatureCollection","features":[]})");
  r.content_type = "application/geo+json";
  r.cache_control = "no-store";
  return r;
}

nlohmann::json TilesStatus(const TileSetInfo* t) {
  if (!t) return nullptr;
  return {{"generation", t->generation},
          {"geographic", t->geographic},
          {"min_zoom", t->min_zoom},
          {"max_zoom", t->max_zoom},
          {"bounds", {t->west, t->south, t->east, t->north}},
          {"frames", t->frames},
          {"final", t->final},
          {"updated_ns", t->updated_ns}};
}

std::string BaseUrl(std::string_view host, const std::string& fallback_host, bool tls) {
  const bool plain = !host.empty() && host.size() <= 255 && std::all_of(host.begin(), host.end(), [](char c) {
    return std::isalnum(static_cast<unsigned char>(c)) || c == '.' || c == '-' || c == ':' || c == '[' || c == ']';
  });
  return (tls ? "https://" : "http://") + (plain ? std::string(host) : fallback_host);
}

bool EtagMatches(std::string_view header, std::string_view etag) {
  while (!header.empty()) {
    const size_t comma = header.find(',');
    std::string_view item = header.substr(0, comma);
    header = comma == std::string_view::npos ? std::string_view{} : header.substr(comma + 1);
    while (!item.empty() && item.front() == ' ') item.remove_prefix(1);
    while (!item.empty() && item.back() == ' ') item.remove_suffix(1);
    if (item.substr(0, 2) == "W/") item.remove_prefix(2);  // If-None-Match compares weakly
    if (item == "*" || item == etag) return true;
  }
  return false;
}

void AddTileRoutes(httplib::Server* server, const TileRouteHooks& h) {
  // Each route: 503 when the pool is full, else a reply built from one snapshot with no lock held.
  using Build = std::function<Reply(const TileSnapshot&, const httplib::Request&, const ServiceUrl&)>;
  const auto route = [h](const Build& f) {
    return [h, f](const httplib::Request& req, httplib::Response& res) {
      if (h.busy(res)) return;
      ++*h.served;
      // A query token that was the request's credential (the gate checked it: no Bearer header took precedence) is
      // carried on in the URLs handed out; nothing else from the query ever reaches a document.
      const bool bearer = req.get_header_value("Authorization").rfind("Bearer ", 0) == 0;
      const std::string token = h.gated && !bearer && req.has_param("token") ? req.get_param_value("token") : "";
      const ServiceUrl url{BaseUrl(req.get_header_value("Host"), h.fallback_host, h.tls),
                           !token.empty() && IsUrlSafe(token) ? "?token=" + token : ""};
      Send(f(h.snapshot(), req, url), res);
    };
  };
  // [\s\S]: every path under /tiles/ is ours, so that a malformed one gets a 400, not the generic 404.
  server->Get(R"(/tiles/[\s\S]*)", route([](const TileSnapshot& s, const httplib::Request& req, const ServiceUrl&) {
                return TileReply(s.tiles.get(), req.path, req.get_header_value("If-None-Match"));
              }));
  server->Get(R"(/tiles\.json)", route([](const TileSnapshot& s, const httplib::Request& req, const ServiceUrl& b) {
                return TileJsonReply(s.tiles.get(), b, req.get_header_value("If-None-Match"));
              }));
  const auto wmts = route(
      [](const TileSnapshot& s, const httplib::Request&, const ServiceUrl& b) { return WmtsReply(s.tiles.get(), b); });
  server->Get(R"(/wmts/1\.0\.0/WMTSCapabilities\.xml)", wmts);
  server->Get(R"(/WMTSCapabilities\.xml)", wmts);
  server->Get(R"(/tiles\.xml)", route([](const TileSnapshot& s, const httplib::Request&, const ServiceUrl& b) {
                return GdalWmsReply(s.tiles.get(), b);
              }));
  server->Get(R"(/footprints\.geojson)", route([](const TileSnapshot& s, const httplib::Request&, const ServiceUrl&) {
                return FootprintsReply(s.footprints.get());
              }));
}

}  // namespace uavm::app
