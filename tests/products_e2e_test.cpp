// Georeferenced products of a real flight with EXIF GPS (brighton_beach_small: Brighton Beach, Duluth MN) and of the
// same frames without GPS: mosaic.tif as a COG in the right UTM zone, frame centres against their GPS, KMZ (a
// super-overlay of the tiles: boxes, links, doc.kml first), tiles (against GDAL's own warp of mosaic.tif) and the
// Leaflet page rendered by headless Chromium.
#include <cpl_conv.h>
#include <cpl_minixml.h>
#include <cpl_string.h>
#include <gdal_priv.h>
#include <gdal_utils.h>
#include <gtest/gtest.h>
#include <ogr_spatialref.h>
#include <sys/wait.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <memory>
#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <set>
#include <sstream>
#include <tuple>

#include "core/session/session_dir.h"
#include "tests/browser_shot.h"
#include "tests/test_env.h"

namespace uavm {
namespace {

namespace fs = std::filesystem;
const std::string kData = UAVM_TEST_DATA;

using test::RunOnboard;

nlohmann::json ReadJson(const fs::path& p) {
  std::ifstream in(p);
  return nlohmann::json::parse(in);
}

std::vector<std::vector<std::string>> ReadCsv(const fs::path& p) {
  std::ifstream in(p);
  std::vector<std::vector<std::string>> rows;
  std::string line;
  while (std::getline(in, line)) {
    std::vector<std::string> cells;
    std::stringstream ss(line);
    std::string c;
    while (std::getline(ss, c, ',')) cells.push_back(c);
    if (!line.empty() && line.back() == ',') cells.emplace_back();
    rows.push_back(cells);
  }
  return rows;
}

struct Closer {
  void operator()(GDALDataset* d) const { GDALClose(d); }
};

class ProductsE2ETest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    GDALAllRegister();
    gps_ = fs::temp_directory_path() / ("uavm_products_gps_" + std::to_string(::getpid()));
    fs::remove_all(gps_);
    // Under emulation the first 8 frames (two strips: the georeference has spread to fit).
    const test::FlightForTest flight(kData + "/brighton_beach_small/images", 8, gps_.string() + "_in");
    gps_frames_ = flight.frames();
    gps_exit_ = RunOnboard("--source replay:" + flight.string() + " --out " + gps_.string(), test::Products::kWrite);
    // The same frames without EXIF (OpenCV writes none): the products in a local frame.
    nogps_in_ = fs::temp_directory_path() / ("uavm_products_nogps_in_" + std::to_string(::getpid()));
    nogps_ = fs::temp_directory_path() / ("uavm_products_nogps_" + std::to_string(::getpid()));
    fs::remove_all(nogps_in_);
    fs::remove_all(nogps_);
    fs::create_directories(nogps_in_);
    std::vector<fs::path> files;
    for (const auto& e : fs::directory_iterator(kData + "/brighton_beach_small/images")) files.push_back(e.path());
    std::sort(files.begin(), files.end());
    for (size_t i = 0; i < 8 && i < files.size(); ++i)
      cv::imwrite((nogps_in_ / files[i].filename()).string(), cv::imread(files[i].string()),
                  {cv::IMWRITE_JPEG_QUALITY, 95});
    nogps_exit_ =
        RunOnboard("--source replay:" + nogps_in_.string() + " --out " + nogps_.string(), test::Products::kWrite);
  }
  static void TearDownTestSuite() {
    if (!::testing::Test::HasFailure()) {
      fs::remove_all(gps_);
      fs::remove_all(nogps_);
    }
    fs::remove_all(nogps_in_);
  }
  static inline fs::path gps_, nogps_, nogps_in_;
  static inline int gps_exit_ = -1, nogps_exit_ = -1;
  static inline int gps_frames_ = 0;  // frames of the GPS flight (fewer under emulation)
};

