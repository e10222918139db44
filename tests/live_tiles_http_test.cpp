// The live tile pyramid over the live HTTP server (firmware_app/tile_routes.h), in-process: a LiveServer on a free
// port over synthetic pyramids written here (a geographic one, z 17-19 near 50.8N 0.1W, four solid-colour tiles at
// z 19; a local CRS.Simple one). Tiles with ETag / 304 / Cache-Control, 404s and 400s (path traversal included), a
// slow client and 50 parallel ones, TileJSON, and the real clients: GDAL's WMTS driver and its WMS/TMS description
// read known tiles back, and headless Chromium shows them on the live page.
#include <arpa/inet.h>
#include <gtest/gtest.h>
#include <httplib.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <latch>
#include <map>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <thread>
#include <vector>

#include "core/tiles/tile_set.h"
#include "firmware_app/live_server.h"
#include "firmware_app/tile_routes.h"
#include "tests/browser_shot.h"
#include "tests/process_util.h"

namespace uavm {
namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

constexpr int kZ = 19;                        // the geographic set's finest level
constexpr double kHalf = 20037508.342789244;  // web-mercator half extent (m)
// The four z-19 tiles of the geographic set (BGRA): red, green / blue, magenta (top-left, top-right / bottom row).
const cv::Vec4b kColours[4] = {{0, 0, 255, 255}, {0, 200, 0, 255}, {255, 0, 0, 255}, {255, 0, 255, 255}};

double TileLon(int64_t x, int z) {
  return static_cast<double>(x) / std::ldexp(1.0, z) * 360.0 - 180.0;
}
double TileLat(int64_t y, int z) {
  return std::atan(std::sinh(M_PI * (1 - 2 * static_cast<double>(y) / std::ldexp(1.0, z)))) * 180.0 / M_PI;
}
int64_t LonTile(double lon, int z) {
  return static_cast<int64_t>(std::floor((lon + 180) / 360 * std::ldexp(1.0, z)));
}
int64_t LatTile(double lat, int z) {
  const double r = lat * M_PI / 180;
  return static_cast<int64_t>(std::floor((1 - std::asinh(std::tan(r)) / M_PI) / 2 * std::ldexp(1.0, z)));
}

// As the pyramid writer does: a temp file renamed over the tile.
void WriteTile(const fs::path& dir, int z, int64_t x, int64_t y, const cv::Mat& bgra) {
  const fs::path file = dir / std::to_string(z) / std::to_string(x) / (std::to_string(y) + ".png");
  fs::create_directories(file.parent_path());
  const fs::path tmp = file.string() + ".tmp.png";
  ASSERT_TRUE(cv::imwrite(tmp.string(), bgra));
  fs::rename(tmp, file);
}

struct GeoSet {
  TileSetInfo info;
  int64_t x0 = 0, y0 = 0;  // the top-left z-19 tile of the 2x2 block
};

// Four solid tiles at z 19 and their true downsamples at z 18 and 17 (transparent elsewhere).
GeoSet MakeGeographic(const fs::path& dir) {
  GeoSet g;
  g.x0 = LonTile(-0.1, kZ) & ~int64_t{3};  // a multiple of 4: one z-17 parent
  g.y0 = LatTile(50.8, kZ) & ~int64_t{3};
  for (int z = 17; z <= kZ; ++z) {
    const int64_t s = int64_t{1} << (kZ - z);
    const int side = kTileSize / static_cast<int>(s);
    std::map<std::pair<int64_t, int64_t>, cv::Mat> out;
    for (int i = 0; i < 4; ++i) {
      const int64_t x = g.x0 + i % 2, y = g.y0 + i / 2;
      cv::Mat& t = out[{x / s, y / s}];
      if (t.empty()) t = cv::Mat(kTileSize, kTileSize, CV_8UC4, cv::Scalar(0, 0, 0, 0));
      t(cv::Rect(static_cast<int>(x % s) * side, static_cast<int>(y % s) * side, side, side)).setTo(kColours[i]);
    }
    for (const auto& [k, m] : out) WriteTile(dir, z, k.first, k.second, m);
  }
  g.info.dir = dir.string();
  g.info.geographic = true;
  g.info.min_zoom = 17;
  g.info.max_zoom = kZ;
  g.info.west = TileLon(g.x0, kZ);
  g.info.east = TileLon(g.x0 + 2, kZ);
  g.info.north = TileLat(g.y0, kZ);
  g.info.south = TileLat(g.y0 + 2, kZ);
  g.info.generation = 3;
  g.info.updated_ns = 1000;
  g.info.frames = 4;
  return g;
}

// A 600x400 map (left half cyan, right half orange) as a local pyramid z 0..2: one map pixel per tile pixel at z 2.
TileSetInfo MakeLocal(const fs::path& dir) {
  cv::Mat map(400, 600, CV_8UC4, cv::Scalar(255, 255, 0, 255));
  map(cv::Rect(300, 0, 300, 400)).setTo(cv::Scalar(0, 128, 255, 255));
  for (int z = 0; z <= 2; ++z) {
    cv::Mat level;
    const double f = std::ldexp(1.0, z - 2);
    cv::resize(map, level, cv::Size(), f, f, cv::INTER_AREA);
    for (int y = 0; y * kTileSize < level.rows; ++y)
      for (int x = 0; x * kTileSize < level.cols; ++x) {
        cv::Mat t(kTileSize, kTileSize, CV_8UC4, cv::Scalar(0, 0, 0, 0));
        const cv::Rect r =
            cv::Rect(x * kTileSize, y * kTileSize, kTileSize, kTileSize) & cv::Rect(0, 0, level.cols, level.rows);
        level(r).copyTo(t(cv::Rect(0, 0, r.width, r.height)));
        WriteTile(dir, z, x, y, t);
      }
  }
  TileSetInfo info;
  info.dir = dir.string();
  info.geographic = false;
  info.min_zoom = 0;
  info.max_zoom = 2;
  info.east = 600 / 4.0;
  info.south = -400 / 4.0;
  info.generation = 1;
  info.frames = 2;
  return info;
}

// Sends `request` as is (no client-side normalisation) and returns the answer's status code (0: none).
int RawStatus(int port, const std::string& request) {
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_port = htons(static_cast<uint16_t>(port));
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  timeval tv{5, 0};
  ::setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof(tv));
  std::string answer;
  if (::connect(fd, reinterpret_cast<sockaddr*>(&a), sizeof(a)) == 0 &&
      ::send(fd, request.data(), request.size(), MSG_NOSIGNAL) == static_cast<ssize_t>(request.size())) {
    char buf[4096];
    for (ssize_t n; (n = ::recv(fd, buf, sizeof(buf), 0)) > 0;) answer.append(buf, static_cast<size_t>(n));
  }
  ::close(fd);
  int status = 0;
  return std::sscanf(answer.c_str(), "HTTP/1.%*d %d", &status) == 1 ? status : 0;
}

