// The live view of uavmosaic-onboard (--http): /status.json, /live.jpg and the live Leaflet page while a replay runs
// (slowed with --process-delay-ms), concurrent clients on loopback, the georeference during the flight (status.json
// "georef", live.jgw + live.jpg.aux.xml read by gdalinfo), and a clean end of the run.
#include <arpa/inet.h>
#include <gtest/gtest.h>
#include <httplib.h>
#include <netinet/in.h>
#include <signal.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <array>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <sstream>
#include <thread>

#include "tests/browser_shot.h"
#include "tests/process_util.h"
#include "tests/test_env.h"
#include "tests/test_net.h"

namespace uavm {
namespace {

namespace fs = std::filesystem;
const std::string kData = UAVM_TEST_DATA;

// EXIF GPS (lat, lon) of the bundled flight's frames, in name order (its manifest).
std::vector<std::array<double, 2>> FlightGps(const std::string& manifest) {
  std::ifstream in(manifest);
  std::string line;
  std::getline(in, line);  // FileName,...,GPSLatitude,GPSLongitude,...
  std::vector<std::array<double, 2>> out;
  while (std::getline(in, line)) {
    std::vector<std::string> cols;
    std::stringstream ss(line);
    for (std::string c; std::getline(ss, c, ',');) cols.push_back(c);
    if (cols.size() > 9) out.push_back({std::stod(cols[8]), std::stod(cols[9])});
  }
  return out;
}

// Whether (lat, lon) lies inside the convex quadrilateral `corners` (a few hundred metres: planar will do).
bool InsideQuad(const nlohmann::json& corners, double lat, double lon) {
  const double k = std::cos(lat * M_PI / 180);
  int sign = 0;
  for (size_t i = 0; i < 4; ++i) {
    const auto& a = corners[i];
    const auto& b = corners[(i + 1) % 4];
    const double ax = (a[1].get<double>() - lon) * k, ay = a[0].get<double>() - lat;
    const double bx = (b[1].get<double>() - lon) * k, by = b[0].get<double>() - lat;
    const int s = ax * by - ay * bx > 0 ? 1 : -1;
    if (sign != 0 && s != sign) return false;
    sign = s;
  }
  return true;
}

// During the flight (state "flying") the status gets a georeference from the frames' EXIF GPS: the flight's UTM zone,
// a picture whose corners hold every drawn frame's position, and sidecars that make GDAL read live.jpg in that CRS.
void CheckLiveGeoref(httplib::Client* client, const fs::path& out) {
  nlohmann::json status;
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(60);
  while (std::chrono::steady_clock::now() < deadline) {
    auto res = client->Get("/status.json");
    if (res && res->status == 200) {
      status = nlohmann::json::parse(res->body);
      if (status["georef"].value("georeferenced", false) || status["state"] != "flying") break;
      EXPECT_TRUE(status["georef"].contains("reason"));
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(200));
  }
  ASSERT_FALSE(status.is_null());
  const nlohmann::json& g = status["georef"];
  std::printf("live georef at frame %d: %s\n", status["frames_in"].get<int>(), g.dump().c_str());
  ASSERT_EQ(status["state"], "flying") << "the flight ended before the live view was georeferenced";
  ASSERT_TRUE(g.value("georeferenced", false)) << g.dump();
  EXPECT_EQ(g["crs"], "EPSG:32615");  // 91.99 W, 46.84 N: UTM zone 15 N
  EXPECT_EQ(g["epsg"], 32615);
  EXPECT_LT(g["rms_m"].get<double>(), 5.0);
  EXPECT_GE(g["frames_used"].get<int>(), 3);
  ASSERT_EQ(g["corners"].size(), 4u);
  ASSERT_EQ(g["bounds"].size(), 4u);
  ASSERT_EQ(g["geotransform"].size(), 6u);
  // The picture of jpeg_seq holds the first jpeg_seq frames (--preview-every 1): each one's GPS position is on it.
  const auto gps = FlightGps(kData + "/brighton_beach_small/manifest.csv");
  const auto drawn = std::min<size_t>(gps.size(), status["jpeg_seq"].get<size_t>());
  ASSERT_GE(drawn, 3u);
  for (size_t i = 0; i < drawn; ++i) {
    const auto& b = g["bounds"];  // south, west, north, east
    EXPECT_TRUE(gps[i][0] > b[0].get<double>() && gps[i][0] < b[2].get<double>()) << "frame " << i;
    EXPECT_TRUE(gps[i][1] > b[1].get<double>() && gps[i][1] < b[3].get<double>()) << "frame " << i;
    EXPECT_TRUE(InsideQuad(g["corners"], gps[i][0], gps[i][1])) << "frame " << i;
  }
  // The picture carries its own corners (the page places it by them).
  auto jpg = client->Get("/live.jpg");
  ASSERT_TRUE(jpg);
  const auto corners = nlohmann::json::parse(jpg->get_header_value("X-Georef-Corners"));
  EXPECT_EQ(corners.size(), 4u);
  // GIS: live.jgw and live.jpg.aux.xml beside live.jpg.
  EXPECT_TRUE(fs::exists(out / "live.jgw"));
  const std::string info = test::CommandOutput("gdalinfo " + (out / "live.jpg").string() + " 2>&1");
  EXPECT_NE(info.find("WGS 84 / UTM zone 15N"), std::string::npos) << info;
  EXPECT_NE(info.find("ID[\"EPSG\",32615]"), std::string::npos) << info;
  EXPECT_NE(info.find("Upper Left  (  5"), std::string::npos) << info;  // easting 5xxxxx, not pixels
}

TEST(LiveHttpTest, StatusJpegAndLivePageDuringARun) {
  const fs::path out = fs::temp_directory_path() / ("uavm_live_http_" + std::to_string(::getpid()));
  fs::remove_all(out);
  const int port = test::FreePort();
  ASSERT_GT(port, 0);
  // Under emulation the first 8 frames (each takes longer there).
  const test::FlightForTest flight(kData + "/brighton_beach_small/images", 8, out.string() + "_in");
  // ~2.4 s per frame: the run lasts long enough to look at it.
  const pid_t pid =
      test::Spawn(std::string(UAVM_ONBOARD_BIN) + " --source replay:" + flight.string() + " --out " + out.string() +
                  " --http 127.0.0.1:" + std::to_string(port) +
                  " --process-delay-ms 1500 --preview-every 1 --log-level warn" + test::EmulationArgsString());
  ASSERT_GT(pid, 0);
  httplib::Client client("127.0.0.1", port);
  client.set_connection_timeout(1, 0);
  client.set_read_timeout(5, 0);
  // Wait for the server and the first picture.
  nlohmann::json status;
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(60);
  while (std::chrono::steady_clock::now() < deadline) {
    auto res = client.Get("/status.json");
    if (res && res->status == 200) {
      status = nlohmann::json::parse(res->body);
      if (status["jpeg_seq"].get<long>() > 0 && status["frames_in"].get<int>() >= 2) break;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(200));
  }
  ASSERT_FALSE(status.is_null()) << "no /status.json";
  for (const char* key : {"state", "frames_in", "registered", "dropped", "fps", "rss_mib", "budget_mib", "last_error",
                          "median_frame_ms", "jpeg_seq"})
    EXPECT_TRUE(status.contains(key)) << key;
  EXPECT_EQ(status["state"], "flying");
  EXPECT_GE(status["registered"].get<int>(), 1);
  EXPECT_LE(status["registered"].get<int>(), status["frames_in"].get<int>());
  EXPECT_GT(status["fps"].get<double>(), 0.0);
  EXPECT_GT(status["rss_mib"].get<double>(), 10.0);
  EXPECT_EQ(status["budget_mib"].get<double>(), 256.0);

  auto jpg = client.Get("/live.jpg");
  ASSERT_TRUE(jpg);
  ASSERT_EQ(jpg->status, 200);
  EXPECT_EQ(jpg->get_header_value("Content-Type"), "image/jpeg");
  const cv::Mat img = cv::imdecode(std::vector<uchar>(jpg->body.begin(), jpg->body.end()), cv::IMREAD_COLOR);
  ASSERT_FALSE(img.empty());
  cv::Scalar unused;
  EXPECT_GT(cv::countNonZero(img.reshape(1) > 20), static_cast<int>(img.total()) / 20);  // frames are drawn on it

  // Concurrent clients (bounded: 4 x 15 requests): every answer is 200, or 503 when the pool is full.
  std::atomic<int> ok{0}, busy{0}, bad{0};
  std::vector<std::thread> load;
  for (int t = 0; t < 4; ++t)
    load.emplace_back([&, t] {
      httplib::Client c("127.0.0.1", port);
      c.set_read_timeout(5, 0);
      for (int i = 0; i < 15; ++i) {
        auto r = c.Get((i + t) % 2 == 0 ? "/live.jpg" : "/status.json");
        if (r && r->status == 200)
          ++ok;
        else if (r && r->status == 503)
          ++busy;
        else
          ++bad;
      }
    });
  for (auto& th : load) th.join();
  EXPECT_EQ(bad.load(), 0);
  EXPECT_GT(ok.load(), 30);

  // The georeference arrives during the flight (EXIF GPS; the fourth frame spreads the positions over 30 m).
  CheckLiveGeoref(&client, out);

  // The live page in a real browser, from the server: it shows the live picture, laid on the map north-up.
  ASSERT_FALSE(test::ChromiumBinary().empty()) << "chromium missing: run scripts/setup.sh";
  const cv::Mat shot =
      test::ScreenshotUntilDrawn("http://127.0.0.1:" + std::to_string(port) + "/", out.string() + "_browser", 0.10);
  ASSERT_FALSE(shot.empty());
  cv::Scalar mean;
  const double share = test::ContentShare(shot, &mean);
  std::printf("live page: %.0f %% of the view is the live picture\n", 100 * share);
  EXPECT_GT(share, 0.10);
  const cv::Scalar ref = test::ContentMean(img);
  for (int c = 0; c < 3; ++c) EXPECT_NEAR(mean[c], ref[c], 30) << "channel " << c;

  // The operator ends the flight (SIGTERM, as systemd stops the service): the run finishes normally with what it
  // received, every frame of it registered despite the clients. Not waiting out the flight keeps the test short.
  ::kill(pid, SIGTERM);
  int wstatus = 0;
  ASSERT_EQ(::waitpid(pid, &wstatus, 0), pid);
  ASSERT_TRUE(WIFEXITED(wstatus));
  EXPECT_EQ(WEXITSTATUS(wstatus), 0);
  std::ifstream in(out / "report.json");
  const auto report = nlohmann::json::parse(in);
  EXPECT_GE(report["frames_decoded"].get<int>(), 2);
  EXPECT_LE(report["frames_decoded"].get<int>(), flight.frames());
  EXPECT_EQ(report["registered"].get<int>(), report["frames_decoded"].get<int>());
  // After the run the server is gone.
  EXPECT_FALSE(client.Get("/status.json"));
  if (!::testing::Test::HasFailure()) {
    fs::remove_all(out);
    fs::remove_all(out.string() + "_browser");
  }
}

TEST(LiveHttpTest, BadAddressIsAUsageError) {
  const std::string cmd = std::string(UAVM_ONBOARD_BIN) + " --source replay:" + kData +
                          "/brighton_beach_small/images --out /tmp/uavm_live_bad_" + std::to_string(::getpid()) +
                          " --http nonsense --log-level off";
  const int status = std::system(cmd.c_str());
  ASSERT_TRUE(WIFEXITED(status));
  EXPECT_EQ(WEXITSTATUS(status), 2);
  fs::remove_all("/tmp/uavm_live_bad_" + std::to_string(::getpid()));
}

// Off the loopback the live view needs an access token (issue 39): without one the program refuses to start (exit 2,
// saying why, before the session is made); so does a token file that holds no token, and a certificate without its
// key.
TEST(LiveHttpTest, OffTheLoopbackWithoutATokenRefusesToStart) {
  const fs::path out = fs::temp_directory_path() / ("uavm_live_noauth_" + std::to_string(::getpid()));
  fs::remove_all(out);
  const fs::path weak = out.string() + ".weak";
  std::ofstream(weak) << "1234\n";
  const std::string run = std::string(UAVM_ONBOARD_BIN) + " --source replay:" + kData +
                          "/brighton_beach_small/images --out " + out.string() + " --log-level error ";
  for (const auto& [args, why] : std::vector<std::pair<std::string, std::string>>{
           {"--http 0.0.0.0:0", "--http-token-file"},
           {"--http 192.0.2.1:8080", "--http-no-auth"},
           {"--http 0.0.0.0:0 --http-token-file " + weak.string(), "openssl rand"},
           {"--http 127.0.0.1:0 --http-cert /etc/hostname", "--http-key"}}) {
    const std::string log = test::CommandOutput(run + args + " 2>&1; echo \"exit=$?\"");
    EXPECT_NE(log.find("exit=2"), std::string::npos) << args << ": " << log;
    EXPECT_NE(log.find(why), std::string::npos) << args << ": " << log;
    EXPECT_FALSE(fs::exists(out)) << args;
  }
  fs::remove(weak);
}

}  // namespace
}  // namespace uavm
