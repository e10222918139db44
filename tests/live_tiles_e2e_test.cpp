// The live tiles of a replayed real flight, read by real clients while the drone "flies": GDAL's WMTS driver (through
// /wmts/1.0.0/WMTSCapabilities.xml) and its XYZ tile service description (/tiles.xml) read a window of the growing
// map, a headless Chromium shows the live page on its tiles; after the flight the same URL gives the end-of-flight
// tiles, which must lie on mosaic.tif to within one tile pixel.
#include <gtest/gtest.h>
#include <httplib.h>
#include <ogr_spatialref.h>
#include <signal.h>
#include <sys/wait.h>

#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <memory>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <thread>

#include "tests/browser_shot.h"
#include "tests/process_util.h"
#include "tests/test_env.h"
#include "tests/test_net.h"

namespace uavm {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

constexpr double kHalfWorld = 20037508.342789244;

// The status' "tiles" once `ready` says so (or null at the deadline).
json WaitForTiles(httplib::Client* client, int seconds, const std::function<bool(const json&)>& ready) {
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(seconds);
  while (std::chrono::steady_clock::now() < deadline) {
    auto res = client->Get("/status.json");
    if (res && res->status == 200) {
      const json st = json::parse(res->body, nullptr, false);
      if (!st.is_discarded() && st.contains("tiles") && !st["tiles"].is_null() && ready(st)) return st;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(250));
  }
  return nullptr;
}

// EPSG:3857 box (xmin, ymin, xmax, ymax) of a lat/lon box, through PROJ (not the product's own arithmetic).
std::array<double, 4> MercatorBox(double west, double south, double east, double north) {
  OGRSpatialReference wgs, merc;
  wgs.importFromEPSG(4326);
  merc.importFromEPSG(3857);
  wgs.SetAxisMappingStrategy(OAMS_TRADITIONAL_GIS_ORDER);
  merc.SetAxisMappingStrategy(OAMS_TRADITIONAL_GIS_ORDER);
  std::unique_ptr<OGRCoordinateTransformation> t(OGRCreateCoordinateTransformation(&wgs, &merc));
  double x[2] = {west, east}, y[2] = {south, north};
  if (!t || !t->Transform(2, x, y)) return {0, 0, 0, 0};
  return {x[0], y[0], x[1], y[1]};
}

// `source` read by GDAL over `box` at `metres_per_px` (EPSG:3857), as RGBA (empty on failure). gdalwarp onto the
// target grid (with -projwin, gdal_translate 3.6 rounds the window and can land a row off).
cv::Mat ReadWindow(const std::string& source, const std::array<double, 4>& box, double metres_per_px,
                   const fs::path& out) {
  const long w = std::lround((box[2] - box[0]) / metres_per_px);
  const long h = std::lround((box[3] - box[1]) / metres_per_px);
  char te[256];
  std::snprintf(te, sizeof(te), "-te %.6f %.6f %.6f %.6f -ts %ld %ld", box[0], box[1], box[2], box[3], w, h);
  const fs::path tif = out.string() + ".tif";
  // No GDAL disk cache of web tiles: a live map changes under the same URL (and a port is used again by later runs).
  const std::string log = test::CommandOutput(
      "gdalwarp -q -overwrite --config GDAL_ENABLE_WMS_CACHE NO -t_srs EPSG:3857 -r bilinear -dstalpha " +
      std::string(te) + " '" + source + "' " + tif.string() + " 2>&1");
  test::CommandOutput("gdal_translate -q -of PNG -b 1 -b 2 -b 3 -b 4 " + tif.string() + " " + out.string() + " 2>&1");
  const cv::Mat img = cv::imread(out.string(), cv::IMREAD_UNCHANGED);
  if (img.empty() || img.channels() != 4) std::printf("gdalwarp %s: %s\n", source.c_str(), log.c_str());
  return img.channels() == 4 ? img : cv::Mat();
}

double OpaqueShare(const cv::Mat& rgba) {
  std::vector<cv::Mat> ch;
  cv::split(rgba, ch);
  return cv::countNonZero(ch[3] > 0) / static_cast<double>(rgba.total());
}

// Mean absolute colour difference where both are opaque, and the share of such pixels.
double MeanDiff(const cv::Mat& a, const cv::Mat& b, double* both_share) {
  double sum = 0;
  long n = 0;
  for (int y = 0; y < a.rows; ++y)
    for (int x = 0; x < a.cols; ++x) {
      const auto pa = a.at<cv::Vec4b>(y, x), pb = b.at<cv::Vec4b>(y, x);
      if (pa[3] < 255 || pb[3] < 255) continue;
      sum += (std::abs(pa[0] - pb[0]) + std::abs(pa[1] - pb[1]) + std::abs(pa[2] - pb[2])) / 3.0;
      ++n;
    }
  *both_share = static_cast<double>(n) / static_cast<double>(a.total());
  return n > 0 ? sum / static_cast<double>(n) : 1e9;
}

// Translation (pixels) from `b` to `a` by phase correlation of their grey images inside both footprints.
cv::Point2d Shift(const cv::Mat& a, const cv::Mat& b) {
  cv::Mat ga, gb, mask;
  cv::cvtColor(a, ga, cv::COLOR_BGRA2GRAY);
  cv::cvtColor(b, gb, cv::COLOR_BGRA2GRAY);
  std::vector<cv::Mat> ca, cb;
  cv::split(a, ca);
  cv::split(b, cb);
  mask = (ca[3] == 255) & (cb[3] == 255);
  ga.setTo(0, ~mask);
  gb.setTo(0, ~mask);
  cv::Mat fa, fb, window;
  ga.convertTo(fa, CV_64F);
  gb.convertTo(fb, CV_64F);
  cv::createHanningWindow(window, fa.size(), CV_64F);
  return cv::phaseCorrelate(fb, fa, window);
}

TEST(LiveTilesE2ETest, GdalAndABrowserReadTheMapDuringTheFlightAndTheFinalTilesAfter) {
  const fs::path out = fs::temp_directory_path() / ("uavm_live_tiles_" + std::to_string(::getpid()));
  fs::remove_all(out);
  fs::create_directories(out.string() + "_reads");
  const fs::path reads(out.string() + "_reads");
  const int port = test::FreePort();
  ASSERT_GT(port, 0);
  const std::string base = "http://127.0.0.1:" + std::to_string(port);
  const std::string data = UAVM_TEST_DATA;
  // Served on every address, as on a drone's Wi-Fi: with an access token (issue 39). The clients below hold it, each
  // in its own way: a header (httplib), the URL (GDAL), the page's URL and then its cookie (Chromium).
  const std::string token = "t0ken-" + std::to_string(::getpid()) + "-of-the-live-view";
  const fs::path token_file = reads / "token";
  std::ofstream(token_file) << token << "\n";
  fs::permissions(token_file, fs::perms::owner_read | fs::perms::owner_write);
  const std::string query = "?token=" + token;
  // ~1.5 s per frame: the 18-frame flight lasts long enough to read it in the middle, also when the tile worker lags
  // on a loaded machine (at 0.7 s per frame a CI run beside a build saw the flight end before 6 frames were drawn).
  const pid_t pid =
      test::Spawn(std::string(UAVM_ONBOARD_BIN) + " --source replay:" + data + "/brighton_beach_small/images --out " +
                  out.string() + " --http 0.0.0.0:" + std::to_string(port) + " --http-token-file " +
                  token_file.string() + " --http-linger 120 --process-delay-ms 1200 --log-level warn");
  ASSERT_GT(pid, 0);
  httplib::Client client("127.0.0.1", port);
  client.set_connection_timeout(1, 0);
  client.set_read_timeout(5, 0);
  client.set_bearer_token_auth(token.c_str());

  // Mid-flight: georeferenced tiles of at least 6 frames while frames are still coming.
  const json mid = WaitForTiles(&client, 120, [](const json& st) {
    return st["state"] == "flying" && st["tiles"]["geographic"].get<bool>() && st["tiles"]["frames"].get<int>() >= 6;
  });
  ASSERT_FALSE(mid.is_null()) << "no georeferenced live tiles during the flight";
  const json& t = mid["tiles"];
  std::printf("status mid-flight: %s\n", t.dump().c_str());
  const int frames_then = mid["frames_in"].get<int>();
  const auto box = MercatorBox(t["bounds"][0].get<double>(), t["bounds"][1].get<double>(), t["bounds"][2].get<double>(),
                               t["bounds"][3].get<double>());  // w, s, e, n
  // At the finest zoom, which both descriptions read as is (coarser zooms are rebuilt a little later than it, and GDAL
  // may pick different levels for a window between zooms).
  const int z = t["max_zoom"].get<int>();
  const double px_m = 2 * kHalfWorld / (256.0 * std::ldexp(1.0, z));
  const cv::Mat wmts = ReadWindow("WMTS:" + base + "/wmts/1.0.0/WMTSCapabilities.xml" + query + ",layer=uavmosaic", box,
                                  px_m, reads / "mid_wmts.png");
  const cv::Mat xyz = ReadWindow(base + "/tiles.xml" + query, box, px_m, reads / "mid_xyz.png");
  ASSERT_FALSE(wmts.empty());
  ASSERT_FALSE(xyz.empty());
  ASSERT_EQ(wmts.size(), xyz.size());
  // Read one after the other while frames keep coming: the second may show more of the map, never elsewhere.
  const cv::Point2d between = Shift(xyz, wmts);
  std::printf(
      "mid-flight (%d frames in, %d drawn): window %dx%d px at zoom %d, map %.0f %% (WMTS) then %.0f %% (XYZ), "
      "offset between them (%.2f, %.2f) px\n",
      frames_then, t["frames"].get<int>(), wmts.cols, wmts.rows, z, 100 * OpaqueShare(wmts), 100 * OpaqueShare(xyz),
      between.x, between.y);
  EXPECT_GT(OpaqueShare(wmts), 0.3);  // the partial map fills its own bounds
  EXPECT_GE(OpaqueShare(xyz), OpaqueShare(wmts) - 0.01);
  EXPECT_LT(std::hypot(between.x, between.y), 0.5);
  double both = 0;

  // The live page in a browser, mid-flight: the map on its tiles.
  ASSERT_FALSE(test::ChromiumBinary().empty()) << "chromium missing: run scripts/setup.sh";
  const cv::Mat shot = test::ScreenshotUntilDrawn(base + "/" + query, out.string() + "_browser", 0.10, 5000);
  ASSERT_FALSE(shot.empty());
  cv::Scalar mean;
  const double share = test::ContentShare(shot, &mean);
  cv::imwrite((reads / "mid_page.png").string(), shot);
  std::printf("live page mid-flight: %.0f %% of the view is map\n", 100 * share);
  EXPECT_GT(share, 0.10);

  // After the flight: the same URLs serve the end-of-flight tiles, re-rendered from mosaic.tif.
  const json done = WaitForTiles(
      &client, 300, [](const json& st) { return st["state"] == "done" && st["tiles"]["final"].get<bool>(); });
  ASSERT_FALSE(done.is_null()) << "the flight did not end with final tiles";
  const json& f = done["tiles"];
  // Every zoom of the live grid is still there: a client keeps its URLs.
  EXPECT_GE(f["max_zoom"].get<int>(), t["max_zoom"].get<int>());
  EXPECT_LE(f["min_zoom"].get<int>(), t["min_zoom"].get<int>());
  EXPECT_GT(f["generation"].get<int64_t>(), t["generation"].get<int64_t>());
  auto fbox = MercatorBox(f["bounds"][0].get<double>(), f["bounds"][1].get<double>(), f["bounds"][2].get<double>(),
                          f["bounds"][3].get<double>());
  const double fine_m = 2 * kHalfWorld / (256.0 * std::ldexp(1.0, f["max_zoom"].get<int>()));
  // On the finest zoom's pixel grid: the WMTS read is then the tiles' own pixels, not resampled.
  fbox[0] = -kHalfWorld + std::floor((fbox[0] + kHalfWorld) / fine_m) * fine_m;
  fbox[2] = -kHalfWorld + std::ceil((fbox[2] + kHalfWorld) / fine_m) * fine_m;
  fbox[1] = kHalfWorld - std::ceil((kHalfWorld - fbox[1]) / fine_m) * fine_m;
  fbox[3] = kHalfWorld - std::floor((kHalfWorld - fbox[3]) / fine_m) * fine_m;
  const cv::Mat served = ReadWindow("WMTS:" + base + "/wmts/1.0.0/WMTSCapabilities.xml" + query + ",layer=uavmosaic",
                                    fbox, fine_m, reads / "final_wmts.png");
  ASSERT_FALSE(served.empty());
  // mosaic.tif warped by GDAL onto the same EPSG:3857 window and pixel.
  const cv::Mat ref = ReadWindow((out / "mosaic.tif").string(), fbox, fine_m, reads / "ref.png");
  ASSERT_EQ(ref.size(), served.size());
  const cv::Point2d shift = Shift(served, ref);
  const double final_diff = MeanDiff(served, ref, &both);
  std::printf("after the flight: %dx%d px at zoom %d, offset to mosaic.tif (%.2f, %.2f) px, colour diff %.2f\n",
              served.cols, served.rows, f["max_zoom"].get<int>(), shift.x, shift.y, final_diff);
  EXPECT_LT(std::hypot(shift.x, shift.y), 1.0);
  EXPECT_LT(final_diff, 8.0);  // the same mosaic resampled twice (tiles, then the read) against once
  EXPECT_GT(both, 0.3);

  // Without the token, or with a wrong one, every route is refused, the page's scripts included; nothing is named.
  httplib::Client stranger("127.0.0.1", port);
  stranger.set_read_timeout(5, 0);
  for (const std::string path : {"/", "/status.json", "/live.jpg", "/tiles.json", "/tiles/0/0/0.png", "/tiles.xml",
                                 "/wmts/1.0.0/WMTSCapabilities.xml", "/footprints.geojson", "/leaflet/leaflet.js",
                                 "/no/such/route", "/?token=wrong-token-of-16-chars"}) {
    const auto res = stranger.Get(path);
    ASSERT_TRUE(res) << path;
    EXPECT_EQ(res->status, 401) << path;
    EXPECT_EQ(res->body.find(out.string()), std::string::npos) << path;
    EXPECT_EQ(res->body.find("/leaflet"), std::string::npos) << path;
  }
  const auto access = client.Get("/status.json");
  ASSERT_TRUE(access);
  const json gate = json::parse(access->body)["http_access"];
  std::printf("access: %s\n", gate.dump().c_str());
  EXPECT_TRUE(gate["token"].get<bool>());
  EXPECT_GE(gate["unauthorized"].get<int>(), 11);
  EXPECT_EQ(gate["wrong_token"].get<int>(), 1);

  ::kill(pid, SIGTERM);  // ends the linger
  int wstatus = 0;
  ASSERT_EQ(::waitpid(pid, &wstatus, 0), pid);
  ASSERT_TRUE(WIFEXITED(wstatus));
  EXPECT_EQ(WEXITSTATUS(wstatus), 0);
  std::ifstream in(out / "report.json");
  const json report = json::parse(in);
  const json& lt = report["live_tiles"];
  std::printf("live tiles: %s\n", lt.dump().c_str());
  EXPECT_EQ(lt["jobs_dropped"].get<int>(), 0);
  EXPECT_EQ(lt["write_errors"].get<int>(), 0);
  // Every frame drawn, or still waiting when the flight ended (the final tiles superseded the backlog).
  EXPECT_GE(lt["frames_drawn"].get<int>() + lt["jobs_superseded"].get<int>(), report["registered"].get<int>());
  EXPECT_FALSE(fs::exists(out / "live_tiles"));  // superseded by tiles/
  if (!::testing::Test::HasFailure()) {
    fs::remove_all(out);
    fs::remove_all(reads);
    fs::remove_all(out.string() + "_browser");
  }
}

// A flight without positions (a simulated one: gps off): the pyramid is local (Leaflet CRS.Simple), served as XYZ
// tiles and TileJSON, not as WMTS (no CRS); the end of the flight switches the URL to the final local tiles.
TEST(LiveTilesE2ETest, WithoutPositionsThePyramidIsLocal) {
  const fs::path dir = fs::temp_directory_path() / ("uavm_live_tiles_local_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  const std::string canvas = std::string(UAVM_TEST_DATA) + "/caliterra_small/images/IMG_9360.jpg";
  std::ofstream(dir / "plan.yaml") << "frame_width: 400\nframe_height: 300\ngsd: 1.0\nstrips: 2\nstrip_length: 480\n"
                                      "forward_overlap: 0.7\nside_overlap: 0.3\nseed: 3\ngps: 0\ncanvas: \""
                                   << canvas << "\"\n";
  const int port = test::FreePort();
  ASSERT_GT(port, 0);
  const pid_t pid =
      test::Spawn(std::string(UAVM_ONBOARD_BIN) + " --source sim:" + (dir / "plan.yaml").string() + " --out " +
                  (dir / "session").string() + " --http 127.0.0.1:" + std::to_string(port) +
                  " --http-linger 60 --process-delay-ms 300 --log-level warn" + test::EmulationArgsString());
  ASSERT_GT(pid, 0);
  httplib::Client client("127.0.0.1", port);
  client.set_connection_timeout(1, 0);
  client.set_read_timeout(5, 0);
  const json mid = WaitForTiles(&client, 120, [](const json& st) { return st["tiles"]["frames"].get<int>() >= 3; });
  ASSERT_FALSE(mid.is_null()) << "no live tiles";
  const json& t = mid["tiles"];
  EXPECT_FALSE(t["geographic"].get<bool>());
  // A drawn tile at the finest zoom, under the set's bounds (CRS.Simple: x = lng * 2^z, y = -lat * 2^z).
  const int z = t["max_zoom"].get<int>();
  const double unit = std::ldexp(1.0, z) / 256.0;
  const int x = static_cast<int>(0.5 * (t["bounds"][0].get<double>() + t["bounds"][2].get<double>()) * unit);
  const int y = static_cast<int>(-0.5 * (t["bounds"][1].get<double>() + t["bounds"][3].get<double>()) * unit);
  auto tile = client.Get("/tiles/" + std::to_string(z) + "/" + std::to_string(x) + "/" + std::to_string(y) + ".png");
  ASSERT_TRUE(tile);
  EXPECT_EQ(tile->status, 200) << "tile " << z << "/" << x << "/" << y;
  const cv::Mat png = cv::imdecode(std::vector<uchar>(tile->body.begin(), tile->body.end()), cv::IMREAD_UNCHANGED);
  ASSERT_EQ(png.channels(), 4);
  EXPECT_GT(OpaqueShare(png), 0.5);  // the middle of the drawn map
  auto tilejson = client.Get("/tiles.json");
  ASSERT_TRUE(tilejson);
  EXPECT_EQ(tilejson->status, 200);
  auto wmts = client.Get("/wmts/1.0.0/WMTSCapabilities.xml");
  ASSERT_TRUE(wmts);
  EXPECT_EQ(wmts->status, 404);  // no CRS: said, not faked
  const json done = WaitForTiles(&client, 300, [](const json& st) { return st["tiles"]["final"].get<bool>(); });
  ASSERT_FALSE(done.is_null());
  EXPECT_FALSE(done["tiles"]["geographic"].get<bool>());
  EXPECT_GT(done["tiles"]["generation"].get<int64_t>(), t["generation"].get<int64_t>());
  ::kill(pid, SIGTERM);
  int wstatus = 0;
  ASSERT_EQ(::waitpid(pid, &wstatus, 0), pid);
  EXPECT_TRUE(WIFEXITED(wstatus) && WEXITSTATUS(wstatus) == 0);
  std::ifstream in(dir / "session/report.json");
  const json report = json::parse(in);
  EXPECT_EQ(report["live_tiles"]["grid"], "local");
  EXPECT_EQ(report["live_tiles"]["write_errors"].get<int>(), 0);
  if (!::testing::Test::HasFailure()) fs::remove_all(dir);
}

}  // namespace
}  // namespace uavm
