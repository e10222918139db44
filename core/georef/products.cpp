#include "core/georef/products.h"

#include <cpl_string.h>
#include <gdal_priv.h>
#include <gdal_utils.h>
#include <gdalwarper.h>
#include <ogr_spatialref.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <memory>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>

namespace uavm {

namespace fs = std::filesystem;

namespace {

constexpr double kWebMercatorHalf = 20037508.342789244;  // metres, half the EPSG:3857 world width
constexpr int kTile = 256;

struct DatasetCloser {
  void operator()(GDALDataset* d) const { GDALClose(d); }
};
using DatasetPtr = std::unique_ptr<GDALDataset, DatasetCloser>;

DatasetPtr OpenRead(const std::string& path, std::string* error) {
  GDALAllRegister();
  DatasetPtr ds(GDALDataset::Open(path.c_str(), GDAL_OF_RASTER | GDAL_OF_READONLY));
  if (!ds) *error = "cannot open " + path + ": " + CPLGetLastErrorMsg();
  return ds;
}

bool RenameOver(const std::string& from, const std::string& to, std::string* error) {
  std::error_code ec;
  fs::rename(from, to, ec);
  if (ec) *error = "cannot rename " + from + " to " + to + ": " + ec.message();
  return !ec;
}

// Writes one BGRA tile as PNG unless it is fully transparent. Returns false on an I/O error.
bool SaveTile(const cv::Mat& bgra, const fs::path& path, bool* written, std::string* error) {
  cv::Mat alpha;
  cv::extractChannel(bgra, alpha, 3);
  *written = cv::countNonZero(alpha) > 0;
  if (!*written) return true;
  std::error_code ec;
  fs::create_directories(path.parent_path(), ec);
  std::vector<uchar> png;
  if (ec || !cv::imencode(".png", bgra, png)) {
    *error = "cannot write " + path.string();
    return false;
  }
  std::ofstream out(path, std::ios::binary);
  out.write(reinterpret_cast<const char*>(png.data()), static_cast<std::streamsize>(png.size()));
  if (!out) *error = "cannot write " + path.string();
  return static_cast<bool>(out);
}

// Reads a 4-band dataset window into a BGRA image of `buf` size at `at` inside `tile` (GDAL resamples, using
// overviews when it downsamples).
bool ReadBgra(GDALDataset* ds, int x, int y, int w, int h, cv::Mat* tile, cv::Rect at) {
  int bands[4] = {3, 2, 1, 4};
  GDALRasterIOExtraArg extra;
  INIT_RASTERIO_EXTRA_ARG(extra);
  extra.eResampleAlg = GRIORA_Average;
  cv::Mat roi = (*tile)(at);
  return ds->RasterIO(GF_Read, x, y, w, h, roi.data, at.width, at.height, GDT_Byte, 4, bands, 4,
                      static_cast<GSpacing>(roi.step[0]), 1, &extra) == CE_None;
}

double Log2Ceil(double v) {
  return std::ceil(std::log2(std::max(v, 1e-12)) - 1e-9);
}

}  // namespace

bool WriteCog(const std::string& src, const std::string& dst, std::string* error) {
  auto in = OpenRead(src, error);
  if (!in) return false;
  GDALDriver* cog = GetGDALDriverManager()->GetDriverByName("COG");
  if (cog == nullptr) {
    *error = "GDAL has no COG driver";
    return false;
  }
  char** opts = nullptr;
  opts = CSLSetNameValue(opts, "BLOCKSIZE", "512");
  opts = CSLSetNameValue(opts, "COMPRESS", "DEFLATE");
  opts = CSLSetNameValue(opts, "LEVEL", "1");  // fast: the onboard CPU is busy
  opts = CSLSetNameValue(opts, "PREDICTOR", "YES");
  opts = CSLSetNameValue(opts, "BIGTIFF", "IF_SAFER");
  opts = CSLSetNameValue(opts, "OVERVIEWS", "AUTO");  // the source's overviews, built while compositing
  opts = CSLSetNameValue(opts, "NUM_THREADS", "1");
  const std::string part = dst + ".part";
  CPLErrorReset();
  // The COG driver checks the extension; .part is fine with the GTiff writer underneath.
  GDALDataset* out = cog->CreateCopy(part.c_str(), in.get(), FALSE, opts, nullptr, nullptr);
  CSLDestroy(opts);
  const bool ok = out != nullptr && CPLGetLastErrorType() != CE_Failure;
  if (out != nullptr) GDALClose(out);
  if (!ok || CPLGetLastErrorType() == CE_Failure) {
    *error = std::string("COG: ") + CPLGetLastErrorMsg();
    std::remove(part.c_str());
    return false;
  }
  in.reset();
  return RenameOver(part, dst, error);
}

bool WriteKmz(const std::string& tif, const std::string& kmz, std::string* error) {
  auto in = OpenRead(tif, error);
  if (!in) return false;
  GDALDriver* drv = GetGDALDriverManager()->GetDriverByName("KMLSUPEROVERLAY");
  if (drv == nullptr) {
    *error = "GDAL has no KMLSUPEROVERLAY driver";
    return false;
  }
  // The driver reprojects to WGS 84 itself, tile by tile.
  char** opts = CSLSetNameValue(nullptr, "FORMAT", "PNG");
  std::string part = kmz;
  part.insert(part.size() - std::min<size_t>(part.size(), 4), ".part");  // the driver zips by the .kmz extension
  CPLErrorReset();
  GDALDataset* out = drv->CreateCopy(part.c_str(), in.get(), FALSE, opts, nullptr, nullptr);
  CSLDestroy(opts);
  const bool ok = out != nullptr && CPLGetLastErrorType() != CE_Failure;
  if (out != nullptr) GDALClose(out);
  if (!ok) {
    *error = std::string("KMZ: ") + CPLGetLastErrorMsg();
    std::remove(part.c_str());
    return false;
  }
  return RenameOver(part, kmz, error);
}

namespace {

fs::path TilePath(const std::string& dir, int z, int tx, int ty) {
  return fs::path(dir) / std::to_string(z) / std::to_string(tx) / (std::to_string(ty) + ".png");
}

// Local pyramid: at max_zoom one tile pixel is one mosaic pixel; zoom 0 holds the whole mosaic in one tile.
bool WriteLocalTiles(GDALDataset* src, const std::string& dir, TileSet* set, std::string* error) {
  const int W = src->GetRasterXSize();
  const int H = src->GetRasterYSize();
  cv::Mat tile(kTile, kTile, CV_8UC4);
  set->max_zoom = static_cast<int>(Log2Ceil(static_cast<double>(std::max(W, H)) / kTile));
  set->min_zoom = 0;
  const double s = std::ldexp(1.0, set->max_zoom);
  set->west = 0;
  set->east = W / s;
  set->north = 0;
  set->south = -H / s;
  for (int z = set->min_zoom; z <= set->max_zoom; ++z) {
    const int f = 1 << (set->max_zoom - z);
    const int span = kTile * f;
    for (int ty = 0; ty * span < H; ++ty)
      for (int tx = 0; tx * span < W; ++tx) {
        tile.setTo(cv::Scalar::all(0));
        const int x0 = tx * span, y0 = ty * span;
        const int w = std::min(span, W - x0), h = std::min(span, H - y0);
        const cv::Rect at(0, 0, std::max(1, (w + f - 1) / f), std::max(1, (h + f - 1) / f));
        if (!ReadBgra(src, x0, y0, w, h, &tile, at)) {
          *error = std::string("tiles: ") + CPLGetLastErrorMsg();
          return false;
        }
        bool written = false;
        if (!SaveTile(tile, TilePath(dir, z, tx, ty), &written, error)) return false;
        (written ? set->tiles : set->tiles_empty)++;
      }
  }
  return true;
}

// The mosaic's extent in EPSG:3857 metres.
struct MercatorBox {
  double x_min = 0, x_max = 0, y_min = 0, y_max = 0;
};

// The mosaic's outline (densified edges) in EPSG:3857 and in lat/lon: the box, and the set's bounds in degrees.
bool MercatorOutline(GDALDataset* src, const std::string& tif, MercatorBox* box, TileSet* set, std::string* error) {
  double gt[6];
  const OGRSpatialReference* srs = src->GetSpatialRef();
  if (src->GetGeoTransform(gt) != CE_None || srs == nullptr) {
    *error = "tiles: " + tif + " is not georeferenced";
    return false;
  }
  OGRSpatialReference merc, wgs;
  merc.importFromEPSG(3857);
  wgs.SetWellKnownGeogCS("WGS84");
  merc.SetAxisMappingStrategy(OAMS_TRADITIONAL_GIS_ORDER);
  wgs.SetAxisMappingStrategy(OAMS_TRADITIONAL_GIS_ORDER);
  OGRSpatialReference source(*srs);
  source.SetAxisMappingStrategy(OAMS_TRADITIONAL_GIS_ORDER);
  std::unique_ptr<OGRCoordinateTransformation> to_merc(OGRCreateCoordinateTransformation(&source, &merc));
  std::unique_ptr<OGRCoordinateTransformation> to_wgs(OGRCreateCoordinateTransformation(&source, &wgs));
  if (!to_merc || !to_wgs) {
    *error = "tiles: no transformation to EPSG:3857";
    return false;
  }
  std::vector<double> xs, ys;
  for (int k = 0; k <= 16; ++k) {
    const double t = k / 16.0;
    const double w = src->GetRasterXSize(), h = src->GetRasterYSize();
    const double edge[4][2] = {{t * w, 0}, {t * w, h}, {0, t * h}, {w, t * h}};
    for (const auto& e : edge) {
      xs.push_back(gt[0] + e[0] * gt[1] + e[1] * gt[2]);
      ys.push_back(gt[3] + e[0] * gt[4] + e[1] * gt[5]);
    }
  }
  std::vector<double> mx(xs), my(ys), lx(xs), ly(ys);
  if (!to_merc->Transform(static_cast<int>(mx.size()), mx.data(), my.data()) ||
      !to_wgs->Transform(static_cast<int>(lx.size()), lx.data(), ly.data())) {
    *error = "tiles: PROJ failed on the mosaic's outline";
    return false;
  }
  box->x_min = *std::min_element(mx.begin(), mx.end());
  box->x_max = *std::max_element(mx.begin(), mx.end());
  box->y_min = *std::min_element(my.begin(), my.end());
  box->y_max = *std::max_element(my.begin(), my.end());
  set->west = *std::min_element(lx.begin(), lx.end());
  set->east = *std::max_element(lx.begin(), lx.end());
  set->south = *std::min_element(ly.begin(), ly.end());
  set->north = *std::max_element(ly.begin(), ly.end());
  return true;
}

constexpr double kWebMercatorWorld = 2 * kWebMercatorHalf;

// The XYZ tiles [x0, x1] x [y0, y1] of zoom z that cover the box.
struct TileRange {
  int x0 = 0, x1 = 0, y0 = 0, y1 = 0;
  TileRange(const MercatorBox& b, int z) {
    const double span = kWebMercatorWorld / std::ldexp(1.0, z);
    const int n = 1 << z;
    x0 = std::clamp(static_cast<int>(std::floor((b.x_min + kWebMercatorHalf) / span)), 0, n - 1);
    x1 = std::clamp(static_cast<int>(std::floor((b.x_max + kWebMercatorHalf) / span)), 0, n - 1);
    y0 = std::clamp(static_cast<int>(std::floor((kWebMercatorHalf - b.y_max) / span)), 0, n - 1);
    y1 = std::clamp(static_cast<int>(std::floor((kWebMercatorHalf - b.y_min) / span)), 0, n - 1);
  }
};

// Finest zoom: a tile pixel on the ground no larger than the GSD; coarsest: the whole mosaic in one tile. The finest
// zooms are dropped while the pyramid holds more than max_tiles.
void ChooseZooms(const MercatorBox& box, double gsd_m, const TileOptions& options, TileSet* set) {
  const double lat = 0.5 * (set->south + set->north) * M_PI / 180.0;
  const double world = kWebMercatorWorld;
  set->max_zoom = std::clamp(static_cast<int>(Log2Ceil(world * std::cos(lat) / (kTile * gsd_m))), 0, 24);
  const double extent = std::max(box.x_max - box.x_min, box.y_max - box.y_min);
  set->min_zoom = std::clamp(static_cast<int>(std::floor(std::log2(world / extent))), 0, set->max_zoom);
  for (;;) {
    long total = 0;
    for (int z = set->min_zoom; z <= set->max_zoom; ++z) {
      const TileRange r(box, z);
      total += static_cast<long>(r.x1 - r.x0 + 1) * (r.y1 - r.y0 + 1);
    }
    if (total <= options.max_tiles || set->max_zoom == set->min_zoom) break;
    --set->max_zoom;
  }
  // Every zoom the live pyramid had stays (a client keeps its URLs), whatever the cap.
  if (options.keep_max_zoom >= 0) {
    set->max_zoom = std::max(set->max_zoom, options.keep_max_zoom);
    set->min_zoom = std::clamp(std::min(set->min_zoom, options.keep_min_zoom), 0, set->max_zoom);
  }
}

// Warps the mosaic into one EPSG:3857 tile (in memory) and reads it as BGRA.
bool WarpTile(GDALDatasetH src_h, GDALWarpAppOptions* wopts, const std::string& merc_wkt, int z, int tx, int ty,
              cv::Mat* tile, std::string* error) {
  const double span = kWebMercatorWorld / std::ldexp(1.0, z);
  GDALDriver* mem = GetGDALDriverManager()->GetDriverByName("MEM");
  DatasetPtr dst(mem->Create("", kTile, kTile, 4, GDT_Byte, nullptr));
  double dgt[6] = {-kWebMercatorHalf + tx * span, span / kTile, 0, kWebMercatorHalf - ty * span, 0, -span / kTile};
  dst->SetGeoTransform(dgt);
  dst->SetProjection(merc_wkt.c_str());
  dst->GetRasterBand(4)->SetColorInterpretation(GCI_AlphaBand);
  int usage = 0;
  GDALDatasetH dst_h = GDALDataset::ToHandle(dst.get());
  if (GDALWarp(nullptr, dst_h, 1, &src_h, wopts, &usage) == nullptr || usage != 0) {
    *error = std::string("tiles: warp failed: ") + CPLGetLastErrorMsg();
    return false;
  }
  tile->setTo(cv::Scalar::all(0));
  if (!ReadBgra(dst.get(), 0, 0, kTile, kTile, tile, cv::Rect(0, 0, kTile, kTile))) {
    *error = std::string("tiles: ") + CPLGetLastErrorMsg();
    return false;
  }
  return true;
}

bool WriteMercatorTiles(GDALDataset* src, const std::string& dir, const MercatorBox& box, TileSet* set,
                        std::string* error) {
  cv::Mat tile(kTile, kTile, CV_8UC4);
  const std::string merc_wkt = EpsgWkt(3857);
  char** wargs = nullptr;
  for (const char* a : {"-r", "bilinear", "-dstalpha", "-wm", "32", "-q"}) wargs = CSLAddString(wargs, a);
  GDALWarpAppOptions* wopts = GDALWarpAppOptionsNew(wargs, nullptr);
  CSLDestroy(wargs);
  GDALDatasetH src_h = GDALDataset::ToHandle(src);
  bool ok = true;
  for (int z = set->min_zoom; z <= set->max_zoom && ok; ++z) {
    const TileRange r(box, z);
    for (int ty = r.y0; ty <= r.y1 && ok; ++ty)
      for (int tx = r.x0; tx <= r.x1 && ok; ++tx) {
        ok = WarpTile(src_h, wopts, merc_wkt, z, tx, ty, &tile, error);
        if (!ok) break;
        bool written = false;
        ok = SaveTile(tile, TilePath(dir, z, tx, ty), &written, error);
        (written ? set->tiles : set->tiles_empty)++;
      }
  }
  GDALWarpAppOptionsFree(wopts);
  return ok;
}

}  // namespace

bool WriteTiles(const std::string& tif, const std::string& dir, bool geographic, double gsd_m,
                const TileOptions& options, TileSet* set, std::string* error) {
  const auto t0 = std::chrono::steady_clock::now();
  auto src = OpenRead(tif, error);
  if (!src) return false;
  std::error_code ec;
  fs::remove_all(dir, ec);
  *set = TileSet{};
  set->geographic = geographic;
  bool ok = false;
  if (!geographic) {
    ok = WriteLocalTiles(src.get(), dir, set, error);
    if (!ok) return false;
  } else {
    MercatorBox box;
    if (!MercatorOutline(src.get(), tif, &box, set, error)) return false;
    ChooseZooms(box, gsd_m, options, set);
    ok = WriteMercatorTiles(src.get(), dir, box, set, error);
  }
  set->ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  return ok;
}

namespace {

// Mosaic pixels -> page coordinates [x, y] of GeoJSON: [lon, lat] (georeferenced) or CRS.Simple [x, -y] / 2^zmax.
bool ToPage(const std::vector<Vec2>& px, const TileSet& tiles, const GeorefFit& fit, std::vector<Vec2>* out,
            std::string* error) {
  out->clear();
  if (!tiles.geographic) {
    const double s = std::ldexp(1.0, tiles.max_zoom);
    for (const auto& p : px) out->emplace_back((p.x() + 0.5) / s, -(p.y() + 0.5) / s);
    return true;
  }
  std::vector<Vec2> world;
  for (const auto& p : px) world.push_back(fit.world_from_pixel.leftCols<2>() * p + fit.world_from_pixel.col(2));
  std::vector<double> lat, lon;
  if (!ProjectedToLatLon(fit.epsg, world, &lat, &lon, error)) return false;
  for (size_t i = 0; i < lat.size(); ++i) out->emplace_back(lon[i], lat[i]);
  return true;
}

nlohmann::json Coord(const Vec2& p) {
  return nlohmann::json::array({p.x(), p.y()});
}

const char* kPage = R"HTML(<!DOCTYPE html>
<html><head><meta charset="utf-8"><title>uavmosaic: %TITLE%</title>
<meta name="viewport" content="width=device-width, initial-scale=1">
<link rel="stylesheet" href="leaflet/leaflet.css">
<script src="leaflet/leaflet.js"></script>
<style>html,body,#map{margin:0;height:100%;background:#000}
#info{position:absolute;z-index:1000;left:50px;top:8px;background:rgba(255,255,255,.85);padding:3px 8px;
font:12px sans-serif;border-radius:4px}</style></head>
<body><div id="map"></div><div id="info"></div>
<script src="map_data.js"></script>
<script>
var D = UAVM_MAP;
var local = !D.geographic;
var map = L.map('map', local ? {crs: L.CRS.Simple, minZoom: -2} : {});
map.getContainer().style.background = '#000';
var b = L.latLngBounds([D.bounds.south, D.bounds.west], [D.bounds.north, D.bounds.east]);
var mosaic = L.tileLayer('tiles/{z}/{x}/{y}.png', {minNativeZoom: D.min_zoom, maxNativeZoom: D.max_zoom,
  minZoom: local ? -2 : Math.max(0, D.min_zoom - 2), maxZoom: D.max_zoom + 3, bounds: b, noWrap: true,
  attribution: 'uavmosaic'}).addTo(map);
var fp = L.geoJSON(D.footprints, {style: function (f) {
  return {color: f.properties.registered ? '#ffd400' : '#ff3030', weight: 1, fill: false}; },
  onEachFeature: function (f, l) { l.bindTooltip(f.properties.name); }});
var graph = L.geoJSON(D.graph, {style: function (f) {
  return {color: f.properties.used ? '#00e0ff' : '#ff00ff', weight: 1.5}; }});
L.control.layers(null, {'Mosaic': mosaic, 'Frame footprints': fp, 'Match graph': graph},
  {collapsed: false}).addTo(map);
map.fitBounds(b);
document.getElementById('info').innerHTML = D.label;
</script></body></html>
)HTML";

}  // namespace

