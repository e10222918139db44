// Camera back-ends on real kernel video devices: vivid (V4L2) and vimc (libcamera), inside the test VM
// (tests/vm/vm_camera_test.sh boots it; tests/vm/guest.sh runs this binary there). Not registered with CTest on its
// own: on a host without these devices it has nothing to test, and says so by failing (--gtest_also_run_disabled is
// not used; the VM script is what runs it).
#include <arpa/inet.h>
#include <fcntl.h>
#include <gtest/gtest.h>
#include <linux/videodev2.h>
#include <netinet/in.h>
#include <poll.h>
#include <signal.h>
#include <sys/ioctl.h>
#include <sys/mman.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/sysmacros.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <sstream>
#include <thread>

#include "core/util/clock.h"
#include "hal/common/camera_options.h"
#include "hal/v4l2/v4l2_device.h"
#include "hal/v4l2/v4l2_source.h"
#ifdef UAVM_HAVE_LIBCAMERA
#include "hal/libcamera/libcamera_source.h"
#endif

namespace uavm::hal {
namespace {

namespace fs = std::filesystem;

// Results (rates, images) go where the VM script collects them.
fs::path ResultsDir() {
  const char* d = std::getenv("UAVM_VM_RESULTS");
  return d != nullptr ? fs::path(d) : fs::temp_directory_path();
}

void Note(const std::string& line) {
  std::printf("%s\n", line.c_str());
  std::ofstream(ResultsDir() / "rates.txt", std::ios::app) << line << "\n";
}

// The node of the driver named `driver` ("vivid"), or "".
std::string FindNode(const std::string& driver) {
  for (const auto& d : ListV4l2Devices())
    if (d.driver == driver && d.capture) return d.path;
  return "";
}

struct Captured {
  std::vector<cv::Mat> images;
  std::vector<int64_t> timestamps;
  double seconds = 0;
};

// Takes `n` frames through the source, checking each one as it comes.
void CaptureFrames(FrameSource* source, int n, int width, int height, Captured* out) {
  const int64_t t0 = MonotonicNs();
  for (int i = 0; i < n; ++i) {
    Frame f;
    std::string err;
    ASSERT_EQ(source->Next(&f, &err), Status::kOk) << err;
    ASSERT_EQ(f.image.cols, width);
    ASSERT_EQ(f.image.rows, height);
    ASSERT_EQ(f.image.type(), CV_8UC3);
    EXPECT_EQ(f.original_size, cv::Size(width, height));
    EXPECT_EQ(f.index, static_cast<uint64_t>(i));
    out->images.push_back(f.image.clone());
    out->timestamps.push_back(f.timestamp_ns);
  }
  out->seconds = static_cast<double>(MonotonicNs() - t0) * 1e-9;
}

// Driver timestamps: CLOCK_MONOTONIC (between our start and now), strictly increasing. vivid stamps a frame with its
// nominal time (stream start + sequence x period): after its thread ran late and caught up, a stamp was 1.9 ms ahead
// of the clock read just after (CI, 2026-11-30). Another clock would be off by far more than the 100 ms allowed.
void ExpectMonotonicTimestamps(const Captured& c, int64_t opened_ns) {
  const int64_t now = MonotonicNs();
  for (size_t i = 0; i < c.timestamps.size(); ++i) {
    EXPECT_GT(c.timestamps[i], opened_ns - 1'000'000'000) << "frame " << i << " is older than the stream";
    EXPECT_LE(c.timestamps[i], now + 100'000'000) << "frame " << i << " is from the future: not CLOCK_MONOTONIC";
    if (i > 0) {
      EXPECT_GT(c.timestamps[i], c.timestamps[i - 1]) << "frame " << i;
    }
  }
}

double FpsOf(const Captured& c) {
  if (c.timestamps.size() < 2) return 0;
  return static_cast<double>(c.timestamps.size() - 1) * 1e9 /
         static_cast<double>(c.timestamps.back() - c.timestamps.front());
}

// vivid's default pattern is 75 % colour bars (white, yellow, cyan, green, magenta, red, blue, black), with text in
// the top rows: the bars in the lower half are known colours.
void ExpectColourBars(const cv::Mat& bgr, const std::string& what) {
  const int bar = bgr.cols / 8;
  const int y0 = bgr.rows / 2;
  const int h = bgr.rows / 4;
  auto mean_of = [&](int k) { return cv::mean(bgr(cv::Rect(k * bar + bar / 4, y0, bar / 2, h))); };
  const cv::Scalar white = mean_of(0), yellow = mean_of(1), red = mean_of(5), blue = mean_of(6), black = mean_of(7);
  // 75 % white is ~191 on every channel; allow for range/matrix choices (limited range, BT.601 vs 709).
  for (int ch = 0; ch < 3; ++ch) EXPECT_NEAR(white[ch], 180, 25) << what << " white bar, channel " << ch;
  EXPECT_LT(yellow[0], 60) << what << " yellow bar: blue";
  EXPECT_GT(yellow[1], 140) << what << " yellow bar: green";
  EXPECT_GT(yellow[2], 140) << what << " yellow bar: red";
  EXPECT_GT(red[2], 140) << what << " red bar: red";
  EXPECT_LT(red[1], 60) << what << " red bar: green";
  EXPECT_GT(blue[0], 140) << what << " blue bar: blue";
  EXPECT_LT(blue[2], 60) << what << " blue bar: red";
  for (int ch = 0; ch < 3; ++ch) EXPECT_LT(black[ch], 40) << what << " black bar, channel " << ch;
}

class VividTest : public ::testing::TestWithParam<const char*> {};

TEST_P(VividTest, CapturesFramesInFormat) {
  const std::string node = FindNode("vivid");
  ASSERT_FALSE(node.empty()) << "no vivid video capture node (is the vivid module loaded?)";
  CaptureOptions o;
  std::string err;
  ASSERT_TRUE(ParseCaptureOptions(node + "?width=640&height=480&fps=30&format=" + GetParam(), &o, &err)) << err;
  V4l2Source source(o);
  const int64_t opened = MonotonicNs();
  ASSERT_EQ(source.Open(&err), Status::kOk) << err;
  constexpr int kFrames = 40;
  Captured c;
  CaptureFrames(&source, kFrames, 640, 480, &c);
  const CaptureCounters counters = source.Counters();
  const double open_s = static_cast<double>(MonotonicNs() - opened) * 1e-9;
  source.Close();
  ASSERT_EQ(c.images.size(), static_cast<size_t>(kFrames));
  ExpectMonotonicTimestamps(c, opened);
  EXPECT_GE(counters.captured, static_cast<uint64_t>(kFrames));
  // Every captured frame was delivered or dropped (2 at most still queued when the counters were read).
  EXPECT_LE(counters.captured - counters.dropped - static_cast<uint64_t>(kFrames), 3u);
  ExpectColourBars(c.images.back(), GetParam());
  cv::imwrite((ResultsDir() / (std::string("vivid_") + GetParam() + ".png")).string(), c.images.back());
  // The capture rate: frames the driver handed to the source per second (vivid paces them at 25 fps; a loaded TCG
  // guest falls behind, not to nothing). The consumer's rate (conversion; slow under ASan) is reported beside it.
  const double capture_fps = static_cast<double>(counters.captured) / open_s;
  EXPECT_GT(capture_fps, 5.0);
  Note("RATE v4l2 vivid " + std::string(GetParam()) + " 640x480: captured " + std::to_string(capture_fps) + " fps (" +
       std::to_string(counters.captured) + " frames in " + std::to_string(open_s) + " s, " +
       std::to_string(counters.dropped) + " dropped, " + std::to_string(counters.driver_gaps) +
       " driver gaps); delivered through Next(): " + std::to_string(kFrames / c.seconds) + " fps, " +
       std::to_string(FpsOf(c)) + " fps by their driver timestamps");
}

INSTANTIATE_TEST_SUITE_P(Formats, VividTest, ::testing::Values("YUYV", "NV12", "RGB24"));

// Two pixel formats of the same pattern convert to the same picture.
TEST(Vivid, FormatsAgree) {
  const std::string node = FindNode("vivid");
  ASSERT_FALSE(node.empty());
  std::vector<cv::Mat> images;
  for (const char* f : {"YUYV", "NV12"}) {
    CaptureOptions o;
    std::string err;
    ASSERT_TRUE(ParseCaptureOptions(node + "?format=" + f, &o, &err)) << err;
    V4l2Source source(o);
    ASSERT_EQ(source.Open(&err), Status::kOk) << err;
    Captured c;
    CaptureFrames(&source, 3, 640, 480, &c);
    images.push_back(c.images.back());
  }
  // The lower half (bars only; the text above changes from frame to frame).
  const cv::Rect bars(0, 240, 640, 200);
  cv::Mat diff;
  cv::absdiff(images[0](bars), images[1](bars), diff);
  // NV12 halves the vertical chroma resolution: equal away from the bar edges, close at them.
  EXPECT_LT(cv::mean(diff)[0] + cv::mean(diff)[1] + cv::mean(diff)[2], 3 * 4.0);
}

TEST(Vivid, RefusesWhatTheDriverDoesNotOffer) {
  const std::string node = FindNode("vivid");
  ASSERT_FALSE(node.empty());
  CaptureOptions o;
  std::string err;
  ASSERT_TRUE(ParseCaptureOptions(node + "?width=642&height=482", &o, &err)) << err;
  V4l2Source source(o);
  EXPECT_EQ(source.Open(&err), Status::kError);
  EXPECT_NE(err.find("not offered"), std::string::npos) << err;
}

// A consumer that stops taking frames: the source's queue stays at its capacity, drops the oldest and counts them,
// and the frame taken afterwards is a recent one.
TEST(Vivid, SlowConsumerDropsOldestAndCounts) {
  const std::string node = FindNode("vivid");
  ASSERT_FALSE(node.empty());
  CaptureOptions o;
  std::string err;
  ASSERT_TRUE(ParseCaptureOptions(node + "?fps=30&buffers=4&queue=2", &o, &err)) << err;
  V4l2Source source(o);
  ASSERT_EQ(source.Open(&err), Status::kOk) << err;
  std::this_thread::sleep_for(std::chrono::milliseconds(1500));
  const CaptureCounters c = source.Counters();
  EXPECT_GE(c.captured, 10u) << "vivid delivered too few frames in 1.5 s";
  // All but the 2 queued were dropped (one more may be between dequeue and queue while the counters are read).
  EXPECT_GE(c.captured - c.dropped, 2u);
  EXPECT_LE(c.captured - c.dropped, 3u);
  Frame f;
  ASSERT_EQ(source.Next(&f, &err), Status::kOk) << err;
  ASSERT_EQ(source.Next(&f, &err), Status::kOk) << err;
  // The second frame out is at most a few frame periods old: old frames did not pile up.
  EXPECT_LT(MonotonicNs() - f.timestamp_ns, 500'000'000);
  Note("DROP v4l2 vivid queue=2 after 1.5 s without consumer: captured " + std::to_string(c.captured) + ", dropped " +
       std::to_string(c.dropped));
}

// Writes a platform device's name into a driver's sysfs bind/unbind file (a real unplug / replug of the device).
bool SysfsWrite(const std::string& path, const std::string& value) {
  std::ofstream out(path);
  out << value;
  out.flush();
  return static_cast<bool>(out);
}

// Device loss on a real device: vivid is unbound from its driver while streaming (its node goes away; the open one
// fails with ENODEV) and bound again 1 s later. The source logs, reopens with back-off and counts one reconnect.
TEST(Vivid, ReconnectsAfterUnplug) {
  const std::string node = FindNode("vivid");
  ASSERT_FALSE(node.empty());
  ASSERT_TRUE(fs::exists("/sys/bus/platform/drivers/vivid/vivid.0")) << "vivid.0 is not bound to vivid";
  CaptureOptions o;
  std::string err;
  ASSERT_TRUE(ParseCaptureOptions(node + "?reconnect_s=20", &o, &err)) << err;
  V4l2Source source(o);
  ASSERT_EQ(source.Open(&err), Status::kOk) << err;
  Captured before;
  CaptureFrames(&source, 5, 640, 480, &before);
  ASSERT_TRUE(SysfsWrite("/sys/bus/platform/drivers/vivid/unbind", "vivid.0"));
  std::this_thread::sleep_for(std::chrono::milliseconds(1000));
  EXPECT_FALSE(fs::exists(node)) << "the node should be gone while unbound";
  ASSERT_TRUE(SysfsWrite("/sys/bus/platform/drivers/vivid/bind", "vivid.0"));
  // Frames again, from the new stream.
  int64_t last_before = before.timestamps.back();
  int got = 0;
  const int64_t deadline = MonotonicNs() + 20'000'000'000LL;
  while (got < 5 && MonotonicNs() < deadline) {
    Frame f;
    const Status st = source.Next(&f, &err);
    ASSERT_EQ(st, Status::kOk) << err;
    if (f.timestamp_ns > last_before + 900'000'000LL) ++got;  // taken after the unplug
  }
  EXPECT_EQ(got, 5);
  const CaptureCounters c = source.Counters();
  EXPECT_EQ(c.reconnects, 1u);
  source.Close();
  Note("RECONNECT v4l2 vivid unbind/bind: reconnects=" + std::to_string(c.reconnects) +
       ", captured=" + std::to_string(c.captured));
}

// Device gone for good: the source gives up after reconnect_s and Next() reports the error.
TEST(Vivid, GivesUpWhenTheDeviceStaysAway) {
  const std::string node = FindNode("vivid");
  ASSERT_FALSE(node.empty());
  CaptureOptions o;
  std::string err;
  ASSERT_TRUE(ParseCaptureOptions(node + "?reconnect_s=1.5", &o, &err)) << err;
  V4l2Source source(o);
  ASSERT_EQ(source.Open(&err), Status::kOk) << err;
  Captured c;
  CaptureFrames(&source, 3, 640, 480, &c);
  ASSERT_TRUE(SysfsWrite("/sys/bus/platform/drivers/vivid/unbind", "vivid.0"));
  const int64_t t0 = MonotonicNs();
  Status st = Status::kOk;
  for (int i = 0; i < 100 && st == Status::kOk; ++i) {
    Frame f;
    st = source.Next(&f, &err);
  }
  const double waited = static_cast<double>(MonotonicNs() - t0) * 1e-9;
  EXPECT_EQ(st, Status::kError);
  EXPECT_NE(err.find("not back within"), std::string::npos) << err;
  EXPECT_GT(waited, 1.0);
  EXPECT_LT(waited, 10.0);
  source.Close();
  ASSERT_TRUE(SysfsWrite("/sys/bus/platform/drivers/vivid/bind", "vivid.0"));
  std::this_thread::sleep_for(std::chrono::milliseconds(300));
}

#ifdef UAVM_HAVE_LIBCAMERA
// libcamera only lists devices udev has initialised; no udev runs in the VM, so mark every video and media node as
// initialised (what udevd would record in /run/udev/data).
void MarkUdevInitialised() {
  fs::create_directories("/run/udev/data");
  for (const char* cls : {"/sys/class/video4linux", "/sys/bus/media/devices"}) {
    std::error_code ec;
    for (const auto& e : fs::directory_iterator(cls, ec)) {
      std::ifstream dev(e.path() / "dev");
      std::string mm;
      if (dev >> mm) std::ofstream("/run/udev/data/c" + mm) << "I:1\n";
    }
  }
}

TEST(Vimc, CapturesThroughLibcamera) {
  MarkUdevInitialised();
  CaptureOptions o;
  std::string err;
  // vimc's pipeline scales the sensor by 3 from a 2-aligned size: widths are multiples of 6 (636, not 640).
  ASSERT_TRUE(ParseCaptureOptions("0?width=636&height=480&format=RGB24&fps=30", &o, &err)) << err;
  LibcameraSource source(o);
  const int64_t opened = MonotonicNs();
  ASSERT_EQ(source.Open(&err), Status::kOk) << err;
  EXPECT_NE(source.camera_id().find("vimc"), std::string::npos) << source.camera_id();
  constexpr int kFrames = 20;
  Captured c;
  CaptureFrames(&source, kFrames, 636, 480, &c);
  const CaptureCounters counters = source.Counters();
  source.Close();
  ASSERT_EQ(c.images.size(), static_cast<size_t>(kFrames));
  ExpectMonotonicTimestamps(c, opened);
  cv::Scalar mean, stddev;
  cv::meanStdDev(c.images.back(), mean, stddev);
  EXPECT_GT(stddev[0] + stddev[1] + stddev[2], 30.0) << "a flat image: the test pattern did not come through";
  cv::imwrite((ResultsDir() / "vimc_libcamera.png").string(), c.images.back());
  Note("RATE libcamera vimc RGB24(BGR888) 636x480: " + std::to_string(FpsOf(c)) + " fps by timestamps, " +
       std::to_string(kFrames / c.seconds) + " fps through Next() (" + std::to_string(counters.captured) +
       " captured, " + std::to_string(counters.dropped) + " dropped)");
}

// Device loss through libcamera: vimc is unbound from its driver while streaming. libcamera 0.0.3 cannot restart a
// lost camera in-process (Camera::stop() aborts on a vanished device), so the source must report the loss through
// Next() within a few seconds, and closing it must not abort. vimc is bound again afterwards.
TEST(Vimc, ReportsUnplug) {
  MarkUdevInitialised();
  ASSERT_TRUE(fs::exists("/sys/bus/platform/drivers/vimc/vimc.0")) << "vimc.0 is not bound to vimc";
  CaptureOptions o;
  std::string err;
  ASSERT_TRUE(ParseCaptureOptions("0?width=636&height=480&format=RGB24", &o, &err)) << err;
  LibcameraSource source(o);
  ASSERT_EQ(source.Open(&err), Status::kOk) << err;
  Captured before;
  CaptureFrames(&source, 3, 636, 480, &before);
  ASSERT_TRUE(SysfsWrite("/sys/bus/platform/drivers/vimc/unbind", "vimc.0"));
  const int64_t t0 = MonotonicNs();
  Status st = Status::kOk;
  for (int i = 0; i < 200 && st == Status::kOk; ++i) {
    Frame f;
    st = source.Next(&f, &err);
  }
  const double waited = static_cast<double>(MonotonicNs() - t0) * 1e-9;
  EXPECT_EQ(st, Status::kError);
  EXPECT_NE(err.find("lost"), std::string::npos) << err;
  EXPECT_LT(waited, 10.0);
  source.Close();  // must return (no abort, no hang)
  EXPECT_TRUE(SysfsWrite("/sys/bus/platform/drivers/vimc/bind", "vimc.0"));
  Note("LOSS libcamera vimc unbind: reported after " + std::to_string(waited) + " s: " + err);
}
#endif

// The onboard program on vivid with a slow consumer: the camera queue drops frames and counts them, nothing
// queues up without bound, and the session directory is complete.
TEST(Onboard, DropsAndCountsWithSlowProcessing) {
  const std::string node = FindNode("vivid");
  ASSERT_FALSE(node.empty());
  // The session on the guest's tmpfs (the results share is slow to write through); report.json is copied out.
  // Small frames and work size: the VM's emulated CPU runs SIFT ~50x slower than the host.
  const fs::path out = fs::temp_directory_path() / "onboard_session";
  // 20 frames: at 150 ms each against a 30 fps camera, hundreds of frames are dropped meanwhile (50 frames proved
  // nothing more and took 113 s of the VM's emulated CPU instead of ~45 s).
  constexpr uint64_t kMaxFrames = 20;
  fs::remove_all(out);
  // One SIFT pass per frame (no lowering of the contrast threshold to reach more keypoints on the colour bars).
  const fs::path config = fs::temp_directory_path() / "onboard_vm.yaml";
  std::ofstream(config) << "features:\n  target_min_features: 10\n";
  const std::string cmd = std::string(UAVM_ONBOARD_BIN) + " --source 'v4l2:" + node +
                          "?width=320&height=180&format=YUYV&fps=30' --out " + out.string() + " --config " +
                          config.string() + " --max-frames " + std::to_string(kMaxFrames) +
                          " --process-delay-ms 150 --work-size 160 --max-features 200 --bands 0 "
                          "--preview-every 0 --no-tiff --log-level info > " +
                          (ResultsDir() / "onboard.log").string() + " 2>&1";
  const int64_t t0 = MonotonicNs();
  const int status = std::system(cmd.c_str());
  const double seconds = static_cast<double>(MonotonicNs() - t0) * 1e-9;
  ASSERT_TRUE(WIFEXITED(status));
  const int code = WEXITSTATUS(status);
  EXPECT_TRUE(code == 0 || code == 5) << "exit " << code << " (see onboard.log)";
  std::error_code ec;
  fs::copy_file(out / "report.json", ResultsDir() / "onboard_report.json", fs::copy_options::overwrite_existing, ec);
  std::ifstream in(out / "report.json");
  ASSERT_TRUE(in.good()) << "no report.json";
  const auto report = nlohmann::json::parse(in);
  const auto captured = report["camera"]["captured"].get<uint64_t>();
  const auto dropped = report["dropped_by_queue"].get<uint64_t>();
  const auto frames_in = report["frames_in"].get<uint64_t>();
  EXPECT_GT(dropped, 0u) << "a 150 ms/frame consumer on a 30 fps camera must drop";
  EXPECT_LE(frames_in, kMaxFrames);
  EXPECT_GT(frames_in, 5u);
  // Every captured frame is accounted for: processed (frames_in) or dropped (in the camera's queue or the app's).
  EXPECT_EQ(frames_in + dropped, captured);
  EXPECT_EQ(report["camera"]["reconnects"].get<uint64_t>(), 0u);
  // Nothing queued without bound: the resident memory stays that of a small session.
  EXPECT_LT(report["peak_rss_mib"].get<double>(), 400.0);
  // A valid session: the journal has a line per accepted frame, frames/ holds them.
  size_t journal_frames = 0;
  std::ifstream journal(out / "journal.jsonl");
  for (std::string line; std::getline(journal, line);)
    if (line.find("\"frame\"") != std::string::npos) ++journal_frames;
  EXPECT_EQ(journal_frames, report["frames_decoded"].get<uint64_t>());
  size_t stored = 0;
  for (const auto& e : fs::directory_iterator(out / "frames")) stored += e.is_regular_file() ? 1 : 0;
  EXPECT_EQ(stored, report["frames_decoded"].get<uint64_t>());
  if (code == 0) {
    EXPECT_TRUE(fs::exists(out / "mosaic.png"));
  }
  Note("ONBOARD vivid " + std::to_string(kMaxFrames) + " frames, 150 ms/frame processing: captured " +
       std::to_string(captured) + ", dropped " + std::to_string(dropped) + ", processed " + std::to_string(frames_in) +
       ", registered " + std::to_string(report["registered"].get<int>()) + ", exit " + std::to_string(code) + ", " +
       std::to_string(seconds) + " s");
}

// ---- A georeferenced camera flight: vivid's capture shows a moving ground, a MAVLink stream says where it is. ----
// vivid's own test patterns cannot be registered when they move (colour bars and ramps vary along one axis only,
// checkers and colour squares repeat, noise changes every frame), so the flight loops pictures through vivid: its
// HDMI output is looped to its HDMI capture ("Loop Video"), and the test writes into the output a 640x480 window that
// slides east over a textured ground at kGroundPxPerS. The capture path (V4L2 source, driver timestamps, queues) is the
// real one; only the picture comes from the test.

constexpr int kFlightWidth = 640;
constexpr int kFlightHeight = 480;
constexpr double kGroundPxPerS = 80;         // the picture's speed over the ground texture
constexpr double kGsdM = 0.1;                // metres per pixel: the vehicle flies east at 8 m/s
constexpr double kFlightSeconds = 40;        // then it hovers at the end of the texture
constexpr double kLat0 = 50.0, kLon0 = 8.0;  // UTM zone 32 N
constexpr int kMavlinkPort = 14551;
constexpr int kHttpPort = 8089;

int Ioctl(int fd, unsigned long request, void* arg) {
  int r = 0;
  do {
    r = ::ioctl(fd, request, arg);
  } while (r != 0 && errno == EINTR);
  return r;
}

// The first vivid node with a video output.
std::string FindVividOutput() {
  for (int i = 0; i < 64; ++i) {
    std::string path = "/dev/video" + std::to_string(i);
    const int fd = ::open(path.c_str(), O_RDWR | O_NONBLOCK);
    if (fd < 0) continue;
    v4l2_capability cap{};
    const bool ok = Ioctl(fd, VIDIOC_QUERYCAP, &cap) == 0 &&
                    std::string(reinterpret_cast<const char*>(cap.driver)) == "vivid" &&
                    (cap.device_caps & V4L2_CAP_VIDEO_OUTPUT) != 0;
    ::close(fd);
    if (ok) return path;
  }
  return "";
}

// Sets the control called `name` (e.g. "Loop Video") to `value`.
bool SetControl(int fd, const std::string& name, int value) {
  v4l2_queryctrl q{};
  q.id = V4L2_CTRL_FLAG_NEXT_CTRL;
  while (Ioctl(fd, VIDIOC_QUERYCTRL, &q) == 0) {
    if (name == reinterpret_cast<const char*>(q.name)) {
      v4l2_control c{q.id, value};
      return Ioctl(fd, VIDIOC_S_CTRL, &c) == 0;
    }
    q.id |= V4L2_CTRL_FLAG_NEXT_CTRL;
  }
  return false;
}

// Selects the input (capture) or output whose name starts with `prefix`.
bool SelectPort(int fd, bool output, const std::string& prefix) {
  for (unsigned i = 0; i < 16; ++i) {
    std::string name;
    if (output) {
      v4l2_output o{};
      o.index = i;
      if (Ioctl(fd, VIDIOC_ENUMOUTPUT, &o) != 0) return false;
      name = reinterpret_cast<const char*>(o.name);
    } else {
      v4l2_input in{};
      in.index = i;
      if (Ioctl(fd, VIDIOC_ENUMINPUT, &in) != 0) return false;
      name = reinterpret_cast<const char*>(in.name);
    }
    if (name.rfind(prefix, 0) != 0) continue;
    int index = static_cast<int>(i);
    return Ioctl(fd, output ? VIDIOC_S_OUTPUT : VIDIOC_S_INPUT, &index) == 0;
  }
  return false;
}

// HDMI timings of exactly w x h (the driver's own list), set on the node.
bool SetTimings(int fd, int w, int h) {
  for (unsigned i = 0; i < 256; ++i) {
    v4l2_enum_dv_timings e{};
    e.index = i;
    if (Ioctl(fd, VIDIOC_ENUM_DV_TIMINGS, &e) != 0) return false;
    if (static_cast<int>(e.timings.bt.width) == w && static_cast<int>(e.timings.bt.height) == h &&
        e.timings.bt.interlaced == 0)
      return Ioctl(fd, VIDIOC_S_DV_TIMINGS, &e.timings) == 0;
  }
  return false;
}

bool SetYuyvFormat(int fd, v4l2_buf_type type, int w, int h) {
  v4l2_format f{};
  f.type = type;
  f.fmt.pix.width = static_cast<uint32_t>(w);
  f.fmt.pix.height = static_cast<uint32_t>(h);
  f.fmt.pix.pixelformat = V4L2_PIX_FMT_YUYV;
  f.fmt.pix.field = V4L2_FIELD_NONE;
  return Ioctl(fd, VIDIOC_S_FMT, &f) == 0 && static_cast<int>(f.fmt.pix.width) == w &&
         static_cast<int>(f.fmt.pix.height) == h && f.fmt.pix.pixelformat == V4L2_PIX_FMT_YUYV;
}

// vivid's HDMI output looped to its HDMI capture, both w x h YUYV; Restore() puts back the webcam input and the
// pattern the other tests expect.
class VividLoop {
 public:
  ~VividLoop() { Restore(); }
  bool Setup(const std::string& capture, const std::string& output, std::string* error) {
    cap_fd_ = ::open(capture.c_str(), O_RDWR);
    out_fd_ = ::open(output.c_str(), O_RDWR);
    auto fail = [&](const std::string& what) {
      *error = what + ": " + std::strerror(errno);
      return false;
    };
    if (cap_fd_ < 0 || out_fd_ < 0) return fail("open " + capture + " / " + output);
    if (!SelectPort(cap_fd_, false, "HDMI")) return fail("capture: no HDMI input");
    if (!SelectPort(out_fd_, true, "HDMI")) return fail("output: no HDMI output");
    if (!SetTimings(cap_fd_, kFlightWidth, kFlightHeight)) return fail("capture: 640x480 HDMI timings");
    if (!SetTimings(out_fd_, kFlightWidth, kFlightHeight)) return fail("output: 640x480 HDMI timings");
    if (!SetYuyvFormat(cap_fd_, V4L2_BUF_TYPE_VIDEO_CAPTURE, kFlightWidth, kFlightHeight))
      return fail("capture: YUYV 640x480");
    if (!SetYuyvFormat(out_fd_, V4L2_BUF_TYPE_VIDEO_OUTPUT, kFlightWidth, kFlightHeight))
      return fail("output: YUYV 640x480");
    if (!SetControl(cap_fd_, "OSD Text Mode", 2)) return fail("capture: OSD Text Mode");  // no text over the picture
    if (!SetControl(cap_fd_, "Loop Video", 1)) return fail("capture: Loop Video");
    return true;
  }
  [[nodiscard]] int output_fd() const { return out_fd_; }
  void Restore() {
    if (cap_fd_ >= 0) {
      SetControl(cap_fd_, "Loop Video", 0);
      SetControl(cap_fd_, "OSD Text Mode", 0);
      int webcam = 0;
      Ioctl(cap_fd_, VIDIOC_S_INPUT, &webcam);
      ::close(cap_fd_);
    }
    if (out_fd_ >= 0) ::close(out_fd_);
    cap_fd_ = out_fd_ = -1;
  }

 private:
  int cap_fd_ = -1;
  int out_fd_ = -1;
};

// A textured ground, the same every run: smooth blobs at several scales (what SIFT finds at the 1/4 working size),
// brightness mostly, some colour.
cv::Mat MakeGround(int width, int height) {
  cv::RNG rng(17);
  auto blobs = [&](int cell, int type) {
    cv::Mat coarse(height / cell + 3, width / cell + 3, type);
    rng.fill(coarse, cv::RNG::NORMAL, 0, 1);
    cv::Mat up;
    cv::resize(coarse, up, cv::Size((coarse.cols - 1) * cell, (coarse.rows - 1) * cell), 0, 0, cv::INTER_CUBIC);
    return cv::Mat(up(cv::Rect(cell, cell, width, height)));
  };
  cv::Mat gray = cv::Mat::zeros(height, width, CV_32F);
  for (const int cell : {8, 16, 32, 64}) gray += blobs(cell, CV_32F);
  cv::Mat acc;
  cv::merge(std::vector<cv::Mat>(3, gray), acc);
  acc += 0.7 * blobs(48, CV_32FC3);
  cv::Mat ground;
  acc.convertTo(ground, CV_8UC3, 28, 128);
  return ground;
}

// BGR to packed YUYV (BT.601, limited range, as a camera sends it), a row of w pixels = 2w bytes.
std::vector<uint8_t> ToYuyv(const cv::Mat& bgr) {
  cv::Mat yuv;
  cv::cvtColor(bgr, yuv, cv::COLOR_BGR2YUV);
  std::vector<uint8_t> out(static_cast<size_t>(bgr.cols) * bgr.rows * 2);
  auto luma = [](int y) { return static_cast<uint8_t>(16 + y * 219 / 255); };
  auto chroma = [](int a, int b) { return static_cast<uint8_t>(128 + ((a + b) / 2 - 128) * 224 / 255); };
  for (int r = 0; r < bgr.rows; ++r) {
    const auto* p = yuv.ptr<cv::Vec3b>(r);
    uint8_t* o = out.data() + static_cast<size_t>(r) * bgr.cols * 2;
    for (int x = 0; x + 1 < bgr.cols; x += 2, o += 4) {
      o[0] = luma(p[x][0]);
      o[1] = chroma(p[x][1], p[x + 1][1]);
      o[2] = luma(p[x + 1][0]);
      o[3] = chroma(p[x][2], p[x + 1][2]);
    }
  }
  return out;
}

int64_t WallMs() {
  return std::chrono::duration_cast<std::chrono::milliseconds>(std::chrono::system_clock::now().time_since_epoch())
      .count();
}

// Streams the camera's view into vivid's output (mmap buffers, as fast as the driver takes them): the window at
// kGroundPxPerS east of the texture's start since t0 (wall clock, the MAVLink peer's), before t0 the start, after the
// flight the end.
class GroundFeed {
 public:
  GroundFeed(int fd, int ground_width) : fd_(fd), width_(ground_width) {
    ground_ = ToYuyv(MakeGround(ground_width, kFlightHeight));
    v4l2_requestbuffers rb{};
    rb.count = 4;
    rb.type = V4L2_BUF_TYPE_VIDEO_OUTPUT;
    rb.memory = V4L2_MEMORY_MMAP;
    if (Ioctl(fd_, VIDIOC_REQBUFS, &rb) != 0) {
      Fail("VIDIOC_REQBUFS");
      return;
    }
    for (uint32_t i = 0; i < rb.count; ++i) {
      v4l2_buffer b{};
      b.index = i;
      b.type = V4L2_BUF_TYPE_VIDEO_OUTPUT;
      b.memory = V4L2_MEMORY_MMAP;
      if (Ioctl(fd_, VIDIOC_QUERYBUF, &b) != 0) {
        Fail("VIDIOC_QUERYBUF");
        return;
      }
      void* p = ::mmap(nullptr, b.length, PROT_READ | PROT_WRITE, MAP_SHARED, fd_, b.m.offset);
      if (p == MAP_FAILED) {
        Fail("mmap");
        return;
      }
      maps_.emplace_back(static_cast<uint8_t*>(p), b.length);
    }
    thread_ = std::thread([this] { Run(); });
  }
  ~GroundFeed() {
    running_ = false;
    if (thread_.joinable()) thread_.join();
    int type = V4L2_BUF_TYPE_VIDEO_OUTPUT;
    Ioctl(fd_, VIDIOC_STREAMOFF, &type);
    for (const auto& [p, n] : maps_) ::munmap(p, n);
    v4l2_requestbuffers rb{};
    rb.type = V4L2_BUF_TYPE_VIDEO_OUTPUT;
    rb.memory = V4L2_MEMORY_MMAP;
    Ioctl(fd_, VIDIOC_REQBUFS, &rb);
  }
  GroundFeed(const GroundFeed&) = delete;
  GroundFeed& operator=(const GroundFeed&) = delete;
  void Start(int64_t t0_ms) { t0_ms_ = t0_ms; }
  [[nodiscard]] uint64_t written() const { return written_; }
  [[nodiscard]] const std::string& error() const { return error_; }

 private:
  void Fail(const std::string& what) { error_ = what + ": " + std::strerror(errno); }
  // The view now into buffer `index`, queued.
  bool Queue(uint32_t index) {
    const int64_t t0 = t0_ms_;
    const double s = t0 == 0 ? 0.0 : std::clamp(static_cast<double>(WallMs() - t0) / 1000.0, 0.0, kFlightSeconds);
    const int x = std::min(static_cast<int>(s * kGroundPxPerS) & ~1, width_ - kFlightWidth);  // YUYV: even
    const size_t row = static_cast<size_t>(kFlightWidth) * 2;
    for (int r = 0; r < kFlightHeight; ++r)
      std::memcpy(maps_[index].first + r * row, ground_.data() + (static_cast<size_t>(r) * width_ + x) * 2, row);
    v4l2_buffer b{};
    b.index = index;
    b.type = V4L2_BUF_TYPE_VIDEO_OUTPUT;
    b.memory = V4L2_MEMORY_MMAP;
    b.bytesused = static_cast<uint32_t>(row * kFlightHeight);
    b.field = V4L2_FIELD_NONE;
    if (Ioctl(fd_, VIDIOC_QBUF, &b) != 0) {
      Fail("VIDIOC_QBUF");
      return false;
    }
    ++written_;
    return true;
  }
  void Run() {
    for (uint32_t i = 0; i < maps_.size(); ++i)
      if (!Queue(i)) return;
    int type = V4L2_BUF_TYPE_VIDEO_OUTPUT;
    if (Ioctl(fd_, VIDIOC_STREAMON, &type) != 0) return Fail("VIDIOC_STREAMON");
    while (running_) {
      pollfd p{fd_, POLLOUT, 0};
      if (::poll(&p, 1, 200) != 1) continue;
      v4l2_buffer b{};
      b.type = V4L2_BUF_TYPE_VIDEO_OUTPUT;
      b.memory = V4L2_MEMORY_MMAP;
      if (Ioctl(fd_, VIDIOC_DQBUF, &b) != 0) return Fail("VIDIOC_DQBUF");
      if (!Queue(b.index)) return;
    }
  }
  int fd_;
  int width_;
  std::vector<uint8_t> ground_;
  std::vector<std::pair<uint8_t*, size_t>> maps_;
  std::atomic<int64_t> t0_ms_{0};
  std::atomic<bool> running_{true};
  std::atomic<uint64_t> written_{0};
  std::string error_;
  std::thread thread_;
};

// The MAVLink peer (tests/telemetry/fly_udp.mjs through run_peer.sh): runs until its stdin is closed.
class MavlinkPeer {
 public:
  bool Start(const std::string& args, std::string* error) {
    const char* run = std::getenv("UAVM_PEER_RUN");
    const fs::path script = fs::path(run).parent_path() / "fly_udp.mjs";
    int in[2], out[2];
    if (::pipe(in) != 0 || ::pipe(out) != 0) return false;
    pid_ = ::fork();
    if (pid_ == 0) {
      ::dup2(in[0], 0);
      ::dup2(out[1], 1);
      ::close(in[1]);
      ::close(out[0]);
      const std::string cmd = "exec bash '" + std::string(run) + "' '" + script.string() + "' " + args + " 2>" +
                              (ResultsDir() / "mavlink_peer.err").string();
      ::execl("/bin/sh", "sh", "-c", cmd.c_str(), static_cast<char*>(nullptr));
      ::_exit(127);
    }
    ::close(in[0]);
    ::close(out[1]);
    stdin_ = in[1];
    stdout_ = out[0];
    // Its first line: "T0 <unix ms>" once it sends (node starts slowly on the emulated CPU: a CI run that shared the
    // 2 cores with a build saw nothing within 60 s).
    const std::string line = ReadLine(150'000);
    if (line.rfind("T0 ", 0) != 0) {
      *error = "the MAVLink peer did not start (" + line + "), see mavlink_peer.err";
      return false;
    }
    t0_ms_ = std::stoll(line.substr(3));
    return true;
  }
  [[nodiscard]] int64_t t0_ms() const { return t0_ms_; }
  // Closes its stdin (it stops) and collects what it printed (the mapper's STATUSTEXT answers).
  std::string Stop() {
    std::string rest;
    if (stdin_ >= 0) ::close(stdin_);
    stdin_ = -1;
    for (std::string l; !(l = ReadLine(5000)).empty();) rest += l + "\n";
    if (pid_ > 0) ::waitpid(pid_, nullptr, 0);
    pid_ = -1;
    if (stdout_ >= 0) ::close(stdout_);
    stdout_ = -1;
    return rest;
  }
  ~MavlinkPeer() { Stop(); }

 private:
  std::string ReadLine(int timeout_ms) {
    std::string line;
    char c = 0;
    pollfd p{stdout_, POLLIN, 0};
    while (::poll(&p, 1, timeout_ms) == 1 && ::read(stdout_, &c, 1) == 1 && c != '\n') line += c;
    return line;
  }
  pid_t pid_ = -1;
  int stdin_ = -1;
  int stdout_ = -1;
  int64_t t0_ms_ = 0;
};

// GET http://127.0.0.1:port/path; the body of a 200 answer, else "".
std::string HttpGet(int port, const std::string& path) {
  const int s = ::socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  a.sin_port = htons(static_cast<uint16_t>(port));
  std::string reply;
  if (::connect(s, reinterpret_cast<sockaddr*>(&a), sizeof(a)) == 0) {
    const std::string req = "GET " + path + " HTTP/1.0\r\nHost: 127.0.0.1\r\n\r\n";
    if (::send(s, req.data(), req.size(), MSG_NOSIGNAL) == static_cast<ssize_t>(req.size())) {
      char buf[4096];
      for (ssize_t n; (n = ::recv(s, buf, sizeof(buf), 0)) > 0;) reply.append(buf, static_cast<size_t>(n));
    }
  }
  ::close(s);
  const size_t body = reply.find("\r\n\r\n");
  if (reply.rfind("HTTP/1.", 0) != 0 || reply.find(" 200 ") > 12 || body == std::string::npos) return "";
  return reply.substr(body + 4);
}

// Whether the child `pid` still runs (without reaping it).
bool Running(pid_t pid) {
  siginfo_t info{};
  return ::waitid(P_PID, static_cast<id_t>(pid), &info, WEXITED | WNOHANG | WNOWAIT) == 0 && info.si_pid == 0;
}

// /status.json while the program flies, until the live view is georeferenced (or the flight ends, or time is up).
nlohmann::json WaitForLiveGeoref(pid_t pid, double seconds) {
  nlohmann::json status;
  const int64_t deadline = MonotonicNs() + static_cast<int64_t>(seconds * 1e9);
  while (MonotonicNs() < deadline && Running(pid)) {
    const std::string body = HttpGet(kHttpPort, "/status.json");
    if (!body.empty()) {
      status = nlohmann::json::parse(body, nullptr, false);
      if (status.is_discarded() || (status["state"] != "starting" && status["state"] != "flying")) break;
      if (status["georef"].value("georeferenced", false)) break;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(500));
  }
  return status;
}

pid_t SpawnShell(const std::string& cmd) {
  const pid_t pid = ::fork();
  if (pid == 0) {
    ::execl("/bin/sh", "sh", "-c", ("exec " + cmd).c_str(), static_cast<char*>(nullptr));
    ::_exit(127);
  }
  return pid;
}

// The onboard program on vivid's capture with the MAVLink stream and the live view.
pid_t StartOnboardFlight(const std::string& node, const fs::path& out) {
  const fs::path config = fs::temp_directory_path() / "onboard_flight.yaml";
  std::ofstream(config) << "features:\n  target_min_features: 10\n";
  return SpawnShell(std::string(UAVM_ONBOARD_BIN) + " --source 'v4l2:" + node +
                    "?width=" + std::to_string(kFlightWidth) + "&height=" + std::to_string(kFlightHeight) +
                    "&format=YUYV' --out " + out.string() + " --config " + config.string() +
                    " --telemetry mavlink-udp:127.0.0.1:" + std::to_string(kMavlinkPort) +
                    // The live view's picture and status are this test's subject; the live tile worker would only
                    // load the emulated guest's CPU, where frame and telemetry timing are measured.
                    " --http 127.0.0.1:" + std::to_string(kHttpPort) + " --no-live-tiles" +
                    " --max-frames 60 --work-size 160 --max-features 200 --bands 0 --preview-every 1 --no-tiff "
                    "--no-products --log-level info > " +
                    (ResultsDir() / "onboard_flight.log").string() + " 2>&1");
}

// frames.csv: the frames' positions (latitude_deg, longitude_deg columns) on the flown line.
void ExpectPositionsOnTheLine(const fs::path& frames_csv, int* with_position) {
  std::ifstream in(frames_csv);
  std::string line;
  ASSERT_TRUE(std::getline(in, line)) << "no frames.csv";
  std::vector<std::string> head;
  std::stringstream hs(line);
  for (std::string c; std::getline(hs, c, ',');) head.push_back(c);
  const auto col = [&](const std::string& name) { return std::find(head.begin(), head.end(), name) - head.begin(); };
  const size_t lat = static_cast<size_t>(col("latitude_deg")), lon = static_cast<size_t>(col("longitude_deg"));
  ASSERT_LT(lon, head.size());
  const double metres_per_deg_lon = 6378137 * M_PI / 180 * std::cos(kLat0 * M_PI / 180);
  const double end_lon = kLon0 + kFlightSeconds * kGroundPxPerS * kGsdM / metres_per_deg_lon;
  // A frame taken up to telemetry.max_hold_s (1 s) before the peer's first fix gets that fix carried back by its
  // velocity (the track's hold, hal/telemetry/track.h): up to a second of flight west of the start (a clean-clone run
  // had frame 0 2.1 m west, 0.26 s before the first fix).
  const double start_lon = kLon0 - 1.0 * kGroundPxPerS * kGsdM / metres_per_deg_lon;
  while (std::getline(in, line)) {
    std::vector<std::string> cols;
    std::stringstream ss(line);
    for (std::string c; std::getline(ss, c, ',');) cols.push_back(c);
    if (cols.size() <= lon || cols[lat].empty()) continue;
    ++*with_position;
    EXPECT_NEAR(std::stod(cols[lat]), kLat0, 1e-6) << line;  // flying east along the parallel
    EXPECT_GE(std::stod(cols[lon]), start_lon - 1e-7) << line;
    EXPECT_LE(std::stod(cols[lon]), end_lon + 1e-7) << line;
  }
}

struct Flight {
  nlohmann::json status;  // the last /status.json of the flight
  int wstatus = 0;
  double live_s = 0;  // from the program's start to that status
  double seconds = 0;
  double peer_start_s = 0;
  std::string peer_answers;
  uint64_t pictures = 0;
};

// Flies: the program starts on vivid's capture, the MAVLink peer meanwhile (node starts slowly on the emulated CPU);
// the picture moves from the peer's T0. The operator ends the flight (SIGTERM) once the live view is georeferenced.
void Fly(const std::string& node, const std::string& output, const fs::path& out, Flight* flight) {
  VividLoop loop;
  std::string err;
  ASSERT_TRUE(loop.Setup(node, output, &err)) << err;
  GroundFeed feed(loop.output_fd(), kFlightWidth + static_cast<int>(kFlightSeconds * kGroundPxPerS) + 2);
  ASSERT_EQ(feed.error(), "");
  fs::remove_all(out);
  const int64_t t0 = MonotonicNs();
  const pid_t pid = StartOnboardFlight(node, out);
  ASSERT_GT(pid, 0);
  MavlinkPeer peer;
  std::ostringstream args;
  args << kMavlinkPort << " " << kLat0 << " " << kLon0 << " " << kGroundPxPerS * kGsdM << " 0 " << kFlightSeconds
       << " 60 10";
  const bool peer_ok = peer.Start(args.str(), &err);
  flight->peer_start_s = static_cast<double>(MonotonicNs() - t0) * 1e-9;
  if (peer_ok) {
    feed.Start(peer.t0_ms());
    flight->status = WaitForLiveGeoref(pid, 90);
  }
  flight->live_s = static_cast<double>(MonotonicNs() - t0) * 1e-9;
  ::kill(pid, SIGTERM);
  ASSERT_EQ(::waitpid(pid, &flight->wstatus, 0), pid);
  flight->peer_answers = peer.Stop();
  flight->seconds = static_cast<double>(MonotonicNs() - t0) * 1e-9;
  flight->pictures = feed.written();
  ASSERT_TRUE(peer_ok) << err;
  EXPECT_EQ(feed.error(), "") << "streaming into vivid's output";
  std::ofstream(ResultsDir() / "onboard_flight_status.json") << flight->status.dump(1);
  std::error_code ec;
  for (const char* f : {"report.json", "frames.csv", "live.jpg", "live.jgw", "mosaic.png"})
    fs::copy_file(out / f, ResultsDir() / (std::string("onboard_flight_") + f), fs::copy_options::overwrite_existing,
                  ec);
}

// During the flight: georeferenced in the flight's UTM zone, the picture not turned (it moves east as the positions
// do; the grid convergence at 8 E in zone 32 is -0.77 deg), the GIS sidecars beside live.jpg.
void ExpectLiveGeoref(const nlohmann::json& status, const fs::path& out) {
  ASSERT_TRUE(status.is_object()) << "no /status.json during the flight";
  const nlohmann::json& g = status["georef"];
  EXPECT_EQ(status["state"], "flying") << "the flight ended before the live view was georeferenced";
  ASSERT_TRUE(g.value("georeferenced", false)) << status.dump();
  EXPECT_EQ(g.value("crs", ""), "EPSG:32632") << g.dump();
  EXPECT_EQ(g.value("epsg", 0), 32632);
  EXPECT_GE(g.value("frames_used", 0), 3);
  EXPECT_LT(g.value("rms_m", 1e9), 3.0);
  EXPECT_LT(std::abs(g.value("rotation_deg", 1e9)), 3.0) << "the picture does not move the way the positions do";
  EXPECT_TRUE(fs::exists(out / "live.jgw"));
  EXPECT_TRUE(fs::exists(out / "live.jpg.aux.xml"));
}

// report.json: georeferenced by the telemetry's positions (the picture not turned, see above), frames placed.
void ExpectReportGeorefAndTelemetry(const nlohmann::json& report) {
  const nlohmann::json& g = report["georef"];
  const nlohmann::json& t = report["telemetry"];
  EXPECT_TRUE(g.value("georeferenced", false)) << g.dump();
  EXPECT_EQ(g.value("crs", ""), "EPSG:32632");
  EXPECT_LT(g.value("rms_m", 1e9), 3.0);
  EXPECT_LT(std::abs(g.value("rotation_removed_deg", 1e9)), 3.0);
  EXPECT_EQ(t.value("kind", ""), "mavlink-udp");
  EXPECT_GT(t.value("frames_placed", 0), 0) << t.dump();
  EXPECT_EQ(t.value("crc_errors", 1), 0);
}

// The end: a complete session, georeferenced, its frames' positions in frames.csv.
void ExpectGeoreferencedSession(const fs::path& out, int wstatus, nlohmann::json* report) {
  ASSERT_TRUE(WIFEXITED(wstatus));
  EXPECT_EQ(WEXITSTATUS(wstatus), 0) << "see onboard_flight.log";
  std::ifstream in(out / "report.json");
  ASSERT_TRUE(in.good()) << "no report.json";
  *report = nlohmann::json::parse(in);
  ExpectReportGeorefAndTelemetry(*report);
  int with_position = 0;
  ExpectPositionsOnTheLine(out / "frames.csv", &with_position);
  EXPECT_EQ(with_position, (*report)["telemetry"].value("frames_placed", -1));
  // A frame is dropped only in the camera's own queue, before the telemetry is asked for its position: each frame
  // asked is in the session (one run dropped 11 of 38 after detection, when the program's queue dropped too).
  EXPECT_EQ((*report)["telemetry"].value("frames_asked", -1), report->value("frames_in", -2));
}

// A camera flight with a MAVLink stream from an independent encoder (node-mavlink): the live status is georeferenced
// during the flight, and the session at the end.
TEST(Onboard, GeoreferencedFlightWithMavlink) {
  if (std::getenv("UAVM_PEER_RUN") == nullptr || std::getenv("UAVM_PEER_MODULES") == nullptr)
    GTEST_SKIP() << "no MAVLink peer (node-mavlink): see vm_camera_test.sh's output";
  const std::string node = FindNode("vivid");
  const std::string output = FindVividOutput();
  ASSERT_FALSE(node.empty());
  ASSERT_FALSE(output.empty()) << "no vivid video output node (node_types in scripts/vm/init.sh)";
  const fs::path out = fs::temp_directory_path() / "onboard_flight";
  Flight flight;
  Fly(node, output, out, &flight);
  if (HasFatalFailure()) return;
  ExpectLiveGeoref(flight.status, out);
  nlohmann::json report;
  ExpectGeoreferencedSession(out, flight.wstatus, &report);
  const nlohmann::json& g = flight.status["georef"];
  Note("ONBOARD-GEOREF vivid 640x480 looped ground + MAVLink UDP (node-mavlink, up after " +
       std::to_string(flight.peer_start_s) + " s): live view georeferenced " + g.value("crs", "-") + " rms " +
       std::to_string(g.value("rms_m", -1.0)) + " m over " + std::to_string(g.value("frames_used", 0)) +
       " frames after " + std::to_string(flight.live_s) + " s (frame " +
       std::to_string(flight.status.value("frames_in", 0)) + "); session: registered " +
       std::to_string(report.value("registered", 0)) + "/" + std::to_string(report.value("frames_in", 0)) +
       ", placed by telemetry " + std::to_string(report["telemetry"].value("frames_placed", 0)) + ", georef rms " +
       std::to_string(report["georef"].value("rms_m", -1.0)) + " m; " + std::to_string(flight.pictures) +
       " pictures looped; " + std::to_string(flight.seconds) + " s");
}

}  // namespace
}  // namespace uavm::hal
