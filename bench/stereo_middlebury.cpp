// Middlebury benchmark of the dense matcher (core/stereo) against OpenCV's StereoSGBM in the same run: per pair
// bad-1 / bad-2 (share of pixels with known ground truth whose error exceeds 1 / 2 px; no disparity = wrong) and the
// median time of N runs. Prints a Markdown table.
#include <CLI/CLI.hpp>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <opencv2/calib3d.hpp>
#include <opencv2/core/utility.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <string>
#include <vector>

#include "core/stereo/sgm.h"

namespace {

struct Pair {
  const char* name;
  const char* left;
  const char* right;
  const char* gt;
  double scale;  // true disparity = GT value / scale
};

const Pair kPairs[] = {
    {"tsukuba", "im3.png", "im4.png", "disp3.pgm", 16},   {"venus", "im2.png", "im6.png", "disp2.pgm", 8},
    {"teddy", "im2.png", "im6.png", "disp2.png", 4},      {"cones", "im2.png", "im6.png", "disp2.png", 4},
    {"cloth3", "view1.png", "view5.png", "disp1.png", 2}, {"wood2", "view1.png", "view5.png", "disp1.png", 2},
};

struct Score {
  double bad1 = 0, bad2 = 0;
};

Score Evaluate(const cv::Mat& disp, const cv::Mat& gt, double scale) {
  size_t known = 0, bad1 = 0, bad2 = 0;
  for (int y = 0; y < gt.rows; ++y) {
    for (int x = 0; x < gt.cols; ++x) {
      const int g = gt.at<uint8_t>(y, x);
      if (g == 0) continue;
      ++known;
      const float d = disp.at<float>(y, x);
      const double err = std::isfinite(d) && d >= 0.0f ? std::abs(d - g / scale) : 1e9;
      bad1 += err > 1.0;
      bad2 += err > 2.0;
    }
  }
  const double k = static_cast<double>(std::max<size_t>(known, 1));
  return {100.0 * static_cast<double>(bad1) / k, 100.0 * static_cast<double>(bad2) / k};
}

// Median times of f and g over `runs` runs, interleaved so that both see the same machine load.
template <typename F, typename G>
std::pair<double, double> MedianMs(int runs, F&& f, G&& g) {
  std::vector<double> fa, ga;
  auto time = [](auto&& fn) {
    const auto t0 = std::chrono::steady_clock::now();
    fn();
    return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  };
  for (int i = 0; i < runs; ++i) {
    fa.push_back(time(f));
    ga.push_back(time(g));
  }
  std::sort(fa.begin(), fa.end());
  std::sort(ga.begin(), ga.end());
  return {fa[fa.size() / 2], ga[ga.size() / 2]};
}

cv::Mat ColorMap(const cv::Mat& disp, double max_disp) {
  cv::Mat u8(disp.size(), CV_8UC1);
  for (int y = 0; y < disp.rows; ++y)
    for (int x = 0; x < disp.cols; ++x) {
      const float d = disp.at<float>(y, x);
      u8.at<uint8_t>(y, x) = std::isfinite(d) ? cv::saturate_cast<uint8_t>(d * 255.0 / max_disp) : 0;
    }
  cv::Mat colour;
  cv::applyColorMap(u8, colour, cv::COLORMAP_TURBO);
  for (int y = 0; y < disp.rows; ++y)
    for (int x = 0; x < disp.cols; ++x)
      if (!std::isfinite(disp.at<float>(y, x))) colour.at<cv::Vec3b>(y, x) = cv::Vec3b(0, 0, 0);
  return colour;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"Middlebury stereo benchmark: core/stereo SGM vs OpenCV StereoSGBM (3-way, block 5)"};
  std::string data;
  int runs = 5;
  std::string png_pair = "teddy";
  std::string png_out;
  app.add_option("data", data, "middlebury_stereo directory")->required()->check(CLI::ExistingDirectory);
  app.add_option("--runs", runs, "timed runs per method (median reported)")->check(CLI::Range(1, 100));
  app.add_option("--png", png_out, "write GT | ours | SGBM colour-mapped disparity of --png-pair here");
  app.add_option("--png-pair", png_pair, "pair for --png");
  uavm::stereo::SgmOptions base;
  app.add_option("--paths", base.num_paths, "SGM paths (4 or 8)");
  app.add_option("--p1", base.p1);
  app.add_option("--p2", base.p2);
  app.add_option("--p2-min", base.p2_min);
  app.add_option("--p2-scale", base.p2_gradient_scale);
  app.add_option("--gradient-weight", base.gradient_weight);
  app.add_option("--census-w", base.census_width);
  app.add_option("--census-h", base.census_height);
  app.add_option("--uniqueness", base.uniqueness_ratio);
  app.add_option("--lr", base.lr_tolerance);
  app.add_option("--speckle", base.speckle_size);
  app.add_option("--median", base.median_size);
  std::string cost = "census";
  app.add_option("--cost", cost, "matching cost")->check(CLI::IsMember({"census", "daisy"}));
  app.add_option("--daisy-divisor", base.daisy_divisor, "DAISY L1 distance per cost unit");
  CLI11_PARSE(app, argc, argv);
  if (cost == "daisy") base.cost = uavm::stereo::SgmOptions::Cost::kDaisy;