TEST_F(ProductsE2ETest, MosaicTifIsCogInTheFlightsUtmZone) {
  ASSERT_EQ(gps_exit_, 0);
  std::unique_ptr<GDALDataset, Closer> ds(
      GDALDataset::Open((gps_ / "mosaic.tif").c_str(), GDAL_OF_RASTER | GDAL_OF_READONLY));
  ASSERT_TRUE(ds);
  ASSERT_EQ(ds->GetRasterCount(), 4);
  EXPECT_EQ(ds->GetRasterBand(4)->GetColorInterpretation(), GCI_AlphaBand);
  const OGRSpatialReference* srs = ds->GetSpatialRef();
  ASSERT_NE(srs, nullptr);
  // Longitude -91.99 is in UTM zone 15, north: EPSG:32615.
  ASSERT_NE(srs->GetAuthorityCode(nullptr), nullptr);
  EXPECT_STREQ(srs->GetAuthorityCode(nullptr), "32615");
  double gt[6];
  ASSERT_EQ(ds->GetGeoTransform(gt), CE_None);
  EXPECT_EQ(gt[2], 0.0);  // north-up: no rotation terms
  EXPECT_EQ(gt[4], 0.0);
  EXPECT_GT(gt[1], 0.05);  // ~13 cm/px at 40 m with mosaic_scale 0.5
  EXPECT_LT(gt[1], 0.3);
  EXPECT_DOUBLE_EQ(gt[5], -gt[1]);
  // COG layout as GDAL records it, and overviews present.
  const char* layout = ds->GetMetadataItem("LAYOUT", "IMAGE_STRUCTURE");
  ASSERT_NE(layout, nullptr);
  EXPECT_STREQ(layout, "COG");
  EXPECT_GE(ds->GetRasterBand(1)->GetOverviewCount(), 1);
  int bx = 0, by = 0;
  ds->GetRasterBand(1)->GetBlockSize(&bx, &by);
  EXPECT_EQ(bx, 512);
  EXPECT_EQ(by, 512);
  // GDAL's own COG validator (python3-gdal), when present.
  const char* validator = "/usr/lib/python3/dist-packages/osgeo_utils/samples/validate_cloud_optimized_geotiff.py";
  if (fs::exists(validator)) {
    const std::string cmd = std::string("/usr/bin/python3 ") + validator + " -q " + (gps_ / "mosaic.tif").string();
    const int status = std::system(cmd.c_str());
    EXPECT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 0) << "validate_cloud_optimized_geotiff.py failed";
  }
  const auto report = ReadJson(gps_ / "report.json");
  EXPECT_EQ(report["georef"]["crs"], "EPSG:32615");
  EXPECT_TRUE(report["products"]["cog"].get<bool>());
}

