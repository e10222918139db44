// The live tile pyramid against a known ground: frames cut from a synthetic picture are drawn at known places, and the
// tiles on disk must show that picture there (max_zoom and coarser), move with a frame that a solve moved, vanish on
// a new grid, and stay bounded and valid when the disk fails. Web-mercator arithmetic against PROJ (GDAL's OGR).
#include "core/tiles/live_tile_pyramid.h"

#include <gtest/gtest.h>
#include <ogr_spatialref.h>
#include <unistd.h>

#include <filesystem>
#include <memory>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <random>

#include "core/tiles/tile_render.h"
#include "core/tiles/web_mercator.h"
#include "core/util/clock.h"

namespace uavm {
namespace {

namespace fs = std::filesystem;

fs::path TempDir(const std::string& name) {
  const fs::path d = fs::temp_directory_path() / ("uavm_tiles_" + name + "_" + std::to_string(::getpid()));
  fs::remove_all(d);
  fs::create_directories(d);
  return d;
}

// A smooth, textured ground: blurred noise (bilinear resampling of it stays close to the truth).
cv::Mat Ground(cv::Size size, int seed) {
  cv::Mat noise(size / 8, CV_8UC3);
  cv::RNG rng(static_cast<uint64_t>(seed));
  rng.fill(noise, cv::RNG::UNIFORM, 0, 255);
  cv::Mat g;
  cv::resize(noise, g, size, 0, 0, cv::INTER_CUBIC);
  cv::GaussianBlur(g, g, cv::Size(0, 0), 2.0);
  return g;
}

struct Flight {
  cv::Mat ground;
  cv::Point origin;  // ground pixel (0, 0) at this max_zoom global pixel
  fs::path frames;   // stored frames, read back by the pyramid
};

TileFrame FrameAt(const Flight& f, int id, cv::Rect crop, bool with_pixels) {
  const cv::Mat pixels = f.ground(crop).clone();
  const std::string path = (f.frames / (std::to_string(id) + ".png")).string();
  cv::imwrite(path, pixels);
  TileFrame t;
  t.id = id;
  t.path = path;
  t.work_size = crop.size();
  // Work pixel centre (u, v) is ground pixel centre (crop.x + u, crop.y + v): global corner coordinates + 0.5.
  t.grid_from_work = Translation(f.origin.x + crop.x + 0.5, f.origin.y + crop.y + 0.5);
  if (with_pixels) t.image = std::make_shared<const cv::Mat>(pixels);
  t.registered_ns = with_pixels ? MonotonicNs() : 0;  // a new frame (its latency is measured), not a redraw
  return t;
}

cv::Mat ReadPng(const fs::path& p) {
  return cv::imread(p.string(), cv::IMREAD_UNCHANGED);
}

// Mean absolute colour difference between a max_zoom tile and the ground under it, over the tile's opaque pixels.
double TileError(const Flight& f, const fs::path& dir, int z, int x, int y, int* opaque) {
  const cv::Mat tile = ReadPng(dir / std::to_string(z) / std::to_string(x) / (std::to_string(y) + ".png"));
  *opaque = 0;
  if (tile.empty()) return -1;
  double sum = 0;
  for (int r = 0; r < tile.rows; ++r)
    for (int c = 0; c < tile.cols; ++c) {
      const cv::Vec4b t = tile.at<cv::Vec4b>(r, c);
      const int gx = x * kTileSize + c - f.origin.x, gy = y * kTileSize + r - f.origin.y;
      if (t[3] == 0 || gx < 0 || gy < 0 || gx >= f.ground.cols || gy >= f.ground.rows) continue;
      const cv::Vec3b g = f.ground.at<cv::Vec3b>(gy, gx);
      sum += (std::abs(t[0] - g[0]) + std::abs(t[1] - g[1]) + std::abs(t[2] - g[2])) / 3.0;
      ++*opaque;
    }
  return *opaque > 0 ? sum / *opaque : -1;
}

LiveTilePyramid::FrameReader PngReader() {
  return [](int, const std::string& path, cv::Size, int, double) { return cv::imread(path, cv::IMREAD_COLOR); };
}

TEST(LiveTilePyramidTest, TilesShowTheGroundWhereTheFramesAre) {
  const fs::path dir = TempDir("ground");
  Flight f{Ground({1200, 700}, 1), {10 * kTileSize + 37, 20 * kTileSize + 101}, dir / "frames"};
  fs::create_directories(f.frames);
  LiveTileOptions o;
  o.queue_images = 2;  // the rest are read back from frames/
  std::vector<std::shared_ptr<const TileSetInfo>> published;
  std::mutex m;
  // The reader is told which frame it reads and its heading (the live radiometry's hotspot turns with it).
  std::vector<std::pair<int, double>> read_back;
  auto reader = [&](int id, const std::string& path, cv::Size, int, double heading) {
    std::lock_guard lock(m);
    read_back.emplace_back(id, heading);
    return cv::imread(path, cv::IMREAD_COLOR);
  };
  LiveTilePyramid pyramid((dir / "tiles").string(), o, reader, [&](std::shared_ptr<const TileSetInfo> i) {
    std::lock_guard lock(m);
    published.push_back(std::move(i));
  });
  pyramid.Reset({true, 12, 9});
  // A strip of 400x300 frames overlapping by half.
  int id = 0;
  for (int y = 0; y + 300 <= 700; y += 200)
    for (int x = 0; x + 400 <= 1200; x += 200) {
      TileFrame frame = FrameAt(f, id, {x, y, 400, 300}, true);
      frame.heading = 0.1 * id++;
      ASSERT_TRUE(pyramid.Draw(std::move(frame)));
    }
  pyramid.Drain();
  {
    std::lock_guard lock(m);
    EXPECT_FALSE(read_back.empty());
    for (const auto& [read_id, heading] : read_back) EXPECT_DOUBLE_EQ(heading, 0.1 * read_id) << read_id;
  }
  const LiveTileStats s = pyramid.Stats();
  EXPECT_EQ(s.frames_drawn, id);
  EXPECT_GT(s.frames_reread, 0);  // past queue_images the pixels came from frames/
  EXPECT_EQ(s.jobs_dropped, 0);
  EXPECT_EQ(static_cast<int>(s.latency_ms.size()), id);
  // Every max_zoom tile over the flown ground shows it (the seams blend neighbouring crops of the same picture).
  int tiles = 0, opaque_total = 0;
  for (int y = 20; y <= 23; ++y)
    for (int x = 10; x <= 15; ++x) {
      int opaque = 0;
      const double err = TileError(f, dir / "tiles/1", 12, x, y, &opaque);
      if (opaque == 0) continue;
      ++tiles;
      opaque_total += opaque;
      EXPECT_LT(err, 2.0) << "tile 12/" << x << "/" << y;
    }
  EXPECT_GE(tiles, 12);
  EXPECT_NEAR(opaque_total, 1200 * 700, 1200 * 700 * 0.01);  // covered: the ground, nothing more
  // Coarser zooms down to min_zoom exist and are the ground halved.
  for (int z = 11; z >= 9; --z) EXPECT_TRUE(fs::exists(dir / "tiles/1" / std::to_string(z)));
  const cv::Mat t11 = ReadPng(dir / "tiles/1/11/5/10.png");  // grid generation 1
  ASSERT_FALSE(t11.empty());
  // Tile 11/5/10's pixel (c, r) is zoom-12 global pixels (2560 + 2c, 5120 + 2r) and the next ones: the mean of
  // those 2x2 ground pixels.
  double diff = 0;
  int n = 0;
  for (int r = 100; r < 250; ++r)
    for (int c = 100; c < 250; ++c) {
      const int gx = 5 * 2 * kTileSize + 2 * c - f.origin.x, gy = 10 * 2 * kTileSize + 2 * r - f.origin.y;
      const cv::Vec4b t = t11.at<cv::Vec4b>(r, c);
      if (gx < 0 || gy < 0 || gx + 1 >= f.ground.cols || gy + 1 >= f.ground.rows || t[3] < 255) continue;
      cv::Vec3d mean(0, 0, 0);
      for (int k = 0; k < 4; ++k) mean += cv::Vec3d(f.ground.at<cv::Vec3b>(gy + k / 2, gx + k % 2)) / 4.0;
      diff += (std::abs(t[0] - mean[0]) + std::abs(t[1] - mean[1]) + std::abs(t[2] - mean[2])) / 3.0;
      ++n;
    }
  ASSERT_GT(n, 1000);
  EXPECT_LT(diff / n, 3.0);
  const auto info = pyramid.Info();
  ASSERT_TRUE(info);
  EXPECT_EQ(info->frames, id);
  EXPECT_EQ(info->max_zoom, 12);
  EXPECT_EQ(info->min_zoom, 9);
  EXPECT_EQ(info->generation, 1);
  EXPECT_EQ(fs::path(info->dir), dir / "tiles/1");
  EXPECT_LT(info->west, info->east);
  EXPECT_LT(info->south, info->north);
  EXPECT_FALSE(published.empty());
  fs::remove_all(dir);
}

TEST(LiveTilePyramidTest, AMovedFrameLeavesItsOldPlaceAndAResetClearsAll) {
  const fs::path dir = TempDir("moved");
  Flight f{Ground({800, 600}, 2), {4 * kTileSize, 4 * kTileSize}, dir / "frames"};
  fs::create_directories(f.frames);
  LiveTilePyramid pyramid((dir / "tiles").string(), LiveTileOptions{}, PngReader(), nullptr);
  pyramid.Reset({false, 10, 8});
  ASSERT_TRUE(pyramid.Draw(FrameAt(f, 0, {0, 0, 400, 300}, true)));
  // Frame 1 first drawn 600 px east of where it belongs (a bad early placement), then moved by a solve.
  TileFrame wrong = FrameAt(f, 1, {300, 200, 400, 300}, true);
  wrong.grid_from_work = Translation(600, 0) * wrong.grid_from_work;
  ASSERT_TRUE(pyramid.Draw(wrong));
  pyramid.Drain();
  const fs::path far_tile = dir / "tiles/1/10/7/5.png";  // only the wrong place reaches x >= 7*256
  EXPECT_TRUE(fs::exists(far_tile));
  ASSERT_TRUE(pyramid.Draw(FrameAt(f, 1, {300, 200, 400, 300}, false)));
  pyramid.Drain();
  EXPECT_FALSE(fs::exists(far_tile));
  EXPECT_EQ(pyramid.Stats().frames_redrawn, 1);
  int opaque = 0;
  for (int y = 4; y <= 5; ++y)
    for (int x = 4; x <= 6; ++x) {
      const double err = TileError(f, dir / "tiles/1", 10, x, y, &opaque);
      if (opaque > 0) {
        EXPECT_LT(err, 2.0) << x << "," << y;
      }
    }
  // A move below redraw_shift_px costs nothing.
  TileFrame nudged = FrameAt(f, 1, {300, 200, 400, 300}, false);
  nudged.grid_from_work = Translation(0.5, 0) * nudged.grid_from_work;
  ASSERT_TRUE(pyramid.Draw(nudged));
  pyramid.Drain();
  EXPECT_EQ(pyramid.Stats().frames_redrawn, 1);  // only the real move was drawn again
  // A new grid is drawn beside the old one, which goes once the new one is published (nothing left to draw).
  pyramid.Reset({true, 11, 9});
  ASSERT_TRUE(pyramid.Draw(FrameAt(f, 0, {0, 0, 400, 300}, true)));
  pyramid.Drain();
  EXPECT_FALSE(fs::exists(dir / "tiles/1"));
  EXPECT_TRUE(fs::exists(dir / "tiles/2/11"));
  EXPECT_EQ(pyramid.Info()->generation, 2);
  EXPECT_EQ(pyramid.Info()->frames, 1);
  fs::remove_all(dir);
}

TEST(LiveTilePyramidTest, AWriteFailureStopsDrawingAndIsCounted) {
  const fs::path dir = TempDir("full");
  Flight f{Ground({400, 300}, 3), {0, 0}, dir / "frames"};
  fs::create_directories(f.frames);
  // A file where the tile directory should be: nothing can be written under it.
  { std::ofstream(dir / "blocked") << "x"; }
  LiveTilePyramid pyramid((dir / "blocked" / "tiles").string(), LiveTileOptions{}, PngReader(), nullptr);
  pyramid.Reset({false, 4, 2});
  ASSERT_TRUE(pyramid.Draw(FrameAt(f, 0, {0, 0, 400, 300}, true)));
  pyramid.Drain();
  EXPECT_GE(pyramid.Stats().write_errors, 1);
  EXPECT_FALSE(pyramid.Draw(FrameAt(f, 1, {0, 0, 400, 300}, true)));  // stopped: refused, counted, never blocks
  EXPECT_EQ(pyramid.Stats().jobs_dropped, 1);
  fs::remove_all(dir);
}

TEST(LiveTilePyramidTest, OptionsAreChecked) {
  std::string why;
  EXPECT_TRUE(LiveTileOptions{}.Check(&why)) << why;
  LiveTileOptions o;
  o.cache_tiles = 2;
  EXPECT_FALSE(o.Check(&why));
  EXPECT_NE(why.find("cache_tiles"), std::string::npos);
  o = {};
  o.png_compression = 12;
  EXPECT_FALSE(o.Check(&why));
}

TEST(WebMercatorTest, AgreesWithProj) {
  OGRSpatialReference wgs, merc;
  wgs.importFromEPSG(4326);
  merc.importFromEPSG(3857);
  wgs.SetAxisMappingStrategy(OAMS_TRADITIONAL_GIS_ORDER);
  merc.SetAxisMappingStrategy(OAMS_TRADITIONAL_GIS_ORDER);
  std::unique_ptr<OGRCoordinateTransformation> t(OGRCreateCoordinateTransformation(&wgs, &merc));
  ASSERT_TRUE(t);
  std::mt19937 rng(4);
  std::uniform_real_distribution<double> lat(-80, 80), lon(-179, 179);
  for (int i = 0; i < 200; ++i) {
    double x = lon(rng), y = lat(rng);
    const double la = y, lo = x;
    ASSERT_TRUE(t->Transform(1, &x, &y));
    const Vec2 px = MercatorPixelFromLatLon(la, lo, 19);
    const Vec2 m = MercatorMetresFromPixel(px, 19);
    EXPECT_NEAR(m.x(), x, 1e-3);
    EXPECT_NEAR(m.y(), y, 1e-3);
    const Vec2 back = LonLatFromMercatorPixel(px, 19);
    EXPECT_NEAR(back.x(), lo, 1e-9);
    EXPECT_NEAR(back.y(), la, 1e-9);
  }
  EXPECT_NEAR(MercatorPixelFromLatLon(0, 0, 0).x(), 128, 1e-9);
  EXPECT_NEAR(MercatorPixelFromLatLon(0, 0, 0).y(), 128, 1e-9);
  // Zoom 18's pixel is 0.597 m at the equator, 0.299 m at 60 degrees.
  EXPECT_EQ(MaxZoomForGsd(0, 0.60), 18);
  EXPECT_EQ(MaxZoomForGsd(0, 0.59), 19);
  EXPECT_EQ(MaxZoomForGsd(60, 0.30), 18);
  EXPECT_EQ(MaxZoomForGsd(60, 0.29), 19);
}

TEST(TileRenderTest, HalvingAveragesOnlyWhatIsThere) {
  cv::Mat children(512, 512, CV_8UC4, cv::Scalar::all(0));
  children(cv::Rect(0, 0, 256, 512)).setTo(cv::Scalar(200, 100, 50, 255));  // the left half opaque
  cv::Mat parent(256, 256, CV_8UC4);
  HalveRgba(children, &parent);
  EXPECT_EQ(parent.at<cv::Vec4b>(10, 10), cv::Vec4b(200, 100, 50, 255));
  EXPECT_EQ(parent.at<cv::Vec4b>(10, 200)[3], 0);
  // A 2x2 block half transparent: the colour of its opaque half, half alpha (no black mixed in).
  children.setTo(cv::Scalar::all(0));
  children.at<cv::Vec4b>(0, 0) = children.at<cv::Vec4b>(1, 0) = cv::Vec4b(80, 160, 240, 255);
  HalveRgba(children, &parent);
  EXPECT_EQ(parent.at<cv::Vec4b>(0, 0), cv::Vec4b(80, 160, 240, 128));
}

}  // namespace
}  // namespace uavm
