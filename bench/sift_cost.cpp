// What detection costs on every frame of a flight, with nothing else running (issue 40: "detection at a third of its
// cost"). In flight the detector shares two cores with the decode and the registration, and its stage time there is
// its share of a saturated machine as much as its own cost; here each frame's working copy (long side --work-size,
// grey, as the flight makes it) goes through our SIFT with the product's defaults and through OpenCV 4.6's SIFT in
// the plan it replaced (the same thresholds and ladder, the frame in --opencv-bands horizontal bands: the flights'
// memory plan gave 3), alternately, --repeat times each. Per frame the medians of wall time and of the process's CPU
// time (getrusage: both threads of the pool, nothing else runs); per flight the medians over its frames and their
// ratio.
// Usage: uavm-sift-cost --images DIR [--frames N] [--repeat R] [--work-size PX] [--opencv-bands B] [--label NAME]
#include <sys/resource.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <string>
#include <thread>
#include <vector>

#include "core/buffers/mat_pool.h"
#include "core/features/sift.h"

namespace {

namespace fs = std::filesystem;

double CpuMs() {
  rusage u{};
  getrusage(RUSAGE_SELF, &u);
  auto ms = [](const timeval& t) {
    return static_cast<double>(t.tv_sec) * 1e3 + static_cast<double>(t.tv_usec) * 1e-3;
  };
  return ms(u.ru_utime) + ms(u.ru_stime);
}

double Median(std::vector<double> v) {
  if (v.empty()) return 0.0;
  std::sort(v.begin(), v.end());
  const size_t n = v.size();
  return n % 2 == 1 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

// The working copy as the flight makes it: JPEG decoded DCT-scaled (OpenCV's reduced modes) to at least the working
// size, area-averaged to it, grey.
cv::Mat WorkingGray(const std::string& path, int work_size) {
  cv::Mat probe = cv::imread(path, cv::IMREAD_GRAYSCALE | cv::IMREAD_IGNORE_ORIENTATION);
  if (probe.empty()) return probe;
  const int long_side = std::max(probe.cols, probe.rows);
  int mode = cv::IMREAD_GRAYSCALE;
  if (long_side / 8 >= work_size)
    mode = cv::IMREAD_REDUCED_GRAYSCALE_8;
  else if (long_side / 4 >= work_size)
    mode = cv::IMREAD_REDUCED_GRAYSCALE_4;
  else if (long_side / 2 >= work_size)
    mode = cv::IMREAD_REDUCED_GRAYSCALE_2;
  cv::Mat gray = mode == cv::IMREAD_GRAYSCALE ? probe : cv::imread(path, mode | cv::IMREAD_IGNORE_ORIENTATION);
  const double s = static_cast<double>(work_size) / std::max(gray.cols, gray.rows);
  if (s < 1.0) cv::resize(gray, gray, cv::Size(), s, s, cv::INTER_AREA);
  return gray;
}

struct Sample {
  std::vector<double> wall_ms, cpu_ms, keypoints;
};

void Time(const uavm::SiftExtractor& sift, const cv::Mat& gray, int repeat, int pause_ms, Sample* frame) {
  for (int r = 0; r < repeat; ++r) {
    // A camera's cadence: the threads idle between frames, as in flight (their pool's workers asleep).
    if (pause_ms > 0) std::this_thread::sleep_for(std::chrono::milliseconds(pause_ms));
    const double cpu0 = CpuMs();
    const auto t0 = std::chrono::steady_clock::now();
    const uavm::Features f = sift.Extract(gray);
    const auto t1 = std::chrono::steady_clock::now();
    frame->cpu_ms.push_back(CpuMs() - cpu0);
    frame->wall_ms.push_back(std::chrono::duration<double, std::milli>(t1 - t0).count());
    frame->keypoints.push_back(static_cast<double>(f.size()));
  }
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"Our SIFT against OpenCV's in the plan it replaced, on every frame of a flight, nothing else running"};
  std::string images;
  std::string label;
  int frames = 0;
  int repeat = 3;
  int work_size = 1000;
  int opencv_bands = 3;
  int pause_ms = 0;
  app.add_option("--images", images, "folder of the flight's photographs")->required();
  app.add_option("--frames", frames, "at most this many frames, evenly spread (0 = all)");
  app.add_option("--repeat", repeat, "runs of each detector per frame (median)")->check(CLI::PositiveNumber);
  app.add_option("--work-size", work_size, "working copy's long side (the onboard default)")
      ->check(CLI::PositiveNumber);
  app.add_option("--opencv-bands", opencv_bands, "OpenCV's SIFT in this many bands")->check(CLI::Range(1, 16));
  app.add_option("--label", label, "name of the flight in the table");
  app.add_option("--pause-ms", pause_ms, "idle this long before each detection (a camera's cadence; 0 = none)")
      ->check(CLI::NonNegativeNumber);
  CLI11_PARSE(app, argc, argv);

  std::vector<std::string> paths;
  for (const auto& e : fs::directory_iterator(images))
    if (e.is_regular_file()) paths.push_back(e.path().string());
  std::sort(paths.begin(), paths.end());
  if (frames > 0 && static_cast<int>(paths.size()) > frames) {
    std::vector<std::string> spread;
    for (int i = 0; i < frames; ++i) spread.push_back(paths[paths.size() * static_cast<size_t>(i) / frames]);
    paths = spread;
  }
  uavm::InstallMatPool();  // the scale space's large buffers reused frame after frame, as in the program
  Sample ours_all;
  Sample opencv_all;
  int used = 0;
  for (const std::string& path : paths) {
    const cv::Mat gray = WorkingGray(path, work_size);
    if (gray.empty()) {
      std::fprintf(stderr, "skipped %s: not an image\n", path.c_str());
      continue;
    }
    uavm::FeatureOptions ours;
    uavm::FeatureOptions opencv;
    opencv.opencv_sift = true;
    // The largest scale-space cap that still gives `opencv_bands` bands (the memory plan's cap did in flight).
    int mib = static_cast<int>(uavm::SiftScaleSpaceMiB(gray.cols, gray.rows, opencv));
    opencv.max_scale_space_mib = opencv_bands > 1 ? mib : 0;
    while (opencv_bands > 1 && mib > 1 && uavm::SiftBands(gray.cols, gray.rows, opencv) < opencv_bands)
      opencv.max_scale_space_mib = --mib;
    Sample a;
    Sample b;
    for (int r = 0; r < repeat; ++r) {  // alternately, so that the machine's drift reaches both alike
      Time(uavm::SiftExtractor(ours), gray, 1, pause_ms, &a);
      Time(uavm::SiftExtractor(opencv), gray, 1, pause_ms, &b);
    }
    ours_all.wall_ms.push_back(Median(a.wall_ms));
    ours_all.cpu_ms.push_back(Median(a.cpu_ms));
    ours_all.keypoints.push_back(Median(a.keypoints));
    opencv_all.wall_ms.push_back(Median(b.wall_ms));
    opencv_all.cpu_ms.push_back(Median(b.cpu_ms));
    opencv_all.keypoints.push_back(Median(b.keypoints));
    ++used;
  }
  if (used == 0) {
    std::fprintf(stderr, "no frames in %s\n", images.c_str());
    return 1;
  }
  const double ow = Median(ours_all.wall_ms);
  const double cw = Median(opencv_all.wall_ms);
  const double oc = Median(ours_all.cpu_ms);
  const double cc = Median(opencv_all.cpu_ms);
  std::printf("| %s | %d | %.1f | %.1f | %.2f | %.1f | %.1f | %.2f | %.0f / %.0f |\n",
              label.empty() ? images.c_str() : label.c_str(), used, ow, cw, ow / cw, oc, cc, oc / cc,
              Median(ours_all.keypoints), Median(opencv_all.keypoints));
  return 0;
}