  std::printf(
      "| pair | size | ndisp | ours bad-1 %% | ours bad-2 %% | ours ms | SGBM bad-1 %% | SGBM bad-2 %% | SGBM ms "
      "| time ratio |\n|---|---|---|---|---|---|---|---|---|---|\n");
  double sum[6] = {0, 0, 0, 0, 0, 0};
  int n = 0;
  for (const Pair& pair : kPairs) {
    const std::filesystem::path dir = std::filesystem::path(data) / pair.name;
    const cv::Mat left = cv::imread((dir / pair.left).string(), cv::IMREAD_COLOR);
    const cv::Mat right = cv::imread((dir / pair.right).string(), cv::IMREAD_COLOR);
    const cv::Mat gt = cv::imread((dir / pair.gt).string(), cv::IMREAD_GRAYSCALE);
    if (left.empty() || right.empty() || gt.empty() || left.size() != right.size() || gt.size() != left.size()) {
      std::fprintf(stderr, "cannot read pair %s in %s\n", pair.name, dir.c_str());
      return 1;
    }
    double gt_max = 0;
    cv::minMaxLoc(gt, nullptr, &gt_max);
    const int ndisp = static_cast<int>(std::ceil((gt_max / pair.scale + 1.0) / 16.0)) * 16;

    uavm::stereo::SgmOptions options = base;
    options.num_disparities = ndisp;
    uavm::stereo::SgmMatcher matcher(options);
    cv::Mat ours;
    std::string error;
    bool ok = true;
    auto sgbm = cv::StereoSGBM::create(0, ndisp, 5, 8 * 3 * 25, 32 * 3 * 25, 1, 63, 10, 100, 32,
                                       cv::StereoSGBM::MODE_SGBM_3WAY);
    cv::Mat raw;
    const auto [ours_ms, sgbm_ms] = MedianMs(
        runs, [&] { ok = ok && matcher.Compute(left, right, &ours, &error); },
        [&] { sgbm->compute(left, right, raw); });
    if (!ok) {
      std::fprintf(stderr, "%s: %s\n", pair.name, error.c_str());
      return 1;
    }
    cv::Mat theirs(raw.size(), CV_32FC1);
    for (int y = 0; y < raw.rows; ++y)
      for (int x = 0; x < raw.cols; ++x) {
        const int16_t v = raw.at<int16_t>(y, x);
        theirs.at<float>(y, x) = v < 0 ? std::numeric_limits<float>::quiet_NaN() : v / 16.0f;
      }
    const Score a = Evaluate(ours, gt, pair.scale);
    const Score b = Evaluate(theirs, gt, pair.scale);
    std::printf("| %s | %dx%d | %d | %.2f | %.2f | %.1f | %.2f | %.2f | %.1f | %.2f |\n", pair.name, left.cols,
                left.rows, ndisp, a.bad1, a.bad2, ours_ms, b.bad1, b.bad2, sgbm_ms, ours_ms / sgbm_ms);
    std::fflush(stdout);
    const double v[6] = {a.bad1, a.bad2, ours_ms, b.bad1, b.bad2, sgbm_ms};
    for (int k = 0; k < 6; ++k) sum[k] += v[k];
    ++n;
    if (!png_out.empty() && png_pair == pair.name) {
      cv::Mat gt_disp;
      gt.convertTo(gt_disp, CV_32F, 1.0 / pair.scale);
      gt_disp.setTo(std::numeric_limits<float>::quiet_NaN(), gt == 0);
      cv::Mat row;
      cv::hconcat(std::vector<cv::Mat>{ColorMap(gt_disp, ndisp), ColorMap(ours, ndisp), ColorMap(theirs, ndisp)}, row);
      if (!cv::imwrite(png_out, row)) std::fprintf(stderr, "cannot write %s\n", png_out.c_str());
    }
  }
  std::printf("| **mean** | | | %.2f | %.2f | %.1f | %.2f | %.2f | %.1f | %.2f |\n", sum[0] / n, sum[1] / n, sum[2] / n,
              sum[3] / n, sum[4] / n, sum[5] / n, sum[2] / sum[5]);
  std::printf("\nthreads: %d, runs per method: %d (median time), OpenCV %s\n", cv::getNumThreads(), runs, CV_VERSION);
  return 0;
}
