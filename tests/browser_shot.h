// Headless Chromium screenshots for the page tests (Debian's `chromium`, installed by scripts/setup.sh).
#pragma once
#include <sys/wait.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <string>

namespace uavm::test {

inline std::string ChromiumBinary() {
  for (const char* c : {"/usr/bin/chromium", "/usr/bin/chromium-browser"})
    if (::access(c, X_OK) == 0) return c;
  return {};
}

// Loads `url` in a fresh profile and returns the 800x600 screenshot (empty on failure). The virtual time budget lets
// the page's scripts and tile loads settle before the picture is taken.
inline cv::Mat Screenshot(const std::string& url, const std::filesystem::path& work, int budget_ms = 5000,
                          cv::Size window = cv::Size(800, 600)) {
  const std::string chromium = ChromiumBinary();
  if (chromium.empty()) return {};
  std::filesystem::remove_all(work);
  std::filesystem::create_directories(work / "profile");
  const auto png = work / "shot.png";
  const std::string cmd = "timeout 120 " + chromium +
                          " --headless --no-sandbox --disable-gpu --disable-background-networking"
                          " --disable-component-update --no-first-run --user-data-dir=" +
                          (work / "profile").string() + " --screenshot=" + png.string() +
                          " --window-size=" + std::to_string(window.width) + "," + std::to_string(window.height) +
                          " --virtual-time-budget=" + std::to_string(budget_ms) + " '" + url + "' >" +
                          (work / "chromium.log").string() + " 2>&1";
  const int status = std::system(cmd.c_str());
  if (!WIFEXITED(status)) return {};
  return cv::imread(png.string(), cv::IMREAD_COLOR);
}

// Share of the screenshot's central area (away from the page's controls) that is not the black page background, and
// the mean colour of those pixels.
inline double ContentShare(const cv::Mat& shot, cv::Scalar* mean_bgr) {
  const cv::Mat centre = shot(cv::Rect(100, 100, shot.cols - 200, shot.rows - 160));
  cv::Mat gray, mask;
  cv::cvtColor(centre, gray, cv::COLOR_BGR2GRAY);
  mask = gray > 20;
  *mean_bgr = cv::mean(centre, mask);
  return static_cast<double>(cv::countNonZero(mask)) / static_cast<double>(mask.total());
}

// For pages fed by a running process (live view): a loaded machine can leave the first picture undrawn when the
// virtual time runs out, so the page is shot again with a longer budget, up to three times, until the live picture
// covers `min_share` of the view. Returns the last shot (the test still judges it).
inline cv::Mat ScreenshotUntilDrawn(const std::string& url, const std::filesystem::path& work, double min_share,
                                    int budget_ms = 4000) {
  cv::Mat shot;
  for (int attempt = 0; attempt < 3; ++attempt, budget_ms *= 2) {
    shot = Screenshot(url, work, budget_ms);
    cv::Scalar unused;
    if (!shot.empty() && ContentShare(shot, &unused) > min_share) break;
  }
  return shot;
}

// Mean colour of an image's pixels that are opaque (BGRA) or not black (BGR).
inline cv::Scalar ContentMean(const cv::Mat& img) {
  cv::Mat bgr, mask;
  if (img.channels() == 4) {
    cv::extractChannel(img, mask, 3);
    mask = mask > 0;
    cv::cvtColor(img, bgr, cv::COLOR_BGRA2BGR);
  } else {
    bgr = img;
    cv::Mat gray;
    cv::cvtColor(img, gray, cv::COLOR_BGR2GRAY);
    mask = gray > 20;
  }
  return cv::mean(bgr, mask);
}

}  // namespace uavm::test