TEST_F(ProductsE2ETest, FrameCentresLandOnTheirGps) {
  ASSERT_EQ(gps_exit_, 0);
  std::unique_ptr<GDALDataset, Closer> ds(
      GDALDataset::Open((gps_ / "mosaic.tif").c_str(), GDAL_OF_RASTER | GDAL_OF_READONLY));
  ASSERT_TRUE(ds);
  double gt[6];
  ASSERT_EQ(ds->GetGeoTransform(gt), CE_None);
  std::string text, err;
  ASSERT_TRUE(ReadTextFile((gps_ / "transforms.csv").string(), &text, &err));
  std::vector<TransformRow> rows;
  ASSERT_TRUE(ParseTransformsCsv(text, &rows, &err)) << err;
  const auto frames = ReadCsv(gps_ / "frames.csv");
  ASSERT_EQ(frames.size(), rows.size() + 1);
  // GPS projected independently of the program (OGR here).
  OGRSpatialReference wgs, utm;
  wgs.SetWellKnownGeogCS("WGS84");
  utm.importFromEPSG(32615);
  wgs.SetAxisMappingStrategy(OAMS_TRADITIONAL_GIS_ORDER);
  utm.SetAxisMappingStrategy(OAMS_TRADITIONAL_GIS_ORDER);
  std::unique_ptr<OGRCoordinateTransformation> t(OGRCreateCoordinateTransformation(&wgs, &utm));
  ASSERT_TRUE(t);
  double sum2 = 0;
  int n = 0;
  for (size_t i = 0; i < rows.size(); ++i) {
    const auto& f = frames[i + 1];
    ASSERT_GE(f.size(), 9u);
    if (!rows[i].registered || f[7].empty()) continue;
    const int w = std::stoi(f[3]), h = std::stoi(f[4]);
    const Vec2 c = Apply(rows[i].mosaic_from_frame, Vec2(0.5 * (w - 1), 0.5 * (h - 1)));
    // GDAL's geotransform is corner-based: pixel centre (x, y) is at (x + 0.5, y + 0.5).
    const double e = gt[0] + (c.x() + 0.5) * gt[1] + (c.y() + 0.5) * gt[2];
    const double nn = gt[3] + (c.x() + 0.5) * gt[4] + (c.y() + 0.5) * gt[5];
    double x = std::stod(f[8]), y = std::stod(f[7]);
    ASSERT_TRUE(t->Transform(1, &x, &y));
    const double d = std::hypot(e - x, nn - y);
    EXPECT_LT(d, 6.0) << rows[i].filename;  // consumer GPS: a few metres
    sum2 += d * d;
    ++n;
  }
  ASSERT_EQ(n, gps_frames_);
  const double rms = std::sqrt(sum2 / n);
  std::printf("frame centre vs EXIF GPS: RMS %.2f m over %d frames\n", rms, n);
  EXPECT_LT(rms, 3.0);
  const auto report = ReadJson(gps_ / "report.json");
  EXPECT_NEAR(report["georef"]["rms_all_m"].get<double>(), rms, 0.05);
  EXPECT_NEAR(report["georef"]["gsd_cm_per_px"].get<double>(), gt[1] * 100, 1e-6);
}

TEST_F(ProductsE2ETest, KmzAndTilesDecode) {
  ASSERT_EQ(gps_exit_, 0);
  // The KMZ is a zip with doc.kml and PNG tiles (read through GDAL's /vsizip/).
  const std::string kmz = "/vsizip/" + (gps_ / "mosaic.kmz").string();
  VSIStatBufL st;
  ASSERT_EQ(VSIStatL((kmz + "/doc.kml").c_str(), &st), 0);
  char** listing = VSIReadDirRecursive(kmz.c_str());
  int pngs = 0;
  std::string first_png;
  for (char** p = listing; p != nullptr && *p != nullptr; ++p)
    if (std::string(*p).size() > 4 && std::string(*p).substr(std::string(*p).size() - 4) == ".png") {
      if (first_png.empty()) first_png = *p;
      ++pngs;
    }
  CSLDestroy(listing);
  EXPECT_GT(pngs, 0);
  std::unique_ptr<GDALDataset, Closer> tile(GDALDataset::Open((kmz + "/" + first_png).c_str(), GDAL_OF_RASTER));
  ASSERT_TRUE(tile) << first_png;
  EXPECT_GT(tile->GetRasterXSize(), 0);
  // Web tiles: every one a 256x256 RGBA PNG with some opaque pixels; the zoom range of the report.
  const auto report = ReadJson(gps_ / "report.json");
  const auto& tiles = report["products"]["tiles"];
  EXPECT_EQ(tiles["crs"], "EPSG:3857");
  const int zmin = tiles["min_zoom"], zmax = tiles["max_zoom"];
  // At 47 deg N a zoom-20 pixel is 10.2 cm on the ground: the first not coarser than a ~13 cm GSD.
  EXPECT_EQ(zmax, 20);
  EXPECT_LE(zmin, 18);
  int count = 0;
  for (const auto& e : fs::recursive_directory_iterator(gps_ / "tiles")) {
    if (e.path().extension() != ".png") continue;
    const cv::Mat img = cv::imread(e.path().string(), cv::IMREAD_UNCHANGED);
    ASSERT_EQ(img.type(), CV_8UC4) << e.path();
    ASSERT_EQ(img.size(), cv::Size(256, 256));
    cv::Mat a;
    cv::extractChannel(img, a, 3);
    EXPECT_GT(cv::countNonZero(a), 0);
    const int z = std::stoi(e.path().parent_path().parent_path().filename().string());
    EXPECT_GE(z, zmin);
    EXPECT_LE(z, zmax);
    ++count;
  }
  EXPECT_EQ(count, tiles["count"].get<int>());
  // The tile that holds the first frame's GPS position (XYZ arithmetic) is present and opaque at that point.
  const double lat = 46.8426070833 * M_PI / 180, lon = -91.9945598889;
  const double n = std::ldexp(1.0, zmax);
  const double fx = (lon + 180) / 360 * n, fy = (1 - std::asinh(std::tan(lat)) / M_PI) / 2 * n;
  const fs::path p = gps_ / "tiles" / std::to_string(zmax) / std::to_string(static_cast<int>(fx)) /
                     (std::to_string(static_cast<int>(fy)) + ".png");
  const cv::Mat img = cv::imread(p.string(), cv::IMREAD_UNCHANGED);
  ASSERT_FALSE(img.empty()) << p;
  const int px = static_cast<int>((fx - std::floor(fx)) * 256), py = static_cast<int>((fy - std::floor(fy)) * 256);
  EXPECT_GT(img.at<cv::Vec4b>(py, px)[3], 0);
}