// A client that sends half a request and stalls (its socket; -1 if it could not connect).
// Polls `reached` for up to 10 s: the server's pool gauge moves when its threads get to it, later on a loaded machine.
template <class Pred>
bool WaitUntil(const Pred& reached) {
  const auto deadline = Clock::now() + std::chrono::seconds(10);
  while (!reached() && Clock::now() < deadline) std::this_thread::sleep_for(std::chrono::milliseconds(5));
  return reached();
}

int StalledClient(int port) {
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_port = htons(static_cast<uint16_t>(port));
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  const std::string half = "GET /tiles/19/0/0.png HTTP/1.1\r\nHost: 127.0";
  if (::connect(fd, reinterpret_cast<sockaddr*>(&a), sizeof(a)) != 0 ||
      ::send(fd, half.data(), half.size(), MSG_NOSIGNAL) != static_cast<ssize_t>(half.size())) {
    ::close(fd);
    return -1;
  }
  return fd;
}

int RawGet(int port, const std::string& target) {
  return RawStatus(port, "GET " + target + " HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n");
}

cv::Vec4b Decode(const std::string& png, int x, int y) {
  const cv::Mat m = cv::imdecode(std::vector<uchar>(png.begin(), png.end()), cv::IMREAD_UNCHANGED);
  if (m.empty() || m.channels() != 4) return {};
  return m.at<cv::Vec4b>(y, x);
}

class LiveTilesHttpTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    root_ = fs::temp_directory_path() / ("uavm_tiles_http_" + std::to_string(::getpid()));
    fs::remove_all(root_);
    geo_ = MakeGeographic(root_ / "geo");
    local_ = MakeLocal(root_ / "local");
  }
  static void TearDownTestSuite() {
    if (!keep_) fs::remove_all(root_);
  }
  void SetUp() override {
    app::LiveServer::Options o;
    o.port = 0;
    std::string error;
    ASSERT_TRUE(server_.Start(o, &error)) << error;
    port_ = server_.port();
    client_ = std::make_unique<httplib::Client>("127.0.0.1", port_);
    client_->set_read_timeout(5, 0);
  }
  void TearDown() override {
    if (HasFailure()) keep_ = true;
    server_.Stop();
  }
  void PublishGeo(bool final = false) {
    auto info = std::make_shared<TileSetInfo>(geo_.info);
    info->final = final;
    server_.PublishTiles(info);
  }
  std::string Tile(int z, int64_t x, int64_t y) const {
    return "/tiles/" + std::to_string(z) + "/" + std::to_string(x) + "/" + std::to_string(y) + ".png";
  }
  std::string Url(const std::string& path) const { return "http://127.0.0.1:" + std::to_string(port_) + path; }

  // Reads the 2x2 block at z 19 (512 x 512 px) through `source`; the centre of each quadrant must be its colour.
  void ExpectBlockRead(const std::string& source, const std::string& name, const std::string& env = "") {
    const double res = 2 * kHalf / std::ldexp(256.0, kZ);
    const double ulx = -kHalf + static_cast<double>(geo_.x0) * 256 * res;
    const double uly = kHalf - static_cast<double>(geo_.y0) * 256 * res;
    const fs::path out = root_ / (name + ".png");
    char win[256];
    std::snprintf(win, sizeof(win), "-projwin %.4f %.4f %.4f %.4f -projwin_srs EPSG:3857", ulx, uly, ulx + 512 * res,
                  uly - 512 * res);
    const std::string log = test::CommandOutput(Env() + env + "gdal_translate -q -of PNG -outsize 512 512 " + win +
                                                " '" + source + "' " + out.string() + " 2>&1");
    const cv::Mat img = cv::imread(out.string(), cv::IMREAD_UNCHANGED);
    ASSERT_FALSE(img.empty()) << name << ": " << log;
    ASSERT_EQ(img.channels(), 4) << name;
    for (int i = 0; i < 4; ++i) {
      const cv::Rect quadrant((i % 2) * 256 + 32, (i / 2) * 256 + 32, 192, 192);
      const cv::Scalar mean = cv::mean(img(quadrant));
      for (int c = 0; c < 4; ++c) EXPECT_NEAR(mean[c], kColours[i][c], 2.0) << name << " tile " << i << " band " << c;
    }
  }
  std::string Env() const {
    return "GDAL_DEFAULT_WMS_CACHE_PATH=" + (root_ / "gdal_cache").string() +
           " GDAL_HTTP_TIMEOUT=10 no_proxy=127.0.0.1 NO_PROXY=127.0.0.1 ";
  }

  static inline fs::path root_;
  static inline GeoSet geo_;
  static inline TileSetInfo local_;
  static inline bool keep_ = false;
  app::LiveServer server_;
  int port_ = 0;
  std::unique_ptr<httplib::Client> client_;
};

