// Google Benchmark micro-benchmarks of the per-frame stages on real frames (two consecutive caliterra_small frames,
// 1000x750, bundled in tests/data): SIFT whole and banded (the memory plan's bands), descriptor index build, guided
// and unguided pair matching, RANSAC alone, JPEG decode, PNG tile encode. bench/micro.sh runs it and keeps the table.
// Image buffers come from the Mat pool, as in the program.
// UAVM_MICRO_IMAGES overrides the image folder (its first two files, sorted by name, are used).
#include <benchmark/benchmark.h>

#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <string>
#include <vector>

#include "core/buffers/mat_pool.h"
#include "core/estimators/affine.h"
#include "core/estimators/ransac.h"
#include "core/features/sift.h"
#include "core/imageio/jpeg_region.h"
#include "core/imageio/png_writer.h"
#include "core/matching/pair_matcher.h"

namespace {

namespace fs = std::filesystem;

std::vector<std::string> FramePaths() {
  const char* env = std::getenv("UAVM_MICRO_IMAGES");
  const fs::path dir = env != nullptr ? fs::path(env) : fs::path(UAVM_SOURCE_DIR) / "tests/data/caliterra_small/images";
  std::vector<std::string> paths;
  for (const auto& e : fs::directory_iterator(dir))
    if (e.is_regular_file()) paths.push_back(e.path().string());
  std::sort(paths.begin(), paths.end());
  return paths;
}

// Two consecutive frames at working resolution (long side 1000 px, as the onboard default), gray, and their features.
struct Pair {
  std::string jpeg_path;
  cv::Mat gray[2];
  uavm::Features features[2];
};

const Pair& Frames() {
  static const Pair pair = [] {
    Pair p;
    const std::vector<std::string> paths = FramePaths();
    if (paths.size() < 2) return p;
    p.jpeg_path = paths[0];
    for (int k = 0; k < 2; ++k) {
      cv::Mat img = cv::imread(paths[static_cast<size_t>(k)], cv::IMREAD_GRAYSCALE);
      const double s = 1000.0 / std::max(img.cols, img.rows);
      if (s < 1.0) cv::resize(img, img, cv::Size(), s, s, cv::INTER_AREA);
      p.gray[k] = img;
      p.features[k] = uavm::SiftExtractor(uavm::FeatureOptions{}).Extract(img);
    }
    return p;
  }();
  return pair;
}

bool Ready(benchmark::State& state) {
  if (Frames().gray[0].empty()) {
    state.SkipWithError("no frames: set UAVM_MICRO_IMAGES");
    return false;
  }
  return true;
}

// Args: bands (1 = whole frame), 1 = OpenCV 4.6's SIFT instead of ours.
void BM_SiftExtract(benchmark::State& state) {
  if (!Ready(state)) return;
  const cv::Mat& gray = Frames().gray[0];
  uavm::FeatureOptions options;
  options.opencv_sift = state.range(1) == 1;
  const int bands = static_cast<int>(state.range(0));
  if (bands > 1) {
    // The largest cap that still gives `bands` bands.
    int mib = static_cast<int>(uavm::SiftScaleSpaceMiB(gray.cols, gray.rows, options));
    options.max_scale_space_mib = mib;
    while (mib > 1 && uavm::SiftBands(gray.cols, gray.rows, options) < bands) options.max_scale_space_mib = --mib;
  }
  size_t n = 0;
  for (auto _ : state) n = uavm::SiftExtractor(options).Extract(gray).size();
  state.counters["keypoints"] = static_cast<double>(n);
  state.counters["bands"] = uavm::SiftBands(gray.cols, gray.rows, options);
}
BENCHMARK(BM_SiftExtract)
    ->Args({1, 0})
    ->Args({2, 0})
    ->Args({1, 1})
    ->Args({3, 1})
    ->Unit(benchmark::kMillisecond)
    ->MeasureProcessCPUTime()
    ->UseRealTime();

// Arg (and the second Arg of BM_MatchPair): kd-tree leaf size, 1 = cvflann's KDTreeIndex at its former 32 checks,
// 4 = the bucketed kd-forest (core/matching/kd_forest.h) at 64.
uavm::MatchOptions TreeOptions(int64_t leaf_size) {
  uavm::MatchOptions options;
  options.flann_leaf_size = static_cast<int>(leaf_size);
  options.flann_checks = leaf_size == 1 ? 32 : 64;
  return options;
}

void BM_IndexBuild(benchmark::State& state) {
  if (!Ready(state)) return;
  const uavm::MatchOptions options = TreeOptions(state.range(0));
  for (auto _ : state) {
    uavm::DescriptorIndex index(Frames().features[0], options);
    benchmark::DoNotOptimize(index.empty());
  }
}
BENCHMARK(BM_IndexBuild)->Arg(1)->Arg(4)->Unit(benchmark::kMillisecond)->UseRealTime();

void BM_IndexQuery(benchmark::State& state) {
  if (!Ready(state)) return;
  const uavm::MatchOptions options = TreeOptions(state.range(0));
  const uavm::DescriptorIndex index(Frames().features[0], options);
  size_t n = 0;
  for (auto _ : state) n = index.Match(Frames().features[1].descriptors).size();
  state.counters["matches"] = static_cast<double>(n);
}
BENCHMARK(BM_IndexQuery)->Arg(1)->Arg(4)->Unit(benchmark::kMillisecond)->UseRealTime();

// Arg: 0 = all points queried; 1 = guided by the relative transform (predicted-inside points, at most
// max_guided_queries of them); 2 = guided without the cap.
void BM_MatchPair(benchmark::State& state) {
  if (!Ready(state)) return;
  const Pair& p = Frames();
  uavm::MatchOptions options = TreeOptions(state.range(1));
  if (state.range(0) == 2) options.max_guided_queries = 0;
  const uavm::DescriptorIndex index(p.features[0], options);
  const uavm::PairResult unguided = uavm::MatchPair(index, p.features[0], p.features[1], options);
  uavm::MatchGuide guide;
  guide.tgt_from_src = unguided.tgt_from_src;
  guide.tgt_size = p.gray[0].size();
  const bool guided = state.range(0) != 0;
  int inliers = 0;
  int queries_matched = 0;
  for (auto _ : state) {
    const uavm::PairResult r = uavm::MatchPair(index, p.features[0], p.features[1], options, guided ? &guide : nullptr);
    inliers = r.num_inliers;
    queries_matched = r.num_matches;
  }
  state.counters["matches"] = queries_matched;
  state.counters["inliers"] = inliers;
}
BENCHMARK(BM_MatchPair)
    ->Args({0, 1})
    ->Args({0, 4})
    ->Args({1, 1})
    ->Args({1, 4})
    ->Args({2, 4})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

// RANSAC<AffineEstimator> alone on the pair's putative matches (their inlier share as it comes).
void BM_RansacAffine(benchmark::State& state) {
  if (!Ready(state)) return;
  const Pair& p = Frames();
  const uavm::DescriptorIndex index(p.features[0], uavm::MatchOptions{});
  std::vector<uavm::Vec2> x, y;
  for (const cv::DMatch& m : index.Match(p.features[1].descriptors)) {
    const cv::Point2f a = p.features[1].points[static_cast<size_t>(m.queryIdx)];
    const cv::Point2f b = p.features[0].points[static_cast<size_t>(m.trainIdx)];
    x.emplace_back(a.x, a.y);
    y.emplace_back(b.x, b.y);
  }
  const uavm::RANSAC<uavm::AffineEstimator> ransac(uavm::RansacOptions{});
  size_t inliers = 0;
  int iterations = 0;
  for (auto _ : state) {
    const auto report = ransac.Estimate(x, y);
    inliers = report.num_inliers;
    iterations = report.iterations;
  }
  state.counters["matches"] = static_cast<double>(x.size());
  state.counters["inliers"] = static_cast<double>(inliers);
  state.counters["iterations"] = iterations;
}
BENCHMARK(BM_RansacAffine)->Unit(benchmark::kMillisecond)->UseRealTime();

// Arg: DCT scale denominator (1, 2, 4, 8).
void BM_JpegDecode(benchmark::State& state) {
  if (!Ready(state)) return;
  const int reduce = static_cast<int>(state.range(0));
  const int flag = reduce == 8   ? cv::IMREAD_REDUCED_COLOR_8
                   : reduce == 4 ? cv::IMREAD_REDUCED_COLOR_4
                   : reduce == 2 ? cv::IMREAD_REDUCED_COLOR_2
                                 : cv::IMREAD_COLOR;
  cv::Size size;
  for (auto _ : state) size = cv::imread(Frames().jpeg_path, flag).size();
  state.counters["megapixels"] = size.area() / 1e6;
}
BENCHMARK(BM_JpegDecode)->Arg(1)->Arg(2)->Arg(4)->Unit(benchmark::kMillisecond)->UseRealTime();

// Part of a frame decoded at 1/2 (core/imageio): Arg 0 = percent of the side kept (a centred square share), Arg 1 =
// where the part sits (0 top, 1 bottom: rows above it are skipped but still entropy-decoded).
void BM_JpegDecodeRegion(benchmark::State& state) {
  if (!Ready(state)) return;
  const double share = static_cast<double>(state.range(0)) / 100.0;
  uavm::JpegRegion part;
  std::string why;
  if (!uavm::DecodeJpegRegion(Frames().jpeg_path, 2, cv::Rect(0, 0, 1, 1), &part, &why)) {
    state.SkipWithError(why.c_str());
    return;
  }
  const cv::Size whole = part.scaled_size;
  const cv::Size size(static_cast<int>(whole.width * share), static_cast<int>(whole.height * share));
  const cv::Rect region((whole.width - size.width) / 2, state.range(1) == 0 ? 0 : whole.height - size.height,
                        size.width, size.height);
  for (auto _ : state) benchmark::DoNotOptimize(uavm::DecodeJpegRegion(Frames().jpeg_path, 2, region, &part, &why));
  state.counters["megapixels"] = region.area() / 1e6;
}
BENCHMARK(BM_JpegDecodeRegion)
    ->Args({100, 0})
    ->Args({50, 0})
    ->Args({50, 1})
    ->Args({25, 1})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

// One 256 px BGRA map tile of real ground; Arg: PNG compression level.
void BM_TilePngEncode(benchmark::State& state) {
  if (!Ready(state)) return;
  cv::Mat bgr = cv::imread(Frames().jpeg_path, cv::IMREAD_COLOR)(cv::Rect(100, 100, 256, 256));
  cv::Mat tile;
  cv::cvtColor(bgr, tile, cv::COLOR_BGR2BGRA);
  const std::vector<int> params = {cv::IMWRITE_PNG_COMPRESSION, static_cast<int>(state.range(0))};
  std::vector<uchar> png;
  for (auto _ : state) cv::imencode(".png", tile, png, params);
  state.counters["kib"] = static_cast<double>(png.size()) / 1024.0;
}
BENCHMARK(BM_TilePngEncode)->Arg(1)->Arg(3)->Arg(6)->Unit(benchmark::kMillisecond)->UseRealTime();

// The same tile through the products' encoder (core/imageio/png_writer.h); Arg: libdeflate level.
void BM_TilePngLibdeflate(benchmark::State& state) {
  if (!Ready(state)) return;
  cv::Mat bgr = cv::imread(Frames().jpeg_path, cv::IMREAD_COLOR)(cv::Rect(100, 100, 256, 256));
  cv::Mat tile;
  cv::cvtColor(bgr, tile, cv::COLOR_BGR2BGRA);
  uavm::PngWriter writer(static_cast<int>(state.range(0)));
  std::vector<uint8_t> png;
  for (auto _ : state) benchmark::DoNotOptimize(writer.Encode(tile, &png));
  state.counters["kib"] = static_cast<double>(png.size()) / 1024.0;
}
BENCHMARK(BM_TilePngLibdeflate)->Arg(1)->Arg(3)->Arg(6)->Unit(benchmark::kMillisecond)->UseRealTime();

}  // namespace

// Large image buffers pooled as in the program (firmware_app/main.cpp): without the pool every SIFT call faults in
// and zeroes its scale space afresh, on 4 KiB pages, which the flight does not.
int main(int argc, char** argv) {
  uavm::InstallMatPool();
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  return 0;
}
