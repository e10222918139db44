// Does a Debian library serve as the onboard SIFT (issue 40)? Side by side on the same frames: core/features (OpenCV
// 4.6's SIFT, doubled first octave, RootSIFT: today's onboard detector), the same on a half-size copy (no doubled
// octave), and VLFeat's vl_sift (libvlfeat-dev) with its first octave at -1 (doubled) and 0.
// For each: detection + description time (median over the frames and repeats, one thread), keypoints, and on pairs
// with a known homography (each frame against a copy warped by a random rotation, scale and perspective, with noise
// and a JPEG round trip) the correct matches (mutual nearest neighbours passing Lowe's ratio 0.8, within 1.5 px of the
// truth), their share, and the RMS of their position error: what the registration's accuracy rests on.
// Usage: uavm-sift-peers --images DIR [--frames N] [--repeat R] [--work-size PX] [--only N]
#include <vl/sift.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <opencv2/core.hpp>
#include <opencv2/features2d.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <random>
#include <string>
#include <vector>

#include "core/features/sift.h"

namespace {

struct Detected {
  std::vector<cv::Point2f> points;
  cv::Mat descriptors;  // CV_32F, RootSIFT-normalised for every detector (fair matching)
};
using Detector = std::function<Detected(const cv::Mat& gray)>;

void RootSift(cv::Mat* d) {
  for (int r = 0; r < d->rows; ++r) {
    cv::Mat row = d->row(r);
    const double l1 = cv::norm(row, cv::NORM_L1);
    if (l1 > 0) row /= l1;
    cv::sqrt(row, row);
  }
}

Detected Ours(const cv::Mat& gray, bool opencv, bool half) {
  uavm::FeatureOptions o;
  o.opencv_sift = opencv;
  o.half_size = half;
  o.target_min_features = 0;  // one pass at the onboard threshold, as for the VLFeat runs
  const uavm::Features f = uavm::SiftExtractor(o).Extract(gray);
  return {f.points, f.descriptors.clone()};
}

// VLFeat with OpenCV's settings: 3 levels per octave, sigma 1.6, edge ratio 10, the same DoG threshold (OpenCV's
// 0.5 * contrast / levels on 0..255 pixels; VLFeat takes 0..1 pixels), the strongest max_features kept by scale as a
// stand-in (VLFeat does not return the DoG peak value).
Detected Vl(const cv::Mat& gray, int first_octave, double contrast, int max_features) {
  cv::Mat f32;
  gray.convertTo(f32, CV_32F, 1.0 / 255.0);
  VlSiftFilt* filt = vl_sift_new(f32.cols, f32.rows, -1, 3, first_octave);
  vl_sift_set_peak_thresh(filt, 0.5 * contrast / 3.0);
  vl_sift_set_edge_thresh(filt, 10.0);
  Detected out;
  std::vector<std::array<float, 128>> rows;
  std::vector<float> scales;
  int err = vl_sift_process_first_octave(filt, reinterpret_cast<const vl_sift_pix*>(f32.data));
  while (err == VL_ERR_OK) {
    vl_sift_detect(filt);
    const VlSiftKeypoint* keys = vl_sift_get_keypoints(filt);
    for (int k = 0; k < vl_sift_get_nkeypoints(filt); ++k) {
      double angles[4];
      const int n = vl_sift_calc_keypoint_orientations(filt, angles, &keys[k]);
      for (int a = 0; a < n; ++a) {
        std::array<float, 128> d{};
        vl_sift_calc_keypoint_descriptor(filt, d.data(), &keys[k], angles[a]);
        rows.push_back(d);
        out.points.emplace_back(keys[k].x, keys[k].y);
        scales.push_back(keys[k].sigma);
      }
    }
    err = vl_sift_process_next_octave(filt);
  }
  vl_sift_delete(filt);
  std::vector<size_t> order(rows.size());
  for (size_t i = 0; i < order.size(); ++i) order[i] = i;
  std::stable_sort(order.begin(), order.end(), [&](size_t a, size_t b) { return scales[a] > scales[b]; });
  if (order.size() > static_cast<size_t>(max_features)) order.resize(static_cast<size_t>(max_features));
  std::vector<cv::Point2f> kept;
  out.descriptors.create(static_cast<int>(order.size()), 128, CV_32F);
  for (size_t i = 0; i < order.size(); ++i) {
    kept.push_back(out.points[order[i]]);
    std::copy(rows[order[i]].begin(), rows[order[i]].end(), out.descriptors.ptr<float>(static_cast<int>(i)));
  }
  out.points = kept;
  RootSift(&out.descriptors);
  return out;
}

// A random view of the same ground: rotation up to 30 deg, scale 0.85-1.15, a little perspective, about the centre.
cv::Mat RandomHomography(cv::Size size, std::mt19937* rng) {
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  const double a = u(*rng) * 30.0 * CV_PI / 180.0, s = 1.0 + 0.15 * u(*rng);
  const double cx = size.width / 2.0, cy = size.height / 2.0;
  cv::Mat t1 = (cv::Mat_<double>(3, 3) << 1, 0, -cx, 0, 1, -cy, 0, 0, 1);
  cv::Mat r = (cv::Mat_<double>(3, 3) << s * std::cos(a), -s * std::sin(a), 0, s * std::sin(a), s * std::cos(a), 0,
               1e-4 * u(*rng), 1e-4 * u(*rng), 1);
  cv::Mat t2 = (cv::Mat_<double>(3, 3) << 1, 0, cx + 20 * u(*rng), 0, 1, cy + 20 * u(*rng), 0, 0, 1);
  return t2 * r * t1;
}

struct PairScore {
  int matches = 0, correct = 0;
  double sq = 0;
};

PairScore Score(const Detected& a, const Detected& b, const cv::Mat& b_from_a) {
  PairScore s;
  if (a.descriptors.empty() || b.descriptors.empty()) return s;
  cv::BFMatcher bf(cv::NORM_L2);
  std::vector<std::vector<cv::DMatch>> ab, ba;
  bf.knnMatch(a.descriptors, b.descriptors, ab, 2);
  bf.knnMatch(b.descriptors, a.descriptors, ba, 1);
  for (const auto& m : ab) {
    if (m.size() < 2 || m[0].distance > 0.8f * m[1].distance) continue;
    if (ba[static_cast<size_t>(m[0].trainIdx)].empty() ||
        ba[static_cast<size_t>(m[0].trainIdx)][0].trainIdx != m[0].queryIdx)
      continue;
    ++s.matches;
    const cv::Point2f p = a.points[static_cast<size_t>(m[0].queryIdx)];
    const cv::Mat x = b_from_a * (cv::Mat_<double>(3, 1) << p.x, p.y, 1.0);
    const cv::Point2d want(x.at<double>(0) / x.at<double>(2), x.at<double>(1) / x.at<double>(2));
    const cv::Point2f got = b.points[static_cast<size_t>(m[0].trainIdx)];
    const double e2 = (want.x - got.x) * (want.x - got.x) + (want.y - got.y) * (want.y - got.y);
    if (e2 < 1.5 * 1.5) {
      ++s.correct;
      s.sq += e2;
    }
  }
  return s;
}

double Median(std::vector<double> v) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App cli{"SIFT detectors side by side (issue 40)"};
  std::string images;
  int frames = 8, repeat = 3, work = 1000, only = -1;
  cli.add_option("--images", images, "Folder of frames")->required();
  cli.add_option("--frames", frames, "Frames to use");
  cli.add_option("--repeat", repeat, "Timed runs per frame and detector");
  cli.add_option("--work-size", work, "Long side of the working copy, px (onboard default 1000)");
  cli.add_option("--only", only, "Run only detector N (0-4, in the table's order; for a profiler)");
  CLI11_PARSE(cli, argc, argv);
  cv::setNumThreads(1);  // one core each: OpenCV's SIFT would otherwise spread over both, VLFeat does not
  std::vector<std::string> files;
  for (const auto& e : std::filesystem::directory_iterator(images)) files.push_back(e.path().string());
  std::sort(files.begin(), files.end());
  if (static_cast<int>(files.size()) > frames) files.resize(static_cast<size_t>(frames));
  const std::vector<std::pair<std::string, Detector>> detectors = {
      {"ours (core/features/dog_sift, doubled)", [](const cv::Mat& g) { return Ours(g, false, false); }},
      {"opencv 4.6 (doubled)", [](const cv::Mat& g) { return Ours(g, true, false); }},
      {"opencv 4.6 on a half-size copy", [](const cv::Mat& g) { return Ours(g, true, true); }},
      {"vlfeat 0.9.21, first octave -1", [](const cv::Mat& g) { return Vl(g, -1, 0.01, 3000); }},
      {"vlfeat 0.9.21, first octave 0", [](const cv::Mat& g) { return Vl(g, 0, 0.01, 3000); }}};
  std::mt19937 rng(40);
  std::vector<cv::Mat> grays, warped, truths;
  for (const auto& f : files) {
    cv::Mat img = cv::imread(f, cv::IMREAD_GRAYSCALE);
    if (img.empty()) continue;
    const double k = static_cast<double>(work) / std::max(img.cols, img.rows);
    cv::resize(img, img, cv::Size(), k, k, cv::INTER_AREA);
    const cv::Mat h = RandomHomography(img.size(), &rng);
    cv::Mat w, noise(img.size(), CV_16S);
    cv::warpPerspective(img, w, h, img.size(), cv::INTER_LINEAR, cv::BORDER_REFLECT);
    cv::randn(noise, 0, 2.0);
    w.convertTo(w, CV_16S);
    w += noise;
    w.convertTo(w, CV_8U);
    std::vector<uchar> jpeg;
    cv::imencode(".jpg", w, jpeg, {cv::IMWRITE_JPEG_QUALITY, 90});
    grays.push_back(img);
    warped.push_back(cv::imdecode(jpeg, cv::IMREAD_GRAYSCALE));
    truths.push_back(h);
  }
  std::printf("%zu frames of %dx%d (work size %d), %d timed runs each, one thread\n\n", grays.size(),
              grays.empty() ? 0 : grays[0].cols, grays.empty() ? 0 : grays[0].rows, work, repeat);
  std::printf(
      "| detector | ms per frame (median) | keypoints (median) | matches | correct (<1.5 px) | share | RMS of correct, "
      "px |\n");
  std::printf("|---|---:|---:|---:|---:|---:|---:|\n");
  for (size_t d = 0; d < detectors.size(); ++d) {
    if (only >= 0 && static_cast<size_t>(only) != d) continue;
    const auto& [name, detect] = detectors[d];
    std::vector<double> ms, counts;
    PairScore total;
    for (size_t i = 0; i < grays.size(); ++i) {
      Detected a;
      for (int r = 0; r < repeat; ++r) {
        const auto t0 = std::chrono::steady_clock::now();
        a = detect(grays[i]);
        ms.push_back(std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
      }
      counts.push_back(static_cast<double>(a.points.size()));
      const PairScore s = Score(a, detect(warped[i]), truths[i]);
      total.matches += s.matches;
      total.correct += s.correct;
      total.sq += s.sq;
    }
    std::printf("| %s | %.1f | %.0f | %d | %d | %.3f | %.3f |\n", name.c_str(), Median(ms), Median(counts),
                total.matches, total.correct, total.matches ? static_cast<double>(total.correct) / total.matches : 0.0,
                total.correct ? std::sqrt(total.sq / total.correct) : 0.0);
  }
  return 0;
}