TEST_F(LiveTilesHttpTest, NothingPublishedYet) {
  auto r = client_->Get(Tile(kZ, geo_.x0, geo_.y0));
  ASSERT_TRUE(r);
  EXPECT_EQ(r->status, 404);
  EXPECT_EQ(r->get_header_value("Cache-Control"), "no-cache");
  for (const char* p : {"/tiles.json", "/wmts/1.0.0/WMTSCapabilities.xml", "/tiles.xml"}) {
    r = client_->Get(p);
    ASSERT_TRUE(r) << p;
    EXPECT_EQ(r->status, 404) << p;
  }
  r = client_->Get("/status.json");
  ASSERT_TRUE(r);
  EXPECT_TRUE(nlohmann::json::parse(r->body).at("tiles").is_null());
  r = client_->Get("/footprints.geojson");
  ASSERT_TRUE(r);
  EXPECT_EQ(r->status, 200);
  EXPECT_EQ(r->get_header_value("Cache-Control"), "no-store");
  const auto fc = nlohmann::json::parse(r->body);
  EXPECT_EQ(fc["type"], "FeatureCollection");
  EXPECT_TRUE(fc["features"].empty());
  // The live page still shows the picture until a tile set comes.
  r = client_->Get("/");
  ASSERT_TRUE(r);
  EXPECT_NE(r->body.find("/live.jpg"), std::string::npos);
}

