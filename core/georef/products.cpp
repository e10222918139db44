#include "core/georef/products.h"

#include <cpl_string.h>
#include <gdal_priv.h>
#include <ogr_spatialref.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <memory>
#include <mutex>
#include <nlohmann/json.hpp>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "core/imageio/png_writer.h"
#include "core/tiles/web_mercator.h"
#include "core/util/hilbert.h"
#include "core/util/parallel.h"

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

// The tiles' PNG encoder: libdeflate at level 1 (core/imageio/png_writer.h). brighton_beach's 488 tiles, one thread:
// 635 ms and 47.8 MB, against 1121 ms and 53.4 MB for OpenCV's defaults (libpng, zlib level 1, RLE strategy, SUB
// filter); libdeflate's level 2 took 1091 ms for 47.5 MB, level 6 2460 ms for 46.5 MB. One encoder per worker thread.
constexpr int kPngLevel = 1;

// Writes one BGRA tile as PNG unless it is fully transparent; through a temporary file and a rename, so that the tile
// server never sends half a tile. Returns false on an I/O error.
bool SaveTile(const cv::Mat& bgra, const fs::path& path, bool* written, std::string* error) {
  cv::Mat alpha;
  cv::extractChannel(bgra, alpha, 3);
  *written = cv::countNonZero(alpha) > 0;
  if (!*written) return true;
  std::error_code ec;
  fs::create_directories(path.parent_path(), ec);
  if (ec && fs::is_directory(path.parent_path())) ec.clear();  // made by the other worker meanwhile
  thread_local PngWriter writer(kPngLevel);
  std::vector<uint8_t> png;
  if (ec || !writer.Encode(bgra, &png)) {
    *error = "cannot write " + path.string();
    return false;
  }
  const fs::path part = path.string() + ".part";
  std::ofstream out(part, std::ios::binary);
  out.write(reinterpret_cast<const char*>(png.data()), static_cast<std::streamsize>(png.size()));
  out.close();
  if (!out) {
    *error = "cannot write " + part.string();
    return false;
  }
  return RenameOver(part.string(), path.string(), error);
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
  // Two threads compress; measured less CPU in all than one (GDAL 3.6: 1.3 s user + 0.3 s sys against 1.6 + 0.7 on
  // brighton_beach's mosaic), so the COG is cheaper even while the tiles take the other core.
  opts = CSLSetNameValue(opts, "NUM_THREADS", "2");
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

// One XYZ tile and where its 3x3 grid of points (tile pixel corners 0, 128 and 256 in each axis) lies in the mosaic, in
// GDAL pixel coordinates (integers are pixel corners).
struct TileJob {
  int z = 0, x = 0, y = 0;
  std::array<cv::Point2d, 9> mosaic;
};

constexpr int kGridStep = kTile / 2;

// Every tile of every zoom with its grid located in the mosaic: one PROJ transformation (EPSG:3857 -> the mosaic's
// CRS) for all points, then the inverse geotransform. Done before the workers start: a PROJ object must not be shared
// between threads, and one call for all tiles costs less than building a transformation per worker.
bool LocateTiles(GDALDataset* src, const MercatorBox& box, const TileSet& set, std::vector<TileJob>* jobs,
                 std::string* error) {
  double gt[6], inv[6];
  if (src->GetGeoTransform(gt) != CE_None || !GDALInvGeoTransform(gt, inv) || src->GetSpatialRef() == nullptr) {
    *error = "tiles: the mosaic is not georeferenced";
    return false;
  }
  OGRSpatialReference merc, target(*src->GetSpatialRef());
  merc.importFromEPSG(3857);
  merc.SetAxisMappingStrategy(OAMS_TRADITIONAL_GIS_ORDER);
  target.SetAxisMappingStrategy(OAMS_TRADITIONAL_GIS_ORDER);
  std::unique_ptr<OGRCoordinateTransformation> to_src(OGRCreateCoordinateTransformation(&merc, &target));
  if (!to_src) {
    *error = "tiles: no transformation from EPSG:3857";
    return false;
  }
  std::vector<double> xs, ys;
  for (int z = set.min_zoom; z <= set.max_zoom; ++z) {
    const TileRange r(box, z);
    // Along a Hilbert curve over the zoom's range: the workers' consecutive tiles read neighbouring windows of the
    // mosaic, whose blocks GDAL's small cache (shared with the COG copy) then still holds. In rows, each row crossed
    // the rotated mosaic and the blocks were decompressed again for the next (products 1.8-2.0 -> 1.7-1.8 s on
    // caliterra, 2.6-3.1 -> 2.3-2.5 s on brighton_beach).
    for (const auto& [cx, cy] : CellsAlongHilbertCurve(r.x1 - r.x0 + 1, r.y1 - r.y0 + 1)) {
      const int tx = r.x0 + cx;
      const int ty = r.y0 + cy;
      jobs->push_back({z, tx, ty, {}});
      for (int k = 0; k < 9; ++k) {
        const Vec2 m =
            MercatorMetresFromPixel(Vec2(tx * kTile + (k % 3) * kGridStep, ty * kTile + (k / 3) * kGridStep), z);
        xs.push_back(m.x());
        ys.push_back(m.y());
      }
    }
  }
  if (!to_src->Transform(static_cast<int>(xs.size()), xs.data(), ys.data())) {
    *error = "tiles: PROJ failed on the tile grid";
    return false;
  }
  for (size_t i = 0; i < xs.size(); ++i)
    (*jobs)[i / 9].mosaic[i % 9] = {inv[0] + inv[1] * xs[i] + inv[2] * ys[i], inv[3] + inv[4] * xs[i] + inv[5] * ys[i]};
  return true;
}

// The level to read a tile from: the coarsest overview whose pixel is still no larger than the tile's (`scale` mosaic
// pixels); -1 for full resolution. Reading full resolution for a coarse zoom is what made the tiles slow.
int PickLevel(GDALRasterBand* band, double scale) {
  int level = -1;
  double best = 1;
  for (int k = 0; k < band->GetOverviewCount(); ++k) {
    GDALRasterBand* ov = band->GetOverview(k);
    if (ov == nullptr || ov->GetXSize() <= 0) continue;
    const double f = static_cast<double>(band->GetXSize()) / ov->GetXSize();
    if (f <= scale * (1 + 1e-9) && f > best) {
      best = f;
      level = k;
    }
  }
  return level;
}

// Reads `win` of `level` as BGRA (bands 3, 2, 1, 4) into `out` (of the window's size: no resampling).
bool ReadLevel(GDALDataset* ds, int level, const cv::Rect& win, cv::Mat* out) {
  const int bands[4] = {3, 2, 1, 4};
  for (int c = 0; c < 4; ++c) {
    GDALRasterBand* b = ds->GetRasterBand(bands[c]);
    if (b != nullptr && level >= 0) b = b->GetOverview(level);
    if (b == nullptr || b->RasterIO(GF_Read, win.x, win.y, win.width, win.height, out->data + c, out->cols, out->rows,
                                    GDT_Byte, 4, static_cast<GSpacing>(out->step[0]), nullptr) != CE_None)
      return false;
  }
  return true;
}

// Colours weighted by alpha around the interpolation (and divided again after), so that the transparent pixels next to
// the flown area do not darken its edge (GDAL's warper weights by the source alpha likewise).
void Premultiply(cv::Mat* bgra, bool inverse) {
  for (int r = 0; r < bgra->rows; ++r) {
    auto* p = bgra->ptr<uchar>(r);
    for (int c = 0; c < bgra->cols; ++c, p += 4) {
      const int a = p[3];
      if (a == 255 || (inverse && a == 0)) continue;
      for (int k = 0; k < 3; ++k)
        p[k] = static_cast<uchar>(inverse ? std::min(255, (p[k] * 255 + a / 2) / a) : (p[k] * a + 127) / 255);
    }
  }
}

// A 3x3 matrix as a cv::Mat, for composing with findHomography's result.
cv::Mat Affine(double sx, double sy, double tx, double ty) {
  return (cv::Mat_<double>(3, 3) << sx, 0, tx, 0, sy, ty, 0, 0, 1);
}

// The homography from tile pixel corners to mosaic pixel corners (relative to the tile's first grid point, `origin`:
// findHomography works in single precision), the tile's bounding box in the mosaic and its scale (mosaic pixels per
// tile pixel). A homography from 9 projected points: the projection's bending across one tile is far below a pixel at
// the zooms of a drone map.
bool FitTile(const TileJob& job, cv::Mat* h, cv::Rect2d* bounds, double* scale) {
  const cv::Point2d o = job.mosaic[0];
  std::vector<cv::Point2f> from, to;
  cv::Point2d lo(1e300, 1e300), hi(-1e300, -1e300);
  for (size_t k = 0; k < job.mosaic.size(); ++k) {
    const cv::Point2d& m = job.mosaic[k];
    from.emplace_back(static_cast<float>(kGridStep * static_cast<int>(k % 3)),
                      static_cast<float>(kGridStep * static_cast<int>(k / 3)));
    to.emplace_back(static_cast<float>(m.x - o.x), static_cast<float>(m.y - o.y));
    lo = {std::min(lo.x, m.x), std::min(lo.y, m.y)};
    hi = {std::max(hi.x, m.x), std::max(hi.y, m.y)};
  }
  *bounds = cv::Rect2d(lo, hi);
  // The area of the tile's outline (corners 0, 2, 8, 6 of the grid), shoelace.
  const std::array<cv::Point2d, 4> q = {job.mosaic[0], job.mosaic[2], job.mosaic[8], job.mosaic[6]};
  double area = 0;
  for (size_t k = 0; k < 4; ++k) area += q[k].cross(q[(k + 1) % 4]);
  *scale = std::sqrt(std::abs(area) / 2) / kTile;
  *h = cv::findHomography(from, to, 0);
  return !h->empty();
}

// Draws one tile (BGRA; transparent where the mosaic has nothing): the window it covers read from the level just
// finer than the tile, averaged down to about the tile's scale, then warped (bilinear).
bool RenderTile(GDALDataset* ds, std::mutex* ds_mutex, const TileJob& job, cv::Mat* tile, std::string* error) {
  tile->setTo(cv::Scalar::all(0));
  cv::Mat h;
  cv::Rect2d b;
  double scale = 1;
  if (!FitTile(job, &h, &b, &scale)) {
    *error = "tiles: no homography for tile " + std::to_string(job.z) + "/" + std::to_string(job.x);
    return false;
  }
  const int W = ds->GetRasterXSize(), H = ds->GetRasterYSize();
  if (b.br().x <= 0 || b.br().y <= 0 || b.x >= W || b.y >= H) return true;  // outside the mosaic
  std::unique_lock lock(*ds_mutex);
  GDALRasterBand* band = ds->GetRasterBand(1);
  const int level = PickLevel(band, scale);
  GDALRasterBand* lb = level < 0 ? band : band->GetOverview(level);
  const int lw = lb->GetXSize(), lh = lb->GetYSize();
  const double fx = static_cast<double>(lw) / W, fy = static_cast<double>(lh) / H;
  const int x0 = std::clamp(static_cast<int>(std::floor(b.x * fx)) - 1, 0, lw);
  const int y0 = std::clamp(static_cast<int>(std::floor(b.y * fy)) - 1, 0, lh);
  const int x1 = std::clamp(static_cast<int>(std::ceil(b.br().x * fx)) + 1, 0, lw);
  const int y1 = std::clamp(static_cast<int>(std::ceil(b.br().y * fy)) + 1, 0, lh);
  if (x1 <= x0 || y1 <= y0) return true;
  const cv::Rect win(x0, y0, x1 - x0, y1 - y0);
  cv::Mat src(win.size(), CV_8UC4);
  if (!ReadLevel(ds, level, win, &src)) {
    *error = std::string("tiles: ") + CPLGetLastErrorMsg();
    return false;
  }
  lock.unlock();
  Premultiply(&src, false);
  // The rest of the scale (the level is up to 2x finer than the tile): an area average, so that the bilinear warp
  // samples about 1:1 as GDALWarp's widened kernel did. Not GDAL's resampling while reading: on a full-resolution band
  // it switches to an overview of its own (up to 1.2x coarser than asked), rounding the window to that overview's
  // pixels (tiles shifted by up to a pixel).
  const double rest = scale * fx;
  if (rest > 1.05)
    cv::resize(src, src,
               cv::Size(std::max(1, static_cast<int>(std::ceil(win.width / rest))),
                        std::max(1, static_cast<int>(std::ceil(win.height / rest)))),
               0, 0, cv::INTER_AREA);
  // Tile pixel centres -> tile corners -> mosaic (relative to grid point 0) -> level -> window -> buffer centres.
  const cv::Point2d o = job.mosaic[0];
  const cv::Mat m =
      Affine(static_cast<double>(src.cols) / win.width, static_cast<double>(src.rows) / win.height, -0.5, -0.5) *
      Affine(fx, fy, fx * o.x - x0, fy * o.y - y0) * h * Affine(1, 1, 0.5, 0.5);
  cv::warpPerspective(src, *tile, m, tile->size(), cv::INTER_LINEAR | cv::WARP_INVERSE_MAP, cv::BORDER_CONSTANT,
                      cv::Scalar::all(0));
  Premultiply(tile, true);
  return true;
}

constexpr int kTileWorkers = 2;

bool WriteMercatorTiles(GDALDataset* src, const std::string& dir, const MercatorBox& box, TileSet* set,
                        std::string* error) {
  std::vector<TileJob> jobs;
  if (!LocateTiles(src, box, *set, &jobs, error)) return false;
  // One handle for both workers, its reads in turn (GDAL datasets are not thread-safe): a block cache entry belongs to
  // a handle, and with one handle per worker each block was decompressed by both (brighton_beach: 1014 block
  // decompressions for 178 blocks; the warps and the PNGs, most of a tile, still run side by side).
  std::mutex src_mutex;
  struct Result {
    bool ok = false, written = false;
    std::string error;
  };
  std::vector<Result> results(jobs.size());
  std::atomic<size_t> next{0};
  ParallelFor(kTileWorkers, kTileWorkers, [&](size_t) {
    cv::Mat tile(kTile, kTile, CV_8UC4);
    for (size_t i = next.fetch_add(1); i < jobs.size(); i = next.fetch_add(1)) {
      const TileJob& j = jobs[i];
      Result& r = results[i];
      r.ok = RenderTile(src, &src_mutex, j, &tile, &r.error) &&
             SaveTile(tile, TilePath(dir, j.z, j.x, j.y), &r.written, &r.error);
    }
  });
  for (const Result& r : results) {
    if (!r.ok) {
      *error = r.error;
      return false;
    }
    (r.written ? set->tiles : set->tiles_empty)++;
  }
  return true;
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
