#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <random>

#include "core/session/feature_store.h"
#include "core/session/session_dir.h"

namespace uavm {
namespace {

namespace fs = std::filesystem;

fs::path TempDir(const std::string& name) {
  const fs::path p = fs::temp_directory_path() / ("uavm_" + name + "_" + std::to_string(::getpid()));
  fs::remove_all(p);
  fs::create_directories(p);
  return p;
}

TEST(SessionTest, TransformsCsvRoundTrip) {
  std::vector<TransformRow> rows(3);
  rows[0] = {0, "a.jpg", true, Mat3::Identity(), ""};
  rows[1].index = 1;
  rows[1].filename = "b.jpg";
  rows[1].registered = true;
  rows[1].mosaic_from_frame << 0.5, 0.01, 12.25, -0.02, 0.49, 300.5, 1e-6, -2e-6, 1;
  rows[1].placed_by = "telemetry";
  rows[2] = {2, "c.jpg", false, Mat3::Identity(), ""};
  const std::string text = FormatTransformsCsv(rows);
  EXPECT_EQ(text.substr(0, text.find('\n')), "index,filename,registered,a00,a01,a02,a10,a11,a12,h20,h21,placed_by");
  std::vector<TransformRow> back;
  std::string err;
  ASSERT_TRUE(ParseTransformsCsv(text, &back, &err)) << err;
  ASSERT_EQ(back.size(), 3u);
  EXPECT_TRUE(back[1].mosaic_from_frame.isApprox(rows[1].mosaic_from_frame, 1e-9));
  EXPECT_EQ(back[0].placed_by, "image");  // a registered row without a value is placed by images
  EXPECT_EQ(back[1].placed_by, "telemetry");
  EXPECT_FALSE(back[2].registered);
  EXPECT_EQ(back[2].placed_by, "");
  EXPECT_FALSE(ParseTransformsCsv("index,wrong\n", &back, &err));
  EXPECT_FALSE(ParseTransformsCsv(std::string(kTransformsHeader) + "\n0,a.jpg,1,1,0,0,0,1,0,0,0,gps\n", &back, &err));
  EXPECT_NE(err.find("placed_by"), std::string::npos) << err;
}

// Sessions written before the placed_by column are still read: their registered frames were placed by images.
TEST(SessionTest, TransformsCsvWithoutPlacedByIsRead) {
  std::vector<TransformRow> back;
  std::string err;
  ASSERT_TRUE(ParseTransformsCsv(std::string(kTransformsHeaderV1) + "\n0,a.jpg,1,1,0,5,0,1,7,0,0\n1,b.jpg,0,,,,,,,,\n",
                                 &back, &err))
      << err;
  ASSERT_EQ(back.size(), 2u);
  EXPECT_EQ(back[0].placed_by, "image");
  EXPECT_DOUBLE_EQ(back[0].mosaic_from_frame(1, 2), 7.0);
  EXPECT_FALSE(back[1].registered);
}

TEST(SessionTest, FeatureStoreEvictsAndReloadsFromDisk) {
  const fs::path dir = TempDir("features");
  std::mt19937 rng(1);
  std::uniform_real_distribution<float> u(0, 0.4f);
  FeatureStore store(dir.string(), 3 * (1000 * (128 + 8)));  // room for about 3 frames
  std::vector<Features> originals;
  for (int id = 0; id < 6; ++id) {
    Features f;
    f.descriptors.create(1000, 128, CV_32F);
    for (int r = 0; r < 1000; ++r) {
      f.points.emplace_back(u(rng) * 1000, u(rng) * 1000);
      for (int c = 0; c < 128; ++c) f.descriptors.at<float>(r, c) = u(rng);
    }
    std::string err;
    ASSERT_TRUE(store.Put(id, f, &err)) << err;
    originals.push_back(f);
  }
  EXPECT_LE(store.resident_bytes(), size_t{3 * 1000 * (128 + 8)});
  const auto first = store.Get(0);  // evicted long ago: comes back from disk
  ASSERT_NE(first, nullptr);
  EXPECT_EQ(store.disk_loads(), 1u);
  ASSERT_EQ(first->size(), 1000u);
  EXPECT_EQ(first->points[17], originals[0].points[17]);
  // 8-bit storage: within half a quantisation step (1/512) of the float value.
  EXPECT_NEAR(first->descriptors.at<uchar>(5, 9) / 512.0, originals[0].descriptors.at<float>(5, 9), 1.0 / 1024 + 1e-6);
  EXPECT_EQ(store.Get(99), nullptr);
  fs::remove_all(dir);
}

TEST(SessionTest, UnwritableOutputIsReported) {
  SessionPaths paths;
  std::string err;
  EXPECT_FALSE(PrepareSessionDir("/proc/uavm_cannot_be_here", &paths, &err));
  EXPECT_NE(err.find("/proc/uavm_cannot_be_here"), std::string::npos);
}

// One run per session directory: a second lock on it is refused, naming the holder's PID, until the first is
// released (the kernel releases it too when its process ends).
TEST(SessionTest, ASessionDirectoryHasOneWriter) {
  const fs::path root = fs::temp_directory_path() / ("uavm_lock_" + std::to_string(::getpid()));
  fs::remove_all(root);
  SessionPaths paths;
  std::string err;
  ASSERT_TRUE(PrepareSessionDir(root.string(), &paths, &err)) << err;
  {
    SessionLock first;
    ASSERT_TRUE(first.Acquire(paths, &err)) << err;
    EXPECT_TRUE(first.held());
    SessionLock second;
    EXPECT_FALSE(second.Acquire(paths, &err));
    EXPECT_FALSE(second.held());
    EXPECT_NE(err.find("in use by process " + std::to_string(::getpid())), std::string::npos) << err;
    SessionLock moved = std::move(first);
    EXPECT_TRUE(moved.held());
    EXPECT_FALSE(second.Acquire(paths, &err)) << "a moved lock is still held";
  }
  SessionLock again;
  EXPECT_TRUE(again.Acquire(paths, &err)) << err;
  fs::remove_all(root);
}

}  // namespace
}  // namespace uavm
