// uavm-products-bench: the end-of-flight products (core/georef/products.h) timed alone on a compositor's tiled
// GeoTIFF (uavmosaic-onboard --keep-tiled-mosaic keeps it as mosaic.tiled.tif), so that a change to the COG copy or
// the web tiles is measured without the rest of the flight. Each product is made --repeat times; the medians, and
// with --together both at once as the onboard app runs them (the tiles beside the COG copy).
#include <gdal_priv.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <future>
#include <string>
#include <vector>

#include "core/georef/products.h"

namespace fs = std::filesystem;

namespace {

double NowMs() {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

double Median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v.empty() ? 0.0 : v[v.size() / 2];
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"Times the COG copy and the web tiles on a tiled mosaic GeoTIFF"};
  std::string tif, out;
  int repeat = 3, cache_mib = 12;
  double gsd_m = 0;
  bool together = false;
  std::string only;
  app.add_option("tif", tif, "the compositor's tiled GeoTIFF (georeferenced for EPSG:3857 tiles)")->required();
  app.add_option("out", out, "scratch folder (emptied)")->required();
  app.add_option("--repeat", repeat, "runs of each product")->check(CLI::Range(1, 100));
  app.add_option("--gsd", gsd_m, "ground sample distance, m (default: the GeoTIFF's pixel size)");
  app.add_option("--cache-mib", cache_mib, "GDAL block cache, MiB (the onboard app's default plan: 12)");
  app.add_option("--only", only, "one product: cog or tiles")->check(CLI::IsMember({"cog", "tiles"}));
  app.add_flag("--together", together, "the tiles and the COG at once, as at the end of a flight");
  CLI11_PARSE(app, argc, argv);
  GDALAllRegister();
  GDALSetCacheMax64(int64_t{cache_mib} << 20);
  bool geographic = false;
  {
    GDALDataset* ds = GDALDataset::Open(tif.c_str(), GDAL_OF_RASTER | GDAL_OF_READONLY);
    if (ds == nullptr) {
      std::fprintf(stderr, "cannot open %s\n", tif.c_str());
      return 1;
    }
    double gt[6];
    geographic = ds->GetSpatialRef() != nullptr && ds->GetGeoTransform(gt) == CE_None;
    if (gsd_m <= 0 && geographic) gsd_m = std::abs(gt[1]);
    GDALClose(ds);
  }
  std::vector<double> cog_ms, tiles_ms, both_ms;
  for (int r = 0; r < repeat; ++r) {
    std::error_code ec;
    fs::remove_all(out, ec);
    fs::create_directories(out);
    std::string error, tiles_error;
    uavm::TileSet set;
    const double t0 = NowMs();
    std::future<bool> tiles;
    double tiles_end = 0;
    auto make_tiles = [&] {
      const bool ok = uavm::WriteTiles(tif, out + "/tiles", geographic, gsd_m, uavm::TileOptions{}, &set, &tiles_error);
      tiles_end = NowMs();
      return ok;
    };
    if (together) tiles = std::async(std::launch::async, make_tiles);
    if (only != "tiles" && !uavm::WriteCog(tif, out + "/mosaic.tif", &error)) {
      std::fprintf(stderr, "COG: %s\n", error.c_str());
      return 1;
    }
    const double t1 = NowMs();
    cog_ms.push_back(t1 - t0);
    const bool tiles_ok = only == "cog" || (together ? tiles.get() : make_tiles());
    if (!tiles_ok) {
      std::fprintf(stderr, "tiles: %s\n", tiles_error.c_str());
      return 1;
    }
    tiles_ms.push_back(tiles_end - (together ? t0 : t1));
    both_ms.push_back(std::max(t1, tiles_end) - t0);
    std::printf("run %d: COG %.0f ms, tiles %.0f ms (z%d-%d, %d written, %d empty), all %.0f ms\n", r + 1,
                cog_ms.back(), tiles_ms.back(), set.min_zoom, set.max_zoom, set.tiles, set.tiles_empty, both_ms.back());
  }
  std::printf("median: COG %.0f ms, tiles %.0f ms, all %.0f ms (%s)\n", Median(cog_ms), Median(tiles_ms),
              Median(both_ms), together ? "together" : "one after the other");
  return 0;
}