// The tile (z, x, y)'s bounds in degrees (west, south, east, north), from the XYZ numbers.
std::array<double, 4> TileBounds(int z, int x, int y) {
  const double n = std::ldexp(1.0, z);
  const auto lat = [&](int row) { return std::atan(std::sinh(M_PI * (1 - 2 * row / n))) * 180 / M_PI; };
  return {x / n * 360 - 180, lat(y + 1), (x + 1) / n * 360 - 180, lat(y)};
}

// The independent reference for a tile: GDAL's warper (bilinear, destination alpha) into a MEM dataset of the tile's
// EPSG:3857 grid, read as BGRA (how the tiles were made before issue 23).
cv::Mat ReferenceTile(GDALDataset* src, int z, int x, int y) {
  const double half = 20037508.342789244, span = 2 * half / std::ldexp(1.0, z);
  std::unique_ptr<GDALDataset, Closer> dst(
      GetGDALDriverManager()->GetDriverByName("MEM")->Create("", 256, 256, 4, GDT_Byte, nullptr));
  double gt[6] = {-half + x * span, span / 256, 0, half - y * span, 0, -span / 256};
  dst->SetGeoTransform(gt);
  OGRSpatialReference merc;
  merc.importFromEPSG(3857);
  dst->SetSpatialRef(&merc);
  dst->GetRasterBand(4)->SetColorInterpretation(GCI_AlphaBand);
  char** args = nullptr;
  for (const char* a : {"-r", "bilinear", "-dstalpha", "-q"}) args = CSLAddString(args, a);
  GDALWarpAppOptions* opts = GDALWarpAppOptionsNew(args, nullptr);
  CSLDestroy(args);
  GDALDatasetH src_h = GDALDataset::ToHandle(src);
  int usage = 0;
  const bool ok = GDALWarp(nullptr, GDALDataset::ToHandle(dst.get()), 1, &src_h, opts, &usage) != nullptr;
  GDALWarpAppOptionsFree(opts);
  cv::Mat tile(256, 256, CV_8UC4, cv::Scalar::all(0));
  int bands[4] = {3, 2, 1, 4};
  if (!ok || usage != 0 ||
      dst->RasterIO(GF_Read, 0, 0, 256, 256, tile.data, 256, 256, GDT_Byte, 4, bands, 4,
                    static_cast<GSpacing>(tile.step[0]), 1, nullptr) != CE_None)
    return {};
  return tile;
}

