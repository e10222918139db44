#include "core/sfm/ortho_files.h"

#include <gdal_priv.h>
#include <gdal_utils.h>

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "core/georef/products.h"
#include "core/mosaic/gdal_writer.h"

namespace uavm::sfm {

nlohmann::json OrthoFilesReport::ToJson() const {
  nlohmann::json js = ortho.ToJson();
  js["mbtiles_written"] = mbtiles_written;
  js["web_tiles"] = web_tiles;
  js["web_zoom"] = {web_min_zoom, web_max_zoom};
  js["warnings"] = warnings;
  js["write_seconds"] = write_seconds;
  return js;
}

namespace {

// A GDAL utility's argument list (gdal_translate / gdalwarp words) as the C API takes it.
class GdalArgs {
 public:
  explicit GdalArgs(const std::vector<std::string>& words) {
    for (const auto& w : words) list_ = CSLAddString(list_, w.c_str());
  }
  ~GdalArgs() { CSLDestroy(list_); }
  GdalArgs(const GdalArgs&) = delete;
  GdalArgs& operator=(const GdalArgs&) = delete;
  [[nodiscard]] char** get() const { return list_; }

 private:
  char** list_ = nullptr;
};

std::string GdalError(const std::string& what) {
  const char* msg = CPLGetLastErrorMsg();
  return what + (msg != nullptr && *msg != '\0' ? std::string(": ") + msg : std::string());
}

// gdal_translate `src` to `dst` (written as dst.part, renamed when complete).
bool Translate(GDALDatasetH src, const std::string& dst, const std::vector<std::string>& words, std::string* error) {
  const GdalArgs args(words);
  GDALTranslateOptions* options = GDALTranslateOptionsNew(args.get(), nullptr);
  int usage_error = 0;
  const std::string part = dst + ".part";
  GDALDatasetH out = GDALTranslate(part.c_str(), src, options, &usage_error);
  GDALTranslateOptionsFree(options);
  if (out == nullptr) {
    *error = GdalError("cannot write " + dst);
    std::remove(part.c_str());
    return false;
  }
  GDALClose(out);
  std::error_code ec;
  std::filesystem::rename(part, dst, ec);
  if (ec) {
    *error = "cannot rename " + part + ": " + ec.message();
    return false;
  }
  return true;
}

// The whole map reduced to `long_side`, averaged, RGBA (the alpha band is the coverage).
bool WriteQuicklook(GDALDatasetH src, const std::string& path, int long_side, std::string* error) {
  auto* ds = GDALDataset::FromHandle(src);
  const int w = ds->GetRasterXSize(), h = ds->GetRasterYSize();
  const double k = std::min(1.0, static_cast<double>(long_side) / std::max(w, h));
  const cv::Size size(std::max(1, static_cast<int>(w * k)), std::max(1, static_cast<int>(h * k)));
  cv::Mat rgba(size, CV_8UC4);
  GDALRasterIOExtraArg extra;
  INIT_RASTERIO_EXTRA_ARG(extra);
  extra.eResampleAlg = GRIORA_Average;
  int bands[4] = {1, 2, 3, 4};
  if (ds->RasterIO(GF_Read, 0, 0, w, h, rgba.data, size.width, size.height, GDT_Byte, 4, bands, 4,
                   static_cast<GSpacing>(rgba.step[0]), 1, &extra) != CE_None) {
    *error = GdalError("cannot read the orthophoto for its quick-look");
    return false;
  }
  cv::Mat bgra;
  cv::cvtColor(rgba, bgra, cv::COLOR_RGBA2BGRA);
  if (!cv::imwrite(path, bgra, {cv::IMWRITE_PNG_COMPRESSION, 6})) {
    *error = "cannot write " + path;
    return false;
  }
  return true;
}

// Web Mercator tiles in an MBTiles file, with zoom levels down to one tile (gdaladdo on the package).
// Web Mercator as a virtual warp of `src`, its pixels no finer than `min_resolution` (metres of EPSG:3857).
GDALDatasetH WarpToMercator(GDALDatasetH src, double min_resolution) {
  std::vector<std::string> words = {"-of", "VRT", "-t_srs", "EPSG:3857", "-r", "bilinear"};
  if (min_resolution > 0.0) {
    words.insert(words.end(), {"-tr", std::to_string(min_resolution), std::to_string(min_resolution), "-r", "average"});
  }
  const GdalArgs warp_args(words);
  GDALWarpAppOptions* warp = GDALWarpAppOptionsNew(warp_args.get(), nullptr);
  int usage_error = 0;
  GDALDatasetH mercator = GDALWarp("", nullptr, 1, &src, warp, &usage_error);
  GDALWarpAppOptionsFree(warp);
  return mercator;
}

bool WriteMbtiles(GDALDatasetH src, const std::string& path, std::string* error) {
  GDALDatasetH mercator = WarpToMercator(src, 0.0);
  // GDAL's MBTiles driver stops at zoom 22 (3.7 cm at the equator): a finer map is written at zoom 22.
  constexpr double kZoom22 = 2.0 * 20037508.342789244 / 256.0 / (1 << 22);
  double gt[6] = {0, 0, 0, 0, 0, 0};
  if (mercator != nullptr && GDALGetGeoTransform(mercator, gt) == CE_None && gt[1] < kZoom22) {
    GDALClose(mercator);
    mercator = WarpToMercator(src, kZoom22);
  }
  if (mercator == nullptr) {
    *error = GdalError("cannot reproject the orthophoto to Web Mercator");
    return false;
  }
  std::remove(path.c_str());  // the driver does not overwrite
  const bool ok =
      Translate(mercator, path, {"-of", "MBTILES", "-co", "TILE_FORMAT=PNG", "-co", "ZOOM_LEVEL_STRATEGY=AUTO"}, error);
  GDALClose(mercator);
  if (!ok) return false;
  GDALDatasetH tiles = GDALOpen(path.c_str(), GA_Update);
  if (tiles == nullptr) {
    *error = GdalError("cannot reopen " + path);
    return false;
  }
  std::vector<int> factors;
  for (int f = 2; std::max(GDALGetRasterXSize(tiles), GDALGetRasterYSize(tiles)) / f >= 256; f *= 2)
    factors.push_back(f);
  const bool built = factors.empty() || GDALBuildOverviews(tiles, "AVERAGE", static_cast<int>(factors.size()),
                                                           factors.data(), 0, nullptr, nullptr, nullptr) == CE_None;
  GDALClose(tiles);
  if (!built) *error = GdalError("cannot build the zoom levels of " + path);
  return built;
}

}  // namespace

bool WriteOrthophoto(const Reconstruction& rec, const std::vector<std::string>& image_paths, const cv::Mat1f& dsm,
                     const cv::Mat1f& terrain, const DsmGrid& dsm_grid, float nodata, const Eigen::Vector2d& offset,
                     const std::string& crs_wkt, const OrthoOptions& options, const OrthoFiles& files,
                     const OrthoFrameCorrection& correct, OrthoFilesReport* report, std::string* error) {
  *report = OrthoFilesReport{};
  const double gsd = options.gsd > 0.0 ? options.gsd : rec.MedianGsd();
  if (gsd <= 0.0 || image_paths.size() != rec.images.size()) {
    *error = "orthophoto: no ground sampling distance or no frame";
    return false;
  }
  const DsmGrid grid = OrthoGridOver(dsm_grid, gsd);
  if (static_cast<double>(grid.width) * grid.height > 4e9) {
    *error = "orthophoto: " + std::to_string(grid.width) + " x " + std::to_string(grid.height) + " pixels at GSD " +
             std::to_string(gsd) + " is too large; set a coarser --ortho-gsd";
    return false;
  }
  // The tiles in a tiled GeoTIFF, then the COG from it (the COG driver writes only by copying a whole dataset).
  const std::string tiles_path = files.cog + ".tiles.tif";
  {
    GdalTiffWriter writer;
    if (!writer.Open(tiles_path, cv::Size(grid.width, grid.height), 512, options.tile_size, false, 64, error))
      return false;
    writer.SetGeoreference({grid.x0 + offset.x(), gsd, 0.0, grid.y0 + offset.y(), 0.0, -gsd}, crs_wkt);
    const OrthoImageLoad load = [&](size_t i) {
      cv::Mat image = cv::imread(image_paths[i], cv::IMREAD_COLOR);
      const Camera& cam = rec.CameraOf(static_cast<int>(i));
      if (!image.empty() && (image.cols != cam.width || image.rows != cam.height)) {
        std::fprintf(stderr, "uavmosaic-ground: orthophoto: %s is %dx%d, its camera %dx%d: left out\n",
                     image_paths[i].c_str(), image.cols, image.rows, cam.width, cam.height);
        return cv::Mat();
      }
      if (!image.empty() && correct) correct(i, &image);
      return image;
    };
    const OrthoTileSink sink = [&](const cv::Mat& image, const cv::Mat& mask, cv::Point at, std::string* why) {
      return writer.Write(image, mask, at, why);
    };
    if (!MakeOrthophoto(rec, dsm, terrain, dsm_grid, nodata, grid, options, load, sink, &report->ortho, error))
      return false;
    if (!writer.Close(error)) return false;
  }
  const auto start = std::chrono::steady_clock::now();
  GDALDatasetH tiles = GDALOpen(tiles_path.c_str(), GA_ReadOnly);
  if (tiles == nullptr) {
    *error = GdalError("cannot reopen " + tiles_path);
    return false;
  }
  // JPEG for the colours (a photograph), the alpha band becomes the COG's mask; overviews averaged.
  bool ok = Translate(tiles, files.cog,
                      {"-of", "COG", "-co", "COMPRESS=JPEG", "-co", "QUALITY=" + std::to_string(files.jpeg_quality),
                       "-co", "BLOCKSIZE=512", "-co", "OVERVIEW_RESAMPLING=AVERAGE", "-co", "BIGTIFF=IF_SAFER"},
                      error);
  ok = ok && (files.quicklook.empty() || WriteQuicklook(tiles, files.quicklook, files.quicklook_long_side, error));
  if (ok && !files.mbtiles.empty() && !crs_wkt.empty()) {
    // An extra for ground stations: when it fails the orthophoto still stands, and the failure is said.
    std::string why;
    report->mbtiles_written = WriteMbtiles(tiles, files.mbtiles, &why);
    if (!report->mbtiles_written) report->warnings.push_back("ortho.mbtiles not written: " + why);
  }
  GDALClose(tiles);
  if (ok && !files.tiles_dir.empty() && !crs_wkt.empty()) {
    TileSet set;
    ok = WriteTiles(tiles_path, files.tiles_dir, true, gsd, TileOptions{}, &set, error);
    report->web_tiles = set.tiles;
    report->web_min_zoom = set.min_zoom;
    report->web_max_zoom = set.max_zoom;
  }
  std::remove(tiles_path.c_str());
  report->write_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return ok;
}

}  // namespace uavm::sfm