// The operator's base map reaches the page as a JS string that cannot end the script.
TEST_F(LiveTilesHttpTest, BasemapOptionOnThePage) {
  server_.Stop();
  app::LiveServer::Options o;
  o.port = 0;
  o.basemap_url = "https://tile.example/{z}/{x}/{y}.png</script>";
  std::string error;
  ASSERT_TRUE(server_.Start(o, &error)) << error;
  httplib::Client c("127.0.0.1", server_.port());
  auto r = c.Get("/");
  ASSERT_TRUE(r);
  EXPECT_NE(r->body.find(R"("https://tile.example/{z}/{x}/{y}.png\u003c/script>")"), std::string::npos);
  EXPECT_EQ(r->body.find("png</script>"), std::string::npos);
  EXPECT_NE(r->body.find("get('basemap')"), std::string::npos);  // /?basemap= overrides it
}

TEST_F(LiveTilesHttpTest, TileEtagRevalidationAndCacheControl) {
  PublishGeo();
  const std::string path = Tile(kZ, geo_.x0 + 1, geo_.y0);
  auto r = client_->Get(path);
  ASSERT_TRUE(r);
  ASSERT_EQ(r->status, 200);
  EXPECT_EQ(r->get_header_value("Content-Type"), "image/png");
  EXPECT_EQ(r->get_header_value("Cache-Control"), "no-cache");
  EXPECT_EQ(Decode(r->body, 10, 10), kColours[1]);
  const std::string etag = r->get_header_value("ETag");
  ASSERT_GE(etag.size(), 3u);
  EXPECT_EQ(etag.front(), '"');
  EXPECT_EQ(etag.back(), '"');
  // Revalidation: 304 without a body; weak and listed forms too.
  for (const std::string& inm : {etag, "W/" + etag, "\"other\", " + etag}) {
    r = client_->Get(path, {{"If-None-Match", inm}});
    ASSERT_TRUE(r);
    EXPECT_EQ(r->status, 304) << inm;
    EXPECT_TRUE(r->body.empty());
  }
  r = client_->Get(path, {{"If-None-Match", "\"3-1-1\""}});
  ASSERT_TRUE(r);
  EXPECT_EQ(r->status, 200);
  // HEAD: the headers, no body. A query (the page's ?v= bump) is ignored.
  r = client_->Head(path);
  ASSERT_TRUE(r);
  EXPECT_EQ(r->status, 200);
  EXPECT_EQ(r->get_header_value("ETag"), etag);
  EXPECT_TRUE(r->body.empty());
  r = client_->Get(path + "?v=3.1000.4");
  ASSERT_TRUE(r);
  EXPECT_EQ(r->status, 200);
  EXPECT_EQ(r->get_header_value("ETag"), etag);
  // The tile is redrawn: a new ETag, the old one no longer matches.
  const fs::path tmp = root_ / "redrawn";
  WriteTile(tmp, kZ, 0, 0, cv::Mat(kTileSize, kTileSize, CV_8UC4, cv::Scalar(0, 255, 255, 255)));
  const fs::path file =
      fs::path(geo_.info.dir) / std::to_string(kZ) / std::to_string(geo_.x0 + 1) / (std::to_string(geo_.y0) + ".png");
  const fs::path saved = root_ / "saved.png";
  fs::copy_file(file, saved, fs::copy_options::overwrite_existing);
  fs::rename(tmp / std::to_string(kZ) / "0" / "0.png", file);
  r = client_->Get(path, {{"If-None-Match", etag}});
  fs::rename(saved, file);  // the other tests read the original
  ASSERT_TRUE(r);
  EXPECT_EQ(r->status, 200);
  EXPECT_NE(r->get_header_value("ETag"), etag);
  EXPECT_EQ(Decode(r->body, 10, 10), cv::Vec4b(0, 255, 255, 255));
  // The end-of-flight tiles no longer change: cacheable.
  PublishGeo(true);
  r = client_->Get(path);
  ASSERT_TRUE(r);
  EXPECT_EQ(r->status, 200);
  EXPECT_EQ(r->get_header_value("Cache-Control"), "public, max-age=3600");
}

TEST_F(LiveTilesHttpTest, MissingAndOutOfRangeTilesAre404) {
  PublishGeo();
  const int64_t x = geo_.x0, y = geo_.y0;
  const std::vector<std::string> paths = {Tile(kZ, x + 2, y),              // on the grid, not drawn
                                          Tile(kZ - 1, x / 2 + 5, y / 2),  // idem at z 18
                                          Tile(16, x / 8, y / 8),          // below min_zoom
                                          Tile(20, x * 2, y * 2),          // above max_zoom
                                          Tile(17, int64_t{1} << 17, 0),   // x = 2^z
                                          Tile(17, 0, int64_t{1} << 17),   // y = 2^z
                                          Tile(30, 0, 0),
                                          "/tiles/999999999/0/0.png"};
  for (const auto& p : paths) {
    auto r = client_->Get(p);
    ASSERT_TRUE(r) << p;
    EXPECT_EQ(r->status, 404) << p;
    EXPECT_EQ(r->get_header_value("Cache-Control"), "no-cache") << p;
  }
}

// Sent raw, so that no client normalises them; the server must never answer 200 (or 500) to any of them.
TEST_F(LiveTilesHttpTest, MalformedPathsAndTraversalAre400) {
  PublishGeo();
  // A file next to the tile directory that a traversal would reach.
  std::FILE* f = std::fopen((root_ / "secret.png").c_str(), "w");
  ASSERT_NE(f, nullptr);
  std::fputs("secret", f);
  std::fclose(f);
  const std::string z = std::to_string(kZ), x = std::to_string(geo_.x0), y = std::to_string(geo_.y0);
  const std::vector<std::string> bad = {"/tiles/../../etc/passwd",
                                        "/tiles/1/%2e%2e/1.png",
                                        "/tiles/-1/0/0.png",
                                        "/tiles/+1/0/0.png",
                                        "/tiles/%2e%2e/%2e%2e/secret.png",
                                        "/tiles/" + z + "/../../secret.png",
                                        "/tiles/" + z + "/" + x + "/..%2fsecret.png",
                                        "/tiles/" + z + "/" + x + "/" + y + ".jpg",
                                        "/tiles/" + z + "/" + x + "/" + y,
                                        "/tiles/" + z + "/" + x + ".png",
                                        "/tiles/" + z + "/" + x + "/" + y + "/0.png",
                                        "/tiles/" + z + "/0" + x + "/" + y + ".png",
                                        "/tiles/" + z + "/" + x + "/" + y + ".png.png",
                                        "/tiles/" + z + "/" + x + "/%20" + y + ".png",
                                        "/tiles/" + z + "/0x1f/" + y + ".png",
                                        "/tiles/" + z + "/" + x + "/" + y + "%00.png",
                                        "/tiles/",
                                        "/tiles//0/0.png",
                                        "/tiles/1e3/0/0.png"};
  for (const auto& p : bad) EXPECT_EQ(RawGet(port_, p), 400) << p;
  const int huge = RawGet(port_, "/tiles/99999999999999999999/0/0.png");
  EXPECT_TRUE(huge == 400 || huge == 404) << huge;
  const int huge_x = RawGet(port_, "/tiles/" + z + "/99999999999999999999/" + y + ".png");
  EXPECT_TRUE(huge_x == 400 || huge_x == 404) << huge_x;
  // The genuine tile through the same raw path: the harness itself works.
  EXPECT_EQ(RawGet(port_, "/tiles/" + z + "/" + x + "/" + y + ".png"), 200);
}

TEST_F(LiveTilesHttpTest, SlowClientsDoNotStopOthers) {
  PublishGeo();
  // Three clients send half a request and stall: three of the four workers wait on them (2 s read timeout).
  std::vector<int> slow;
  for (int i = 0; i < 3; ++i) {
    slow.push_back(StalledClient(port_));
    ASSERT_GE(slow.back(), 0);
  }
  ASSERT_TRUE(WaitUntil([&] { return server_.working() == 3; }));
  const auto t0 = Clock::now();
  int ok = 0;
  double worst_ms = 0;
  for (int i = 0; i < 20; ++i) {
    const auto t = Clock::now();
    auto r = client_->Get(Tile(kZ, geo_.x0 + i % 2, geo_.y0 + i / 2 % 2));
    worst_ms = std::max(worst_ms, std::chrono::duration<double, std::milli>(Clock::now() - t).count());
    ok += r && r->status == 200;
  }
  const double total_ms = std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
  std::printf("with 3 stalled clients: 20 tiles in %.0f ms (slowest %.0f ms)\n", total_ms, worst_ms);
  EXPECT_EQ(ok, 20);
  EXPECT_LT(total_ms, 1500);
  // The stalled connections are closed by the server's read timeout, not held for ever.
  for (const int fd : slow) {
    timeval tv{5, 0};
    ::setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof(tv));
    char buf[256];
    const auto t = Clock::now();
    const ssize_t n = ::recv(fd, buf, sizeof(buf), 0);
    EXPECT_GE(n, 0);  // an answer (400) or the close, not the receive timeout
    EXPECT_LT(std::chrono::duration<double>(Clock::now() - t).count(), 4.0);
    ::close(fd);
  }
}

// A pool with no room left answers at once: 503 with Retry-After, from the accepting thread.
TEST_F(LiveTilesHttpTest, FullPoolAnswers503) {
  server_.Stop();
  app::LiveServer::Options o;
  o.port = 0;
  o.threads = 1;
  o.queue = 1;
  std::string error;
  ASSERT_TRUE(server_.Start(o, &error)) << error;
  PublishGeo();
  // One in the worker, then one in the queue: each waited for, since on a loaded machine the second could otherwise
  // arrive before the worker took the first and be the one refused.
  std::vector<int> stalled;
  stalled.push_back(StalledClient(server_.port()));
  ASSERT_GE(stalled.back(), 0);
  ASSERT_TRUE(WaitUntil([&] { return server_.working() == 1; }));
  stalled.push_back(StalledClient(server_.port()));
  ASSERT_GE(stalled.back(), 0);
  ASSERT_TRUE(WaitUntil([&] { return server_.queued() == 1; }));
  httplib::Client c("127.0.0.1", server_.port());
  c.set_read_timeout(5, 0);
  const auto t = Clock::now();
  auto r = c.Get(Tile(kZ, geo_.x0, geo_.y0));
  const double ms = std::chrono::duration<double, std::milli>(Clock::now() - t).count();
  ASSERT_TRUE(r);
  EXPECT_EQ(r->status, 503);
  EXPECT_EQ(r->get_header_value("Retry-After"), "1");
  EXPECT_LT(ms, 1000);
  EXPECT_EQ(server_.refused(), 1);
  for (const int fd : stalled) ::close(fd);
}

TEST_F(LiveTilesHttpTest, FiftyParallelClients) {
  PublishGeo();
  constexpr int kClients = 50, kEach = 4;
  std::atomic<int> ok{0}, busy{0}, bad{0};
  std::latch start(kClients);
  std::vector<std::thread> threads;
  for (int c = 0; c < kClients; ++c)
    threads.emplace_back([&, c] {
      httplib::Client client("127.0.0.1", port_);
      client.set_read_timeout(5, 0);
      start.arrive_and_wait();
      for (int i = 0; i < kEach; ++i) {
        const int k = (c + i) % 4;
        auto r = client.Get(Tile(kZ, geo_.x0 + k % 2, geo_.y0 + k / 2));
        if (r && r->status == 200 && Decode(r->body, 128, 128) == kColours[k])
          ++ok;
        else if (r && r->status == 503 && r->get_header_value("Retry-After") == "1")
          ++busy;
        else
          ++bad;
      }
    });
  for (auto& t : threads) t.join();
  std::printf("50 parallel clients x 4 tiles: %d x 200, %d x 503, %d other (refused counter %ld)\n", ok.load(),
              busy.load(), bad.load(), server_.refused());
  EXPECT_EQ(bad.load(), 0);
  EXPECT_EQ(ok.load() + busy.load(), kClients * kEach);
  EXPECT_GE(ok.load(), kClients * kEach * 8 / 10);
  EXPECT_EQ(server_.refused(), busy.load());
}

TEST_F(LiveTilesHttpTest, TileJsonAndStatus) {
  PublishGeo();
  auto r = client_->Get("/tiles.json");
  ASSERT_TRUE(r);
  ASSERT_EQ(r->status, 200);
  EXPECT_EQ(r->get_header_value("Cache-Control"), "no-cache");
  const auto j = nlohmann::json::parse(r->body);
  EXPECT_EQ(j["tilejson"], "3.0.0");
  ASSERT_EQ(j["tiles"].size(), 1u);
  EXPECT_EQ(j["tiles"][0], Url("/tiles/{z}/{x}/{y}.png"));
  // Without an access token a query token is nobody's credential: it never reaches the documents.
  const auto open_xml = client_->Get("/tiles.xml?token=%22%2F%3E%3Cscript%3E");
  ASSERT_TRUE(open_xml);
  EXPECT_EQ(open_xml->body.find("token="), std::string::npos) << open_xml->body;
  EXPECT_EQ(j["minzoom"], 17);
  EXPECT_EQ(j["maxzoom"], kZ);
  EXPECT_EQ(j["scheme"], "xyz");
  EXPECT_TRUE(j["name"].is_string());
  EXPECT_TRUE(j["attribution"].is_string());
  const auto& b = j["bounds"];
  ASSERT_EQ(b.size(), 4u);
  EXPECT_NEAR(b[0].get<double>(), geo_.info.west, 1e-9);
  EXPECT_NEAR(b[1].get<double>(), geo_.info.south, 1e-9);
  EXPECT_NEAR(b[2].get<double>(), geo_.info.east, 1e-9);
  EXPECT_NEAR(b[3].get<double>(), geo_.info.north, 1e-9);
  EXPECT_LT(b[0].get<double>(), -0.09);  // around 50.8N 0.1W
  EXPECT_NEAR(b[3].get<double>(), 50.8, 0.01);
  const auto& c = j["center"];
  ASSERT_EQ(c.size(), 3u);
  EXPECT_TRUE(c[0].get<double>() > geo_.info.west && c[0].get<double>() < geo_.info.east);
  EXPECT_TRUE(c[1].get<double>() > geo_.info.south && c[1].get<double>() < geo_.info.north);
  EXPECT_TRUE(c[2].get<int>() >= 17 && c[2].get<int>() <= kZ);
  EXPECT_EQ(j["uavmosaic"]["geographic"], true);
  EXPECT_EQ(j["uavmosaic"]["generation"], 3);
  EXPECT_EQ(j["uavmosaic"]["final"], false);
  EXPECT_EQ(j["uavmosaic"]["frames"], 4);
  const std::string etag = r->get_header_value("ETag");
  ASSERT_FALSE(etag.empty());
  r = client_->Get("/tiles.json", {{"If-None-Match", etag}});
  ASSERT_TRUE(r);
  EXPECT_EQ(r->status, 304);
  // A Host header that is not a plain host:port never reaches the documents.
  r = client_->Get("/tiles.json", {{"Host", "evil\"><x"}});
  ASSERT_TRUE(r);
  EXPECT_EQ(r->body.find("evil"), std::string::npos);
  EXPECT_EQ(nlohmann::json::parse(r->body)["tiles"][0], Url("/tiles/{z}/{x}/{y}.png"));
  // status.json carries the set.
  r = client_->Get("/status.json");
  ASSERT_TRUE(r);
  const auto t = nlohmann::json::parse(r->body).at("tiles");
  EXPECT_EQ(t["generation"], 3);
  EXPECT_EQ(t["geographic"], true);
  EXPECT_EQ(t["min_zoom"], 17);
  EXPECT_EQ(t["max_zoom"], kZ);
  EXPECT_EQ(t["bounds"].size(), 4u);
  EXPECT_EQ(t["frames"], 4);
  EXPECT_EQ(t["final"], false);
  EXPECT_EQ(t["updated_ns"], 1000);
}

TEST_F(LiveTilesHttpTest, LocalSetIsServedButNotAsWmts) {
  server_.PublishTiles(std::make_shared<TileSetInfo>(local_));
  auto r = client_->Get("/tiles/2/2/1.png");  // the map's bottom-right tile (orange, partly transparent)
  ASSERT_TRUE(r);
  ASSERT_EQ(r->status, 200);
  EXPECT_EQ(Decode(r->body, 10, 10), cv::Vec4b(0, 128, 255, 255));
  EXPECT_EQ(Decode(r->body, 100, 200), cv::Vec4b(0, 0, 0, 0));  // beyond the map's 600 x 400 pixels
  r = client_->Get("/tiles/0/0/0.png");
  ASSERT_TRUE(r);
  EXPECT_EQ(r->status, 200);
  for (const char* p : {"/tiles/2/3/0.png", "/tiles/2/0/2.png", "/tiles/3/0/0.png"}) {
    r = client_->Get(p);
    ASSERT_TRUE(r);
    EXPECT_EQ(r->status, 404) << p;  // beyond the map's extent or levels
  }
  r = client_->Get("/tiles.json");
  ASSERT_TRUE(r);
  const auto j = nlohmann::json::parse(r->body);
  EXPECT_EQ(j["uavmosaic"]["geographic"], false);
  EXPECT_EQ(j["uavmosaic"]["crs"], "CRS.Simple");
  EXPECT_NE(j["uavmosaic"]["bounds_units"].get<std::string>().find("not WGS84"), std::string::npos);
  EXPECT_EQ(j["bounds"][2], 150.0);
  EXPECT_EQ(j["bounds"][1], -100.0);
  for (const char* p : {"/wmts/1.0.0/WMTSCapabilities.xml", "/WMTSCapabilities.xml", "/tiles.xml"}) {
    r = client_->Get(p);
    ASSERT_TRUE(r) << p;
    EXPECT_EQ(r->status, 404) << p;
    EXPECT_NE(r->body.find("not georeferenced"), std::string::npos) << r->body;
  }
}

TEST_F(LiveTilesHttpTest, FootprintsAsPublished) {
  const auto geojson = std::make_shared<const std::string>(
      R"({"type":"FeatureCollection","features":[{"type":"Feature","properties":{"frame":1},)"
      R"("geometry":{"type":"Polygon","coordinates":[[[-0.1,50.8],[-0.099,50.8],[-0.099,50.801],[-0.1,50.8]]]}}]})");
  server_.PublishFootprints(geojson);
  auto r = client_->Get("/footprints.geojson");
  ASSERT_TRUE(r);
  EXPECT_EQ(r->status, 200);
  EXPECT_EQ(r->get_header_value("Content-Type"), "application/geo+json");
  EXPECT_EQ(r->get_header_value("Cache-Control"), "no-store");
  EXPECT_EQ(r->body, *geojson);
}

// The real clients: GDAL opens the WMTS capabilities and the XYZ description and reads the z-19 block back.
TEST_F(LiveTilesHttpTest, WmtsCapabilitiesAndXyzDescriptionReadTheTiles) {
  if (std::system("command -v gdal_translate >/dev/null 2>&1") != 0) GTEST_SKIP() << "gdal-bin missing";
  PublishGeo();
  auto r = client_->Get("/wmts/1.0.0/WMTSCapabilities.xml");
  ASSERT_TRUE(r);
  ASSERT_EQ(r->status, 200);
  EXPECT_NE(r->body.find("template=\"" + Url("/tiles/{TileMatrix}/{TileCol}/{TileRow}.png") + "\""), std::string::npos);
  // Where tiles exist, per level (the block is 2x2 tiles at z 19, one tile at z 18 and 17).
  const auto limits = [](int z, int64_t row0, int64_t row1, int64_t col0, int64_t col1) {
    return "<TileMatrix>" + std::to_string(z) + "</TileMatrix><MinTileRow>" + std::to_string(row0) +
           "</MinTileRow><MaxTileRow>" + std::to_string(row1) + "</MaxTileRow><MinTileCol>" + std::to_string(col0) +
           "</MinTileCol><MaxTileCol>" + std::to_string(col1) + "</MaxTileCol>";
  };
  EXPECT_NE(r->body.find(limits(kZ, geo_.y0, geo_.y0 + 1, geo_.x0, geo_.x0 + 1)), std::string::npos) << r->body;
  EXPECT_NE(r->body.find(limits(18, geo_.y0 / 2, geo_.y0 / 2, geo_.x0 / 2, geo_.x0 / 2)), std::string::npos);
  EXPECT_NE(r->body.find(limits(17, geo_.y0 / 4, geo_.y0 / 4, geo_.x0 / 4, geo_.x0 / 4)), std::string::npos);
  EXPECT_EQ(r->body.find("<TileMatrix>16</TileMatrix><Min"), std::string::npos);
  const fs::path caps = root_ / "caps.xml";
  {
    std::FILE* f = std::fopen(caps.c_str(), "w");
    ASSERT_NE(f, nullptr);
    std::fwrite(r->body.data(), 1, r->body.size(), f);
    std::fclose(f);
  }
  if (std::system("command -v xmllint >/dev/null 2>&1") == 0) {
    EXPECT_EQ(std::system(("xmllint --noout " + caps.string()).c_str()), 0) << "not well-formed";
  }
  r = client_->Get("/WMTSCapabilities.xml");
  ASSERT_TRUE(r);
  EXPECT_EQ(r->status, 200);

  const std::string wmts = "WMTS:" + Url("/wmts/1.0.0/WMTSCapabilities.xml");
  const std::string info = test::CommandOutput(Env() + "gdalinfo '" + wmts + "' 2>&1");
  EXPECT_NE(info.find("Driver: WMTS"), std::string::npos) << info;
  EXPECT_NE(info.find("uavmosaic"), std::string::npos) << info;
  EXPECT_NE(info.find("3857"), std::string::npos) << info;
  EXPECT_NE(info.find("Band 4"), std::string::npos) << info;
  ExpectBlockRead(wmts, "via_wmts");

  r = client_->Get("/tiles.xml");
  ASSERT_TRUE(r);
  ASSERT_EQ(r->status, 200);
  const fs::path desc = root_ / "tiles.xml";
  {
    std::FILE* f = std::fopen(desc.c_str(), "w");
    ASSERT_NE(f, nullptr);
    std::fwrite(r->body.data(), 1, r->body.size(), f);
    std::fclose(f);
  }
  const std::string xyz_info = test::CommandOutput(Env() + "gdalinfo " + desc.string() + " 2>&1");
  EXPECT_NE(xyz_info.find("Driver: WMS"), std::string::npos) << xyz_info;
  ExpectBlockRead(desc.string(), "via_tiles_xml");
  // GDAL can also open the description straight from the server.
  ExpectBlockRead(Url("/tiles.xml"), "via_tiles_xml_url");
}

TEST_F(LiveTilesHttpTest, LivePageShowsTheTiles) {
  if (test::ChromiumBinary().empty()) GTEST_SKIP() << "chromium missing: run scripts/setup.sh";
  PublishGeo();
  // The frames' footprints: the block's four tiles.
  nlohmann::json fc = {{"type", "FeatureCollection"}, {"features", nlohmann::json::array()}};
  for (int i = 0; i < 4; ++i) {
    const int64_t x = geo_.x0 + i % 2, y = geo_.y0 + i / 2;
    const double w = TileLon(x, kZ), e = TileLon(x + 1, kZ), n = TileLat(y, kZ), s = TileLat(y + 1, kZ);
    const nlohmann::json ring = {{w, n}, {e, n}, {e, s}, {w, s}, {w, n}};
    nlohmann::json feature = {{"type", "Feature"}, {"properties", {{"frame", i}}}};
    feature["geometry"] = {{"type", "Polygon"}, {"coordinates", nlohmann::json::array({ring})}};
    fc["features"].push_back(feature);
  }
  server_.PublishFootprints(std::make_shared<const std::string>(fc.dump()));
  const long before = server_.served();
  const cv::Mat shot = test::Screenshot(Url("/"), root_ / "browser", 5000);
  ASSERT_FALSE(shot.empty());
  // Each tile's colour covers a good part of the view (the view follows the footprints: the whole block).
  std::printf("live page over the tiles (%ld requests):", server_.served() - before);
  for (int i = 0; i < 4; ++i) {
    const cv::Vec3b bgr(kColours[i][0], kColours[i][1], kColours[i][2]);
    cv::Mat diff, mask;
    cv::absdiff(shot, cv::Scalar(bgr[0], bgr[1], bgr[2]), diff);
    cv::cvtColor(diff, mask, cv::COLOR_BGR2GRAY);
    const double share = static_cast<double>(cv::countNonZero(mask < 12)) / static_cast<double>(mask.total());
    std::printf(" colour %d %.0f %%", i, 100 * share);
    EXPECT_GT(share, 0.03) << "tile colour " << i;
  }
  std::printf("\n");
  // Red (top-left tile) lies left of green and above blue: the tiles are in their places.
  cv::Mat red, green, blue;
  cv::inRange(shot, cv::Scalar(0, 0, 240), cv::Scalar(15, 15, 255), red);
  cv::inRange(shot, cv::Scalar(0, 185, 0), cv::Scalar(15, 215, 15), green);
  cv::inRange(shot, cv::Scalar(240, 0, 0), cv::Scalar(255, 15, 15), blue);
  const cv::Moments mr = cv::moments(red, true), mg = cv::moments(green, true), mb = cv::moments(blue, true);
  ASSERT_GT(mr.m00, 0);
  ASSERT_GT(mg.m00, 0);
  ASSERT_GT(mb.m00, 0);
  EXPECT_LT(mr.m10 / mr.m00, mg.m10 / mg.m00);
  EXPECT_LT(mr.m01 / mr.m00, mb.m01 / mb.m00);
}

}  // namespace
}  // namespace uavm