// A few tiles of zoom z: the `count` with the most opaque pixels (the most to compare), as (x, y).
std::vector<std::pair<int, int>> MostOpaqueTiles(const fs::path& tiles, int z, size_t count) {
  std::vector<std::tuple<int, int, int>> found;  // opaque pixels, x, y
  for (const auto& e : fs::recursive_directory_iterator(tiles / std::to_string(z))) {
    if (e.path().extension() != ".png") continue;
    cv::Mat a;
    cv::extractChannel(cv::imread(e.path().string(), cv::IMREAD_UNCHANGED), a, 3);
    found.emplace_back(cv::countNonZero(a), std::stoi(e.path().parent_path().filename().string()),
                       std::stoi(e.path().stem().string()));
  }
  std::sort(found.rbegin(), found.rend());
  std::vector<std::pair<int, int>> out;
  for (size_t i = 0; i < found.size() && i < count; ++i) out.emplace_back(std::get<1>(found[i]), std::get<2>(found[i]));
  return out;
}

TEST_F(ProductsE2ETest, TilesAgreeWithGdalWarp) {
  ASSERT_EQ(gps_exit_, 0);
  std::unique_ptr<GDALDataset, Closer> ds(
      GDALDataset::Open((gps_ / "mosaic.tif").c_str(), GDAL_OF_RASTER | GDAL_OF_READONLY));
  ASSERT_TRUE(ds);
  const auto report = ReadJson(gps_ / "report.json");
  const int zmin = report["products"]["tiles"]["min_zoom"], zmax = report["products"]["tiles"]["max_zoom"];
  std::vector<std::tuple<int, int, int>> picked;
  for (const auto& [x, y] : MostOpaqueTiles(gps_ / "tiles", zmax, 3)) picked.emplace_back(zmax, x, y);
  for (const auto& [x, y] : MostOpaqueTiles(gps_ / "tiles", zmin, 1)) picked.emplace_back(zmin, x, y);
  ASSERT_EQ(picked.size(), 4u);
  for (const auto& [z, x, y] : picked) {
    const std::string name = std::to_string(z) + "/" + std::to_string(x) + "/" + std::to_string(y);
    const cv::Mat ours = cv::imread((gps_ / "tiles" / (name + ".png")).string(), cv::IMREAD_UNCHANGED);
    const cv::Mat ref = ReferenceTile(ds.get(), z, x, y);
    ASSERT_FALSE(ref.empty()) << name << ": " << CPLGetLastErrorMsg();
    ASSERT_EQ(ours.type(), CV_8UC4) << name;
    double diff = 0;
    int both = 0, agree = 0;
    for (int r = 0; r < 256; ++r)
      for (int c = 0; c < 256; ++c) {
        const auto a = ours.at<cv::Vec4b>(r, c), b = ref.at<cv::Vec4b>(r, c);
        agree += (a[3] > 0) == (b[3] > 0);
        if (a[3] < 255 || b[3] < 255) continue;
        ++both;
        for (int k = 0; k < 3; ++k) diff += std::abs(a[k] - b[k]);
      }
    ASSERT_GT(both, 1000) << name;
    const double mad = diff / (3.0 * both), agreement = agree / 65536.0;
    std::printf("tile %s: mean |difference| %.2f over %d pixels, alpha agrees on %.2f %%\n", name.c_str(), mad, both,
                100 * agreement);
    // At the native zoom the tiles are GDAL's within 0.1 grey level. At the coarsest zoom (8x below) our pyramid's
    // tiles and GDAL's warp differ with the content: 1.6-1.7 and 3.3 on two neighbouring tiles of this flight,
    // whichever descriptor registered it (measured 2026-12-06; the most opaque of them changes with the mosaic's edge).
    EXPECT_LT(mad, z == zmax ? 1.0 : 4.0) << name;
    EXPECT_GE(agreement, 0.98) << name;
  }
}

// The KML element `path` (dot-separated) under `node`, as text.
std::string Xml(const CPLXMLNode* node, const char* path) {
  const char* v = CPLGetXMLValue(node, path, nullptr);
  return v == nullptr ? std::string() : std::string(v);
}