bool WriteWebPage(const std::string& out_dir, const std::string& leaflet_dir, const TileSet& tiles,
                  const GeorefFit& fit, const std::vector<MapFrame>& frames, const std::vector<MapEdge>& edges,
                  std::string* error) {
  std::error_code ec;
  const fs::path leaflet = fs::path(out_dir) / "leaflet";
  fs::create_directories(leaflet, ec);
  for (const char* f : {"leaflet.js", "leaflet.css"}) {
    fs::copy_file(fs::path(leaflet_dir) / f, leaflet / f, fs::copy_options::overwrite_existing, ec);
    if (ec) {
      *error = "cannot copy Leaflet from " + leaflet_dir + " (libjs-leaflet): " + ec.message();
      return false;
    }
  }
  if (fs::is_directory(fs::path(leaflet_dir) / "images"))
    fs::copy(fs::path(leaflet_dir) / "images", leaflet / "images",
             fs::copy_options::recursive | fs::copy_options::overwrite_existing, ec);

  // Footprints (each frame's outline) and the match graph (frame centre to frame centre).
  nlohmann::json footprints = {{"type", "FeatureCollection"}, {"features", nlohmann::json::array()}};
  nlohmann::json graph = {{"type", "FeatureCollection"}, {"features", nlohmann::json::array()}};
  std::vector<Vec2> centre_px(frames.size(), Vec2::Zero());
  std::vector<bool> has_centre(frames.size(), false);
  std::unordered_map<int, size_t> by_id;
  for (size_t i = 0; i < frames.size(); ++i) {
    const MapFrame& f = frames[i];
    by_id[f.id] = i;
    if (!f.registered) continue;
    std::vector<Vec2> ring;
    for (int k = 0; k <= 40; ++k) {  // densified: a projective outline is straight, but the map may bend it
      const int side = (k / 10) % 4;
      const double t = (k % 10) / 10.0;
      const double w = f.width - 1, h = f.height - 1;
      const Vec2 p = side == 0   ? Vec2(t * w, 0)
                     : side == 1 ? Vec2(w, t * h)
                     : side == 2 ? Vec2(w - t * w, h)
                                 : Vec2(0, h - t * h);
      ring.push_back(Apply(f.mosaic_from_frame, p));
    }
    std::vector<Vec2> page;
    if (!ToPage(ring, tiles, fit, &page, error)) return false;
    nlohmann::json coords = nlohmann::json::array();
    for (const auto& p : page) coords.push_back(Coord(p));
    footprints["features"].push_back(
        {{"type", "Feature"},
         {"properties", {{"id", f.id}, {"name", f.name}, {"registered", f.registered}}},
         {"geometry", {{"type", "Polygon"}, {"coordinates", nlohmann::json::array({coords})}}}});
    centre_px[i] = Apply(f.mosaic_from_frame, Vec2(0.5 * (f.width - 1), 0.5 * (f.height - 1)));
    has_centre[i] = true;
  }
  std::vector<Vec2> centres;
  if (!ToPage(centre_px, tiles, fit, &centres, error)) return false;
  for (const MapEdge& e : edges) {
    if (by_id.count(e.src) == 0 || by_id.count(e.tgt) == 0) continue;
    const size_t a = by_id[e.src], b = by_id[e.tgt];
    if (!has_centre[a] || !has_centre[b]) continue;
    graph["features"].push_back(
        {{"type", "Feature"},
         {"properties", {{"src", e.src}, {"tgt", e.tgt}, {"inliers", e.inliers}, {"used", e.used}}},
         {"geometry", {{"type", "LineString"}, {"coordinates", {Coord(centres[a]), Coord(centres[b])}}}}});
  }
  std::string label;
  if (tiles.geographic) {
    char buf[256];
    std::snprintf(buf, sizeof(buf),
                  "uavmosaic &middot; EPSG:%d (%s fit, RMS %.1f m, %d/%d frames) &middot; GSD %.1f cm/px", fit.epsg,
                  fit.model.c_str(), fit.rms_m, fit.inliers, fit.points, fit.gsd_m * 100);
    label = buf;
  } else {
    label = "<b>LOCAL FRAME &ndash; not georeferenced</b> (no GPS): units are mosaic pixels";
  }
  nlohmann::json data = {
      {"geographic", tiles.geographic},
      {"min_zoom", tiles.min_zoom},
      {"max_zoom", tiles.max_zoom},
      {"bounds", {{"west", tiles.west}, {"south", tiles.south}, {"east", tiles.east}, {"north", tiles.north}}},
      {"crs", tiles.geographic ? "EPSG:" + std::to_string(fit.epsg) : "local"},
      {"label", label},
      {"footprints", footprints},
      {"graph", graph}};
  const auto write = [&](const std::string& name, const std::string& text) {
    const fs::path p = fs::path(out_dir) / name;
    std::ofstream out(p.string() + ".part", std::ios::binary);
    out << text;
    out.close();
    if (!out) {
      *error = "cannot write " + p.string();
      return false;
    }
    return RenameOver(p.string() + ".part", p.string(), error);
  };
  std::string page = kPage;
  const std::string title = tiles.geographic ? "mosaic map" : "mosaic (local frame)";
  page.replace(page.find("%TITLE%"), 7, title);
  // Data as a script, not fetched: browsers refuse fetch() from file:// pages.
  return write("footprints.geojson", footprints.dump()) && write("graph.geojson", graph.dump()) &&
         write("map_data.js", "var UAVM_MAP = " + data.dump() + ";\n") && write("index.html", page);
}

}  // namespace uavm