namespace uavm {
namespace {

// A test CA and a server certificate it signed for 127.0.0.1 (openssl, EC P-256: fast), in `dir`.
bool MakeTestCertificates(const fs::path& dir) {
  fs::create_directories(dir);
  const std::string d = "'" + dir.string() + "/";
  const std::string ec = " -newkey ec -pkeyopt ec_paramgen_curve:prime256v1 -nodes";
  {
    std::ofstream ext(dir / "ext.cnf");
    ext << "subjectAltName=IP:127.0.0.1,DNS:localhost\nbasicConstraints=CA:FALSE\n";
  }
  const std::string cmd = "openssl req -x509" + ec + " -keyout " + d + "ca.key' -out " + d +
                          "ca.pem' -days 2 -subj '/CN=uavmosaic test CA' && openssl req" + ec + " -keyout " + d +
                          "server.key' -out " + d + "server.csr' -subj '/CN=127.0.0.1' && openssl x509 -req -in " + d +
                          "server.csr' -CA " + d + "ca.pem' -CAkey " + d + "ca.key' -CAcreateserial -out " + d +
                          "server.pem' -days 2 -extfile " + d + "ext.cnf' 2>&1";
  const std::string log = test::CommandOutput(cmd);
  const bool ok = fs::exists(dir / "server.pem") && fs::exists(dir / "server.key");
  if (!ok) std::printf("openssl: %s\n", log.c_str());
  return ok;
}

// The server behind a token and TLS (issue 39): curl and GDAL with the test CA and the token read the map; without
// the CA the connection is refused by the client, without the token every route answers 401, and wrong tokens from
// one address are rate-limited (429) and counted.
TEST_F(LiveTilesHttpTest, HttpsWithATokenForCurlAndGdal) {
  if (std::system("command -v openssl >/dev/null 2>&1 && command -v curl >/dev/null 2>&1") != 0)
    GTEST_SKIP() << "openssl or curl missing: run scripts/setup.sh";
  const fs::path tls = root_ / "tls";
  ASSERT_TRUE(MakeTestCertificates(tls));
  server_.Stop();
  const std::string token = "test-token-0123456789abcdef";
  app::LiveServer::Options o;
  o.port = 0;
  o.token = token;
  o.access.max_failures = 3;
  o.cert_file = (tls / "server.pem").string();
  o.key_file = (tls / "server.key").string();
  std::string error;
  ASSERT_TRUE(server_.Start(o, &error)) << error;
  PublishGeo();
  const std::string base = "https://127.0.0.1:" + std::to_string(server_.port());
  const std::string ca = " --cacert '" + (tls / "ca.pem").string() + "'";
  const auto curl = [&](const std::string& args) {
    return test::CommandOutput("curl -s -o /dev/null -w '%{http_code}' --noproxy '*' " + args + "; echo \" rc=$?\"");
  };
  EXPECT_EQ(curl(ca + " -H 'Authorization: Bearer " + token + "' " + base + "/status.json"), "200 rc=0\n");
  EXPECT_EQ(curl(ca + " '" + base + "/tiles.json?token=" + token + "'"), "200 rc=0\n");
  EXPECT_EQ(curl(ca + " " + base + "/status.json"), "401 rc=0\n");
  // Without the test CA, curl does not trust the server (60: the certificate cannot be verified).
  EXPECT_EQ(curl(base + "/status.json"), "000 rc=60\n");
  // Plain HTTP to the TLS port gets nothing.
  EXPECT_NE(curl("http://127.0.0.1:" + std::to_string(server_.port()) + "/status.json").substr(0, 3), "200");

  // GDAL through the WMTS capabilities with the token in the URL: the tile template it is given is https:// and
  // carries the token on.
  const std::string wmts = "WMTS:" + base + "/wmts/1.0.0/WMTSCapabilities.xml?token=" + token;
  const std::string trusted = "CURL_CA_BUNDLE='" + (tls / "ca.pem").string() + "' ";
  const std::string caps = test::CommandOutput("curl -s --noproxy '*'" + ca + " '" + base +
                                               "/wmts/1.0.0/WMTSCapabilities.xml?token=" + token + "'");
  EXPECT_NE(caps.find("template=\"" + base + "/tiles/{TileMatrix}/{TileCol}/{TileRow}.png?token=" + token + "\""),
            std::string::npos)
      << caps;
  ExpectBlockRead(wmts, "via_https_wmts", trusted);
  // The XYZ description (GDAL's WMS driver) verifies the server: without the test CA it reads nothing. (GDAL 3.6's
  // WMTS driver fetches without verifying certificates, whatever the CA: a client-side choice.)
  const std::string xyz = base + "/tiles.xml?token=" + token;
  const std::string untrusted_info = test::CommandOutput(Env() + "CPL_CURL_VERBOSE=YES gdalinfo '" + xyz + "' 2>&1");
  EXPECT_EQ(untrusted_info.find("Driver: WMS"), std::string::npos) << untrusted_info;
  EXPECT_NE(untrusted_info.find("certificate verification failed"), std::string::npos) << untrusted_info;
  ExpectBlockRead(xyz, "via_https_tiles_xml", trusted);

  // A query that was not the credential (a Bearer header was) never reaches a document, whatever it holds.
  const std::string evil = "%22%2F%3E%3Cscript%3E";
  const std::string with_bearer = test::CommandOutput("curl -s --noproxy '*'" + ca + " -H 'Authorization: Bearer " +
                                                      token + "' '" + base + "/tiles.xml?token=" + evil + "'");
  EXPECT_NE(with_bearer.find("<GDAL_WMS>"), std::string::npos) << with_bearer;
  EXPECT_EQ(with_bearer.find("token="), std::string::npos) << with_bearer;

  // Wrong tokens: refused, then the address is locked out (even with the right token), and it all shows in the status.
  httplib::SSLClient client("127.0.0.1", server_.port());
  client.set_ca_cert_path((tls / "ca.pem").c_str());
  client.enable_server_certificate_verification(true);
  client.set_read_timeout(5, 0);
  for (int i = 0; i < 3; ++i) {
    const auto r = client.Get(("/tiles.json?token=guess-number-" + std::to_string(i) + "-of-many").c_str());
    ASSERT_TRUE(r) << httplib::to_string(r.error());
    EXPECT_EQ(r->status, 401);
    EXPECT_EQ(r->get_header_value("WWW-Authenticate"), "Bearer realm=\"uavmosaic\"");
  }
  client.set_bearer_token_auth(token.c_str());
  const auto locked = client.Get("/status.json");
  ASSERT_TRUE(locked);
  EXPECT_EQ(locked->status, 429);
  EXPECT_GE(std::stoi(locked->get_header_value("Retry-After")), 1);
  const auto counters = server_.access_counters();
  std::printf("access: %llu allowed, %llu unauthorized (%llu wrong tokens), %llu rate-limited, %llu lockouts\n",
              static_cast<unsigned long long>(counters.allowed), static_cast<unsigned long long>(counters.unauthorized),
              static_cast<unsigned long long>(counters.wrong_token),
              static_cast<unsigned long long>(counters.rate_limited),
              static_cast<unsigned long long>(counters.lockouts));
  EXPECT_EQ(counters.wrong_token, 3u);
  EXPECT_EQ(counters.lockouts, 1u);
  EXPECT_GE(counters.rate_limited, 1u);
  EXPECT_GE(counters.allowed, 3u);
}

}  // namespace
}  // namespace uavm
