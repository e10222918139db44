#include "core/session/edge_store.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <random>

namespace uavm {
namespace {

namespace fs = std::filesystem;

Edge RandomEdge(int src, int tgt, size_t n, size_t n_holdout, std::mt19937* rng) {
  std::uniform_real_distribution<double> u(0.0, 1920.0);
  Edge e;
  e.src = src;
  e.tgt = tgt;
  std::vector<Vec2f> from, to, held_from, held_to;
  for (size_t k = 0; k < n; ++k) {
    from.emplace_back(u(*rng), u(*rng));
    to.emplace_back(u(*rng), u(*rng));
  }
  for (size_t k = 0; k < n_holdout; ++k) {
    held_from.emplace_back(u(*rng), u(*rng));
    held_to.emplace_back(u(*rng), u(*rng));
  }
  e.points = EdgePoints(from, to, held_from, held_to);
  return e;
}

fs::path TempDir() {
  return fs::temp_directory_path() / ("uavm_edges_" + std::to_string(::getpid()));
}

// Removed when the test process exits (ctest runs every test in a process of its own), so runs leave no files.
struct RemoveTempDirAtExit {
  ~RemoveTempDirAtExit() {
    std::error_code ec;
    fs::remove_all(TempDir(), ec);
  }
} remove_temp_dir_at_exit;

fs::path TempFile(const std::string& name) {
  fs::create_directories(TempDir());
  return TempDir() / name;
}

TEST(EdgeStoreTest, ReleasedPointsComeBackExactly) {
  std::mt19937 rng(5);
  EdgeStore store;
  std::string err;
  ASSERT_TRUE(store.Open(TempFile("roundtrip.bin").string(), &err)) << err;
  std::vector<Edge> edges;
  for (int i = 0; i < 50; ++i) edges.push_back(RandomEdge(i, i + 1, 64, 16, &rng));
  edges.push_back(RandomEdge(50, 51, 0, 0, &rng));  // an edge without points is a valid record
  const std::vector<Edge> original = edges;
  for (auto& e : edges) ASSERT_TRUE(store.Append(&e, &err)) << err;
  size_t freed = 0;
  for (auto& e : edges) freed += store.Release(&e);
  EXPECT_GE(freed, 50u * 160u * sizeof(Vec2f));
  for (const auto& e : edges) {
    EXPECT_FALSE(e.points_resident);
    EXPECT_EQ(e.points.size() + e.points.holdout_size(), 0u);
    EXPECT_EQ(e.points.bytes(), 0u);  // given back, not just cleared
  }
  // Out of order, as a solve that needs an old edge would.
  for (size_t i = edges.size(); i-- > 0;) {
    ASSERT_TRUE(store.Load(&edges[i], &err)) << err;
    const EdgePoints& read = edges[i].points;
    const EdgePoints& written = original[i].points;
    ASSERT_EQ(read.size(), written.size());
    ASSERT_EQ(read.holdout_size(), written.holdout_size());
    for (size_t k = 0; k < written.size(); ++k) {
      EXPECT_EQ(read.src(k), written.src(k));
      EXPECT_EQ(read.tgt(k), written.tgt(k));
    }
    for (size_t k = 0; k < written.holdout_size(); ++k) {
      EXPECT_EQ(read.holdout_src(k), written.holdout_src(k));
      EXPECT_EQ(read.holdout_tgt(k), written.holdout_tgt(k));
    }
  }
  // Appending after reads still goes to the end.
  Edge late = RandomEdge(60, 61, 8, 2, &rng);
  ASSERT_TRUE(store.Append(&late, &err)) << err;
  EXPECT_GT(late.stored_at, edges.back().stored_at);
  ASSERT_GT(store.Release(&late), 0u);
  ASSERT_TRUE(store.Load(&late, &err)) << err;
  EXPECT_EQ(late.points.size(), 8u);
  EXPECT_EQ(late.points.holdout_size(), 2u);
}

TEST(EdgeStoreTest, CorruptRecordIsRefusedNotTrusted) {
  std::mt19937 rng(6);
  const fs::path path = TempFile("corrupt.bin");
  EdgeStore store;
  std::string err;
  ASSERT_TRUE(store.Open(path.string(), &err)) << err;
  Edge a = RandomEdge(0, 1, 32, 4, &rng);
  Edge b = RandomEdge(1, 2, 32, 4, &rng);
  ASSERT_TRUE(store.Append(&a, &err));
  ASSERT_TRUE(store.Append(&b, &err));
  store.Release(&a);
  store.Release(&b);
  {
    // Flip one byte of a's payload on disk.
    std::fstream f(path, std::ios::in | std::ios::out | std::ios::binary);
    f.seekp(a.stored_at + 24 + 40);
    char c = 0;
    f.seekg(a.stored_at + 24 + 40);
    f.read(&c, 1);
    c = static_cast<char>(c ^ 0x5a);
    f.seekp(a.stored_at + 24 + 40);
    f.write(&c, 1);
  }
  EXPECT_FALSE(store.Load(&a, &err));
  EXPECT_NE(err.find("corrupt"), std::string::npos) << err;
  EXPECT_FALSE(a.points_resident);
  ASSERT_TRUE(store.Load(&b, &err)) << err;  // its neighbour is intact
  // A record that belongs to another edge is refused too.
  Edge wrong = b;
  store.Release(&b);
  wrong.points_resident = false;
  wrong.src = 7;
  EXPECT_FALSE(store.Load(&wrong, &err));
}

TEST(EdgeStoreTest, UnwritablePathFailsWithReason) {
  EdgeStore store;
  std::string err;
  EXPECT_FALSE(store.Open("/nonexistent_dir_uavm/edges.bin", &err));
  EXPECT_NE(err.find("edges.bin"), std::string::npos);
  Edge e;
  EXPECT_FALSE(store.Append(&e, &err));
  EXPECT_EQ(store.Release(&e), 0u);  // never stored: keeps its points
  EXPECT_TRUE(e.points_resident);
}

}  // namespace
}  // namespace uavm
