#include "core/mosaic/compositor.h"

#include <gdal_priv.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <atomic>
#include <filesystem>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <set>

#include "core/mosaic/gdal_writer.h"
#include "core/mosaic/selection.h"
#include "tests/test_env.h"

namespace uavm {
namespace {

struct Scene {
  cv::Mat ground;  // the "true" map
  std::vector<CompositeInput> inputs;
  std::vector<cv::Mat> images;
};

// Three overlapping crops of a real aerial frame, one rotated, placed back with their exact transforms.
Scene MakeScene() {
  Scene s;
  s.ground = cv::imread(std::string(UAVM_TEST_DATA) + "/caliterra_small/images/IMG_9360.jpg");
  const cv::Rect crops[] = {{0, 0, 520, 420}, {380, 100, 520, 420}, {150, 300, 520, 420}};
  for (int i = 0; i < 3; ++i) {
    CompositeInput in;
    in.id = i;
    in.image_size = crops[i].size();
    in.canvas_from_image = Translation(crops[i].x, crops[i].y);
    s.images.push_back(s.ground(crops[i]).clone());
    s.inputs.push_back(in);
  }
  return s;
}

// Small tiles and blocks over the scene, every frame kept, the quick-look at full size (compared pixel for pixel).
CompositorOptions SceneOptions() {
  CompositorOptions o;
  o.tiff_block = 128;
  o.tile_size = 256;
  o.num_bands = 4;
  o.max_covered_fraction = 1.0;
  o.quicklook_long_side = 4096;
  return o;
}

// Composite() with the quick-look written to a PNG in the temporary directory, read back (BGRA) by OpenCV's decoder
// into `quicklook` and the file removed.
template <typename Load>
CompositeResult ComposeWithQuicklook(const std::vector<CompositeInput>& inputs, cv::Size canvas, Load&& load,
                                     CompositorOptions o, cv::Mat* quicklook) {
  static std::atomic<int> serial{0};
  const auto path = std::filesystem::temp_directory_path() /
                    ("uavm_quicklook_" + std::to_string(::getpid()) + "_" + std::to_string(serial++) + ".png");
  o.quicklook_path = path.string();
  CompositeResult r = Composite(inputs, canvas, std::forward<Load>(load), o, nullptr);
  *quicklook = cv::imread(path.string(), cv::IMREAD_UNCHANGED);
  std::filesystem::remove(path);
  EXPECT_FALSE(std::filesystem::exists(path.string() + ".raw.tmp")) << "the raw quick-look is removed";
  EXPECT_FALSE(std::filesystem::exists(path.string() + ".tmp"));
  if (r.ok) {
    EXPECT_EQ(quicklook->size(), r.quicklook_size);
  }
  return r;
}

TEST(CompositorTest, RebuildsTheGroundFromCrops) {
  Scene s = MakeScene();
  ASSERT_FALSE(s.ground.empty());
  CompositorOptions o = SceneOptions();
  const cv::Size canvas(s.ground.cols, s.ground.rows);
  cv::Mat quicklook;
  const auto r = ComposeWithQuicklook(
      s.inputs, canvas, [&](int id) { return s.images[static_cast<size_t>(id)]; }, o, &quicklook);
  ASSERT_TRUE(r.ok) << r.error;
  ASSERT_EQ(quicklook.type(), CV_8UC4);
  ASSERT_EQ(quicklook.size(), canvas);
  cv::Mat bgr;
  cv::Mat alpha;
  cv::cvtColor(quicklook, bgr, cv::COLOR_BGRA2BGR);
  cv::extractChannel(quicklook, alpha, 3);
  // Covered area = union of the crops; outside it stays transparent.
  EXPECT_EQ(alpha.at<uchar>(10, 10), 255);
  EXPECT_EQ(alpha.at<uchar>(740, 990), 0);
  cv::Mat diff;
  cv::absdiff(bgr, s.ground, diff);
  const cv::Scalar mean_err = cv::mean(diff, alpha);
  // Exact crops: OpenCV's 16-bit Laplacian pyramid rounds a little at every level (~2 grey levels on texture).
  EXPECT_LT((mean_err[0] + mean_err[1] + mean_err[2]) / 3, 2.5);
  // With hard seams the crops must come back bit for bit: the geometry and the seams are exact.
  o.num_bands = 0;
  cv::Mat hard_quicklook;
  const auto hard = ComposeWithQuicklook(
      s.inputs, canvas, [&](int id) { return s.images[static_cast<size_t>(id)]; }, o, &hard_quicklook);
  ASSERT_TRUE(hard.ok);
  cv::cvtColor(hard_quicklook, bgr, cv::COLOR_BGRA2BGR);
  cv::absdiff(bgr, s.ground, diff);
  const cv::Scalar hard_err = cv::mean(diff, alpha);
  EXPECT_LT(hard_err[0] + hard_err[1] + hard_err[2], 0.01);
}

// A quick-look that cannot be written stops the composite with the reason and the path, and leaves no file behind.
TEST(CompositorTest, AnUnwritableQuicklookIsAnErrorNamingIt) {
  Scene s = MakeScene();
  CompositorOptions o = SceneOptions();
  const auto dir = std::filesystem::temp_directory_path() / ("uavm_quicklook_gone_" + std::to_string(::getpid()));
  o.quicklook_path = (dir / "mosaic.png").string();  // a directory that does not exist
  const auto r = Composite(
      s.inputs, cv::Size(s.ground.cols, s.ground.rows), [&](int id) { return s.images[static_cast<size_t>(id)]; }, o,
      nullptr);
  EXPECT_FALSE(r.ok);
  EXPECT_NE(r.error.find(o.quicklook_path), std::string::npos) << r.error;
  EXPECT_FALSE(std::filesystem::exists(dir));
}

// A frame's avoid disc (the sun's hotspot and the drone's shadow): the ground under it is taken from another frame
// that sees it, although distance-to-border alone would give it to the disc's frame.
TEST(CompositorTest, SeamsKeepOutOfAnAvoidDisc) {
  Scene s = MakeScene();
  ASSERT_FALSE(s.ground.empty());
  // A dark shadow in frame 1 at (100, 200), canvas (480, 300): 100 px from frame 1's border, 40 px from frame 0's.
  cv::circle(s.images[1], cv::Point(100, 200), 8, cv::Scalar::all(0), cv::FILLED);
  CompositorOptions o = SceneOptions();
  o.num_bands = 0;
  const cv::Size canvas(s.ground.cols, s.ground.rows);
  auto error_at_shadow = [&](const std::vector<CompositeInput>& inputs) {
    cv::Mat quicklook;
    const auto r = ComposeWithQuicklook(
        inputs, canvas, [&](int id) { return s.images[static_cast<size_t>(id)]; }, o, &quicklook);
    EXPECT_TRUE(r.ok) << r.error;
    cv::Mat bgr;
    cv::cvtColor(quicklook, bgr, cv::COLOR_BGRA2BGR);
    const cv::Rect window(470, 290, 21, 21);
    cv::Mat diff;
    cv::absdiff(bgr(window), s.ground(window), diff);
    const cv::Scalar e = cv::mean(diff);
    return (e[0] + e[1] + e[2]) / 3;
  };
  EXPECT_GT(error_at_shadow(s.inputs), 20.0);  // the shadow is in the mosaic
  std::vector<CompositeInput> avoiding = s.inputs;
  avoiding[1].avoid_centre = cv::Point2d(100, 200);
  avoiding[1].avoid_radius = 60;
  EXPECT_LT(error_at_shadow(avoiding), 0.01);  // frame 0's pixels, exactly
  // Ground only the disc's frame sees stays its own: a disc at frame 1's far corner changes nothing there.
  avoiding[1].avoid_centre = cv::Point2d(480, 380);
  cv::Mat quicklook;
  const auto r = ComposeWithQuicklook(
      avoiding, canvas, [&](int id) { return s.images[static_cast<size_t>(id)]; }, o, &quicklook);
  ASSERT_TRUE(r.ok);
  EXPECT_EQ(quicklook.at<cv::Vec4b>(480, 860)[3], 255);
}

TEST(CompositorTest, TilesMatchAWholeCanvasBlend) {
  Scene s = MakeScene();
  // Perturb the exposure of one crop so that the blend has work to do across seams.
  s.images[1].convertTo(s.images[1], -1, 1.15, 12);
  CompositorOptions o = SceneOptions();
  const cv::Size canvas(s.ground.cols, s.ground.rows);
  cv::Mat tiled_quicklook;
  const auto tiled = ComposeWithQuicklook(
      s.inputs, canvas, [&](int id) { return s.images[static_cast<size_t>(id)]; }, o, &tiled_quicklook);
  ASSERT_TRUE(tiled.ok);
  cv::Mat whole;
  cv::Mat whole_mask;
  ASSERT_TRUE(
      RenderRoi(s.inputs, s.images, cv::Rect(0, 0, canvas.width, canvas.height), o.num_bands, &whole, &whole_mask));
  cv::Mat tiled_bgr;
  cv::cvtColor(tiled_quicklook, tiled_bgr, cv::COLOR_BGRA2BGR);
  cv::Mat diff;
  cv::absdiff(tiled_bgr, whole, diff);
  diff = diff.reshape(1);
  std::vector<uchar> v(diff.begin<uchar>(), diff.end<uchar>());
  std::sort(v.begin(), v.end());
  EXPECT_LE(v[static_cast<size_t>(0.999 * static_cast<double>(v.size()))], 2) << "tile borders must be invisible";
}

// A loader of parts (what JPEG region decoding gives: a little more than asked for, at an offset) composes the same
// mosaic as whole frames, and is asked for less than whole frames where frames overlap.
TEST(CompositorTest, PartLoadsComposeLikeWholeFrames) {
  Scene s = MakeScene();
  s.images[1].convertTo(s.images[1], -1, 1.15, 12);
  CompositorOptions o = SceneOptions();
  const cv::Size canvas(s.ground.cols, s.ground.rows);
  cv::Mat whole_quicklook;
  const auto whole = ComposeWithQuicklook(
      s.inputs, canvas, [&](int id) { return s.images[static_cast<size_t>(id)]; }, o, &whole_quicklook);
  ASSERT_TRUE(whole.ok);
  for (auto& in : s.inputs) in.region_loads = true;
  int smaller = 0;
  cv::Mat parts_quicklook;
  const auto parts = ComposeWithQuicklook(
      s.inputs, canvas,
      [&](int id, const cv::Rect& need) {
        const cv::Mat& img = s.images[static_cast<size_t>(id)];
        smaller += need.size() != img.size() ? 1 : 0;
        // Widened to the left by up to 8 px, as libjpeg widens to its MCU columns.
        const cv::Rect part =
            cv::Rect(need.x - 8, need.y, need.width + 8, need.height) & cv::Rect(cv::Point(), img.size());
        return FramePart{img(part).clone(), cv::Point2d(part.tl())};
      },
      o, &parts_quicklook);
  ASSERT_TRUE(parts.ok);
  EXPECT_GT(smaller, 0) << "a frame partly covered by others is needed only in part";
  cv::Mat diff;
  cv::absdiff(whole_quicklook, parts_quicklook, diff);
  EXPECT_EQ(cv::countNonZero(diff.reshape(1)), 0);
}

// The frame cache's tests: small tiles over the scene, so that each frame's part serves several of them, one worker,
// every frame kept; each load reported as `kPart` bytes.
constexpr size_t kPart = 520 * 420 * 3;
CompositorOptions CacheTestOptions(Scene* s) {
  CompositorOptions o;
  o.tiff_block = 128;
  o.tile_size = 128;
  o.num_bands = 3;
  o.threads = 1;
  o.max_covered_fraction = 1.0;
  o.quicklook_long_side = 4096;
  for (auto& in : s->inputs) in.load_bytes = kPart;
  return o;
}

// With room for one decoded part only, parts evicted between tiles come back from the cache's in-memory JPEG: each
// frame is loaded once, and the mosaic differs from the all-decoded one by about a grey level at most on average.
TEST(CompositorTest, EvictedPartsComeBackFromMemory) {
  Scene s = MakeScene();
  CompositorOptions o = CacheTestOptions(&s);
  const cv::Size canvas(s.ground.cols, s.ground.rows);
  const size_t part = kPart;
  o.image_cache_bytes = part + part + part / 2;  // one load in flight, one decoded part and a half
  int loads_decoded_only = 0;
  o.compressed_share = 0.0;
  cv::Mat decoded_only_quicklook;
  const auto decoded_only = ComposeWithQuicklook(
      s.inputs, canvas,
      [&](int id) {
        ++loads_decoded_only;
        return s.images[static_cast<size_t>(id)];
      },
      o, &decoded_only_quicklook);
  ASSERT_TRUE(decoded_only.ok);
  ASSERT_GT(loads_decoded_only, 3) << "the test needs a cache too small for every frame";
  int loads = 0;
  o.compressed_share = 1.0;
  cv::Mat two_tiers_quicklook;
  const auto two_tiers = ComposeWithQuicklook(
      s.inputs, canvas,
      [&](int id) {
        ++loads;
        return s.images[static_cast<size_t>(id)];
      },
      o, &two_tiers_quicklook);
  ASSERT_TRUE(two_tiers.ok);
  EXPECT_EQ(loads, 3);
  EXPECT_EQ(two_tiers.image_loads, 3);
  EXPECT_EQ(two_tiers.reloads_from_memory, loads_decoded_only - 3);
  cv::Mat diff;
  cv::absdiff(decoded_only_quicklook, two_tiers_quicklook, diff);
  const cv::Scalar mean = cv::mean(diff);
  EXPECT_LT((mean[0] + mean[1] + mean[2]) / 3, 1.0);
}

// The decoded tier is a fixed line, not a share of what the budget leaves: with a large cache but no decoded bytes
// beyond one part per worker, parts needed again come back from the in-memory JPEG (each frame still loaded once), and
// the decoded tier never holds more than that one part.
TEST(CompositorTest, TheDecodedTierStaysWithinItsOwnCap) {
  Scene s = MakeScene();
  CompositorOptions o = CacheTestOptions(&s);
  const cv::Size canvas(s.ground.cols, s.ground.rows);
  o.image_cache_bytes = 40 * kPart;  // room for every part, decoded or not
  const auto compose = [&](double decoded_cache_mib, int* loads) {
    o.decoded_cache_mib = decoded_cache_mib;
    return Composite(
        s.inputs, canvas,
        [&](int id) {
          ++*loads;
          return s.images[static_cast<size_t>(id)];
        },
        o, nullptr);
  };
  int loads_roomy = 0;
  const CompositeResult roomy = compose(64, &loads_roomy);
  ASSERT_TRUE(roomy.ok);
  EXPECT_EQ(loads_roomy, 3);
  EXPECT_EQ(roomy.reloads_from_memory, 0);
  int loads_capped = 0;
  const CompositeResult capped = compose(0, &loads_capped);
  ASSERT_TRUE(capped.ok);
  EXPECT_EQ(loads_capped, 3);
  EXPECT_GT(capped.reloads_from_memory, 0);
  // One decoded part and the JPEG copies, against every part decoded (measured 1.44 against 2.06 MB).
  EXPECT_LT(static_cast<double>(capped.cache_peak_bytes), 0.8 * static_cast<double>(roomy.cache_peak_bytes));
}

// A strip longer than 32767 px (where OpenCV's warps and its stitcher stop): 40 overlapping frames along a synthetic
// 34000 px ground, composited tile by tile into a BigTIFF with overviews; the far end reads back like the ground.
TEST(CompositorTest, CanvasWiderThan32767PxComposesCorrectly) {
  cv::Mat base = cv::imread(std::string(UAVM_TEST_DATA) + "/caliterra_small/images/IMG_9360.jpg");
  ASSERT_FALSE(base.empty());
  // The width is the point of the test; under emulation a strip of 320 rows is enough and blends in a third the time.
  if (test::Emulated()) base = base.rowRange(0, 320).clone();
  constexpr int kWidth = 34000;
  cv::Mat ground(base.rows, kWidth, CV_8UC3);
  for (int x = 0, k = 0; x < kWidth; x += base.cols, ++k) {
    cv::Mat piece;
    cv::flip(base, piece, 1);  // mirrored copies: no seam in the texture itself
    const cv::Mat& src = k % 2 == 0 ? base : piece;
    const int w = std::min(base.cols, kWidth - x);
    src(cv::Rect(0, 0, w, base.rows)).copyTo(ground(cv::Rect(x, 0, w, base.rows)));
  }
  constexpr int kFrames = 40;
  const cv::Size frame(1000, base.rows);
  std::vector<CompositeInput> inputs;
  std::vector<cv::Rect> crops;
  for (int i = 0; i < kFrames; ++i) {
    const int x = (kWidth - frame.width) * i / (kFrames - 1);
    crops.emplace_back(x, 0, frame.width, frame.height);
    CompositeInput in;
    in.id = i;
    in.image_size = frame;
    in.canvas_from_image = Translation(x, 0);
    inputs.push_back(in);
  }
  CompositorOptions o;
  o.max_covered_fraction = 1.0;
  const auto path = std::filesystem::temp_directory_path() / ("uavm_wide_" + std::to_string(::getpid()) + ".tif");
  GdalTiffWriter tiff;
  std::string err;
  const cv::Size canvas(kWidth, frame.height);
  ASSERT_TRUE(tiff.Open(path.string(), canvas, o.tiff_block, o.tile_size, true, 16, &err)) << err;
  std::atomic<int> loads = 0;
  const auto r = Composite(
      inputs, canvas,
      [&](int id) {
        ++loads;
        return ground(crops[static_cast<size_t>(id)]).clone();
      },
      o, &tiff);
  ASSERT_TRUE(r.ok) << r.error;
  ASSERT_TRUE(tiff.Close(&err)) << err;
  EXPECT_EQ(r.canvas.width, kWidth);
  EXPECT_EQ(r.frames_used, kFrames);
  // Each frame decoded at least once. A worker that waited for the other's serial load of the same frame decodes it
  // again (the cache is not checked twice): 40-41 natively, 49 under qemu-aarch64, hence the loose bound.
  EXPECT_GE(loads.load(), kFrames);
  EXPECT_LE(loads.load(), 2 * kFrames);
  // The cache (256 MiB, room for every frame) held only the frames about the tiles in progress: each frame left it
  // when its last tile was made.
  EXPECT_EQ(r.parts_released, kFrames);
  const size_t every_frame = static_cast<size_t>(kFrames) * frame.area() * 3;
  EXPECT_GT(r.cache_peak_bytes, 0u);
  EXPECT_LT(r.cache_peak_bytes, every_frame / 4) << "peak " << r.cache_peak_bytes << " of " << every_frame;

  GDALAllRegister();
  GDALDataset* ds = static_cast<GDALDataset*>(GDALOpen(path.c_str(), GA_ReadOnly));
  ASSERT_NE(ds, nullptr);
  EXPECT_EQ(ds->GetRasterXSize(), kWidth);
  EXPECT_EQ(ds->GetRasterCount(), 4);
  EXPECT_GT(ds->GetRasterBand(1)->GetOverviewCount(), 3);
  // Windows near the start, in the middle and beyond 32767 px.
  for (const int x0 : {100, 17000, 33200}) {
    const cv::Rect win(x0, 100, 600, std::min(500, base.rows - 120));
    cv::Mat got(win.size(), CV_8UC3);
    for (int b = 0; b < 3; ++b) {
      cv::Mat plane(win.size(), CV_8UC1);
      ASSERT_EQ(ds->GetRasterBand(b + 1)->RasterIO(GF_Read, win.x, win.y, win.width, win.height, plane.data, win.width,
                                                   win.height, GDT_Byte, 0, 0),
                CE_None);
      // The TIFF is RGB(A); the ground is BGR.
      cv::insertChannel(plane, got, 2 - b);
    }
    cv::Mat diff;
    cv::absdiff(got, ground(win), diff);
    const cv::Scalar e = cv::mean(diff);
    EXPECT_LT((e[0] + e[1] + e[2]) / 3, 2.5) << "window at x=" << x0;
  }
  GDALClose(ds);
  std::filesystem::remove(path);
}

// The TIFF writer gives each block to the file once all of its pixels are written: GDAL's cache holds the blocks in
// progress, not the mosaic (before, every block stayed until Close). The file still holds every pixel as written, its
// overviews each tile's reduction, and no block written twice (its size is that of a copy GDAL writes block by block).
TEST(GdalTiffWriterTest, ReleasesEachBlockOnceWrittenWhole) {
  const cv::Size canvas(1536 + 100, 1280 + 60);  // clipped tiles and blocks at the right and bottom
  const int tile = 512;
  cv::Mat image(canvas, CV_8UC3);
  cv::randu(image, 0, 255);
  cv::GaussianBlur(image, image, cv::Size(5, 5), 0);  // compressible, like a photograph
  cv::Mat mask(canvas, CV_8U, cv::Scalar(255));
  const auto dir = std::filesystem::temp_directory_path() / ("uavm_blocks_" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  const std::string path = (dir / "m.tif").string();
  GdalTiffWriter tiff;
  std::string err;
  ASSERT_TRUE(tiff.Open(path, canvas, 256, tile, true, 64, &err)) << err;
  const size_t canvas_bytes = static_cast<size_t>(canvas.area()) * 4;
  GIntBig most_cached = 0;
  for (const cv::Rect& t : TilesAlongHilbertCurve(canvas, tile)) {
    ASSERT_TRUE(tiff.Write(image(t), mask(t), t.tl(), &err)) << err;
    most_cached = std::max(most_cached, GDALGetCacheUsed64());
  }
  // At most about a tile and the overview blocks it has begun: a fraction of the canvas.
  EXPECT_LT(static_cast<size_t>(most_cached), canvas_bytes / 3) << most_cached << " of " << canvas_bytes;
  EXPECT_LT(static_cast<size_t>(GDALGetCacheUsed64()), canvas_bytes / 10);
  ASSERT_TRUE(tiff.Close(&err)) << err;

  GDALAllRegister();
  auto* ds = static_cast<GDALDataset*>(GDALOpen(path.c_str(), GA_ReadOnly));
  ASSERT_NE(ds, nullptr);
  cv::Mat rgba(canvas, CV_8UC4);
  ASSERT_EQ(ds->RasterIO(GF_Read, 0, 0, canvas.width, canvas.height, rgba.data, canvas.width, canvas.height, GDT_Byte,
                         4, nullptr, 4, static_cast<GSpacing>(rgba.step[0]), 1, nullptr),
            CE_None);
  cv::Mat bgr;
  cv::cvtColor(rgba, bgr, cv::COLOR_RGBA2BGR);
  EXPECT_EQ(cv::norm(bgr, image, cv::NORM_INF), 0.0);
  // The first overview: each tile reduced on its own, as written.
  GDALRasterBand* ov = ds->GetRasterBand(2)->GetOverview(0);
  ASSERT_NE(ov, nullptr);
  const cv::Size half(ov->GetXSize(), ov->GetYSize());
  cv::Mat green(half, CV_8U);
  ASSERT_EQ(ov->RasterIO(GF_Read, 0, 0, half.width, half.height, green.data, half.width, half.height, GDT_Byte, 0, 0),
            CE_None);
  cv::Mat expected(half, CV_8U);
  for (const cv::Rect& t : TilesAlongHilbertCurve(canvas, tile)) {
    const cv::Rect o(t.x / 2, t.y / 2, std::min((t.width + 1) / 2, half.width - t.x / 2),
                     std::min((t.height + 1) / 2, half.height - t.y / 2));
    cv::Mat small;
    cv::resize(image(t), small, o.size(), 0, 0, cv::INTER_AREA);
    cv::extractChannel(small, expected(o), 1);
  }
  EXPECT_EQ(cv::norm(green, expected, cv::NORM_INF), 0.0);
  // Every block compressed once: the file is no larger than GDAL's own block-by-block copy of it.
  const std::string copy_path = (dir / "copy.tif").string();
  char** opts = nullptr;
  for (const char* kv : {"TILED=YES", "BLOCKXSIZE=256", "BLOCKYSIZE=256", "COMPRESS=ZSTD", "ZSTD_LEVEL=1",
                         "PREDICTOR=2", "PHOTOMETRIC=RGB", "ALPHA=YES", "SPARSE_OK=TRUE", "COPY_SRC_OVERVIEWS=YES"})
    opts = CSLAddString(opts, kv);
  GDALDataset* copy = GetGDALDriverManager()->GetDriverByName("GTiff")->CreateCopy(copy_path.c_str(), ds, FALSE, opts,
                                                                                   nullptr, nullptr);
  CSLDestroy(opts);
  ASSERT_NE(copy, nullptr);
  GDALClose(copy);
  GDALClose(ds);
  const auto ours = std::filesystem::file_size(path);
  const auto gdal = std::filesystem::file_size(copy_path);
  EXPECT_LT(static_cast<double>(ours), 1.02 * static_cast<double>(gdal)) << ours << " against " << gdal;
  std::filesystem::remove_all(dir);
}

// The tile order: every tile once, clipped at the canvas; consecutive tiles share an edge on a power-of-two grid; and
// each aligned 2x2 block of tiles comes in one run (what keeps a TIFF overview block open only briefly).
TEST(CompositorTest, TilesFollowAHilbertCurve) {
  const std::vector<cv::Rect> square = TilesAlongHilbertCurve(cv::Size(4096, 4096), 512);
  ASSERT_EQ(square.size(), 64u);
  for (size_t k = 1; k < square.size(); ++k)
    EXPECT_EQ(std::abs(square[k].x - square[k - 1].x) + std::abs(square[k].y - square[k - 1].y), 512) << k;
  for (size_t k = 0; k < square.size(); k += 4) {
    std::set<std::pair<int, int>> block;
    for (size_t j = k; j < k + 4; ++j) block.insert({square[j].x / 1024, square[j].y / 1024});
    EXPECT_EQ(block.size(), 1u) << "tiles " << k << ".." << k + 3 << " span several 2x2 blocks";
  }
  const cv::Size odd(2600, 1100);  // 6 x 3 tiles, the last column and row clipped
  const std::vector<cv::Rect> tiles = TilesAlongHilbertCurve(odd, 512);
  ASSERT_EQ(tiles.size(), 18u);
  std::set<std::pair<int, int>> seen;
  long area = 0;
  for (const cv::Rect& t : tiles) {
    EXPECT_TRUE(seen.insert({t.x, t.y}).second) << "tile at " << t.x << "," << t.y << " twice";
    EXPECT_EQ(t, t & cv::Rect(0, 0, odd.width, odd.height));
    area += t.area();
  }
  EXPECT_EQ(area, static_cast<long>(odd.area()));
}

TEST(SelectionTest, DropsAFrameCoveredByOthers) {
  const auto square = [](float x, float y, float w) {
    return std::vector<cv::Point2f>{{x, y}, {x + w, y}, {x + w, y + w}, {x, y + w}};
  };
  const std::vector<std::vector<cv::Point2f>> fps{square(0, 0, 100), square(80, 0, 100), square(5, 5, 90),
                                                  square(200, 0, 100)};
  const auto keep = SelectByOverlap(fps, cv::Rect2d(0, 0, 300, 100), 0.9, 300);
  EXPECT_EQ(keep, (std::vector<bool>{true, true, false, true}));
}

}  // namespace
}  // namespace uavm