// A tile KML's GroundOverlay: its LatLonBox is the bounds of the tile the file is named after (z/x/y.kml), its image
// that tile's PNG, present in the zip.
void CheckOverlay(const CPLXMLNode* overlay, const std::string& entry, const std::set<std::string>& entries) {
  int z = -1, x = -1, y = -1;
  ASSERT_EQ(std::sscanf(entry.c_str(), "%d/%d/%d.kml", &z, &x, &y), 3) << entry;
  const auto b = TileBounds(z, x, y);
  EXPECT_NEAR(std::stod(Xml(overlay, "LatLonBox.west")), b[0], 1e-9) << entry;
  EXPECT_NEAR(std::stod(Xml(overlay, "LatLonBox.south")), b[1], 1e-9) << entry;
  EXPECT_NEAR(std::stod(Xml(overlay, "LatLonBox.east")), b[2], 1e-9) << entry;
  EXPECT_NEAR(std::stod(Xml(overlay, "LatLonBox.north")), b[3], 1e-9) << entry;
  const std::string png = (fs::path(entry).parent_path() / Xml(overlay, "Icon.href")).lexically_normal().string();
  EXPECT_EQ(png, std::to_string(z) + "/" + std::to_string(x) + "/" + std::to_string(y) + ".png");
  EXPECT_EQ(entries.count(png), 1u) << entry;
}

// One KML file of the KMZ: its GroundOverlays (CheckOverlay) and every NetworkLink's target, resolved against the
// zip's entries. Returns the GroundOverlays seen.
int CheckKml(const std::string& kmz, const std::string& entry, const std::set<std::string>& entries) {
  CPLXMLNode* root = CPLParseXMLFile((kmz + "/" + entry).c_str());
  EXPECT_NE(root, nullptr) << entry;
  if (root == nullptr) return 0;
  const CPLXMLNode* doc = CPLGetXMLNode(root, "=kml.Document");
  EXPECT_NE(doc, nullptr) << entry;
  int overlays = 0;
  for (const CPLXMLNode* n = doc == nullptr ? nullptr : doc->psChild; n != nullptr; n = n->psNext) {
    if (n->eType != CXT_Element) continue;
    if (std::string(n->pszValue) == "NetworkLink") {
      const std::string target = (fs::path(entry).parent_path() / Xml(n, "Link.href")).lexically_normal().string();
      EXPECT_EQ(entries.count(target), 1u) << entry << " links to " << target;
    } else if (std::string(n->pszValue) == "GroundOverlay") {
      ++overlays;
      CheckOverlay(n, entry, entries);
    }
  }
  CPLDestroyXMLNode(root);
  return overlays;
}

TEST_F(ProductsE2ETest, KmzIsASuperOverlayOfTheTiles) {
  ASSERT_EQ(gps_exit_, 0);
  // Google Earth takes the first .kml of the archive: doc.kml must be entry 0 (the zip's first local file header).
  std::ifstream zip(gps_ / "mosaic.kmz", std::ios::binary);
  unsigned char head[30] = {};
  zip.read(reinterpret_cast<char*>(head), sizeof(head));
  ASSERT_TRUE(zip);
  ASSERT_EQ(std::string(reinterpret_cast<char*>(head), 4), std::string("PK\x03\x04", 4));
  const int name_len = head[26] | (head[27] << 8);
  std::string first(static_cast<size_t>(name_len), '\0');
  zip.read(first.data(), name_len);
  EXPECT_EQ(first, "doc.kml");
  const std::string kmz = "/vsizip/" + (gps_ / "mosaic.kmz").string();
  std::set<std::string> entries;
  char** listing = VSIReadDirRecursive(kmz.c_str());
  for (char** p = listing; p != nullptr && *p != nullptr; ++p) entries.insert(*p);
  CSLDestroy(listing);
  int overlays = 0;
  for (const std::string& e : entries)
    if (e.size() > 4 && e.substr(e.size() - 4) == ".kml") overlays += CheckKml(kmz, e, entries);
  // One GroundOverlay per tile written.
  EXPECT_EQ(overlays, ReadJson(gps_ / "report.json")["products"]["tiles"]["count"].get<int>());
}

TEST_F(ProductsE2ETest, BrowserShowsTheMosaic) {
  ASSERT_EQ(gps_exit_, 0);
  ASSERT_FALSE(test::ChromiumBinary().empty()) << "chromium missing: run scripts/setup.sh";
  ASSERT_TRUE(fs::exists(gps_ / "leaflet" / "leaflet.js"));
  // The page's layers: one footprint per registered frame (lon/lat near the flight), one line per graph.csv edge.
  const auto fp = ReadJson(gps_ / "footprints.geojson");
  ASSERT_EQ(fp["features"].size(), static_cast<size_t>(gps_frames_));
  for (const auto& f : fp["features"])
    for (const auto& c : f["geometry"]["coordinates"][0]) {
      EXPECT_NEAR(c[0].get<double>(), -91.994, 0.005);
      EXPECT_NEAR(c[1].get<double>(), 46.843, 0.005);
    }
  EXPECT_EQ(ReadJson(gps_ / "graph.geojson")["features"].size(), ReadCsv(gps_ / "graph.csv").size() - 1);
  const cv::Mat shot = test::Screenshot("file://" + (gps_ / "index.html").string(), gps_ / "browser");
  ASSERT_FALSE(shot.empty());
  cv::Scalar mean;
  const double share = test::ContentShare(shot, &mean);
  std::printf("index.html: %.0f %% of the view is mosaic\n", 100 * share);
  EXPECT_GT(share, 0.15);  // the mosaic fills a good part of the view, not just the page's controls
  // The drawn pixels have the mosaic's colours (mean BGR within 25 levels of the quick look's).
  const cv::Scalar ref = test::ContentMean(cv::imread((gps_ / "mosaic.png").string(), cv::IMREAD_UNCHANGED));
  for (int c = 0; c < 3; ++c) EXPECT_NEAR(mean[c], ref[c], 25) << "channel " << c;
}

TEST_F(ProductsE2ETest, WithoutGpsTheProductsAreLocal) {
  ASSERT_EQ(nogps_exit_, 0);
  const auto report = ReadJson(nogps_ / "report.json");
  EXPECT_EQ(report["georef"]["crs"], "local");
  EXPECT_FALSE(report["georef"]["georeferenced"].get<bool>());
  EXPECT_EQ(report["georef"]["frames_with_gps"].get<int>(), 0);
  EXPECT_EQ(report["products"]["tiles"]["crs"], "local");
  EXPECT_GT(report["products"]["tiles"]["count"].get<int>(), 0);
  std::unique_ptr<GDALDataset, Closer> ds(
      GDALDataset::Open((nogps_ / "mosaic.tif").c_str(), GDAL_OF_RASTER | GDAL_OF_READONLY));
  ASSERT_TRUE(ds);
  EXPECT_EQ(ds->GetSpatialRef(), nullptr);
  EXPECT_STREQ(ds->GetMetadataItem("LAYOUT", "IMAGE_STRUCTURE"), "COG");
  EXPECT_FALSE(fs::exists(nogps_ / "mosaic.kmz"));  // Google Earth needs a position
  std::string page;
  std::string err;
  ASSERT_TRUE(ReadTextFile((nogps_ / "map_data.js").string(), &page, &err));
  EXPECT_NE(page.find("not georeferenced"), std::string::npos);
  EXPECT_NE(page.find("\"geographic\":false"), std::string::npos);
  const cv::Mat shot = test::Screenshot("file://" + (nogps_ / "index.html").string(), nogps_ / "browser");
  ASSERT_FALSE(shot.empty());
  cv::Scalar mean;
  EXPECT_GT(test::ContentShare(shot, &mean), 0.10);
}

}  // namespace
}  // namespace uavm
