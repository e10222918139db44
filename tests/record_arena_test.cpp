#include "core/util/record_arena.h"

#include <gtest/gtest.h>
#include <linux/magic.h>
#include <sys/mman.h>
#include <sys/resource.h>
#include <sys/vfs.h>
#include <unistd.h>

#include <csignal>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <memory>
#include <random>
#include <string>
#include <thread>
#include <unordered_map>
#include <vector>

#include "core/util/memory.h"

namespace uavm {
namespace {

class RecordArenaTest : public ::testing::Test {
 protected:
  void SetUp() override {
    if (!RecordArena::Enabled()) GTEST_SKIP() << "the arena is compiled out under AddressSanitizer";
  }
};

TEST_F(RecordArenaTest, SmallBlocksInAScopeComeFromTheArenaOthersFromMalloc) {
  std::string name_outside(20, 'a');
  std::vector<int> large_in_scope;
  std::string name_inside;
  std::unordered_map<int, double> map_inside;
  {
    const RecordArena::Scope scope;
    name_inside.assign(20, 'b');
    map_inside.emplace(7, 1.5);
    large_in_scope.resize(600);  // 2400 bytes: above kMaxBlockBytes
  }
  EXPECT_FALSE(RecordArena::Owns(name_outside.data()));
  EXPECT_TRUE(RecordArena::Owns(name_inside.data()));
  EXPECT_FALSE(RecordArena::Owns(large_in_scope.data()));
  EXPECT_EQ(name_inside, std::string(20, 'b'));
  EXPECT_EQ(map_inside.at(7), 1.5);
  // Grown outside the scope, the string moves to malloc and its arena block is freed.
  const size_t blocks = RecordArena::counters().blocks_in_use;
  name_inside.append(40, 'c');
  EXPECT_FALSE(RecordArena::Owns(name_inside.data()));
  EXPECT_EQ(RecordArena::counters().blocks_in_use, blocks - 1);
}

TEST_F(RecordArenaTest, AFreedBlockIsReusedByTheNextOfItsClass) {
  const RecordArena::Scope scope;
  const RecordArena::Counters before = RecordArena::counters();
  auto* first = new char[100];
  EXPECT_EQ(RecordArena::counters().in_use_bytes, before.in_use_bytes + 112);  // the 112-byte class
  const auto first_address = reinterpret_cast<uintptr_t>(first);
  delete[] first;
  EXPECT_EQ(RecordArena::counters().in_use_bytes, before.in_use_bytes);
  auto* second = new char[110];
  EXPECT_EQ(reinterpret_cast<uintptr_t>(second), first_address);
  delete[] second;
}

TEST_F(RecordArenaTest, ScopesNestAndBelongToTheirThread) {
  std::unique_ptr<int> outer;
  std::unique_ptr<int> inner;
  std::unique_ptr<int> after_inner;
  std::unique_ptr<int> other_thread;
  {
    const RecordArena::Scope a;
    {
      const RecordArena::Scope b;
      inner = std::make_unique<int>(1);
    }
    after_inner = std::make_unique<int>(2);
    std::thread([&other_thread] { other_thread = std::make_unique<int>(3); }).join();
  }
  outer = std::make_unique<int>(4);
  EXPECT_TRUE(RecordArena::Owns(inner.get()));
  EXPECT_TRUE(RecordArena::Owns(after_inner.get()));
  EXPECT_FALSE(RecordArena::Owns(other_thread.get()));
  EXPECT_FALSE(RecordArena::Owns(outer.get()));
  // A block made in a scope goes back to the arena when another thread deletes it.
  const size_t blocks = RecordArena::counters().blocks_in_use;
  std::thread([&inner] { inner.reset(); }).join();
  EXPECT_EQ(RecordArena::counters().blocks_in_use, blocks - 1);
}

// Random sizes made and freed in a scope, each block filled with its own byte: no two live blocks overlap, and every
// block keeps its bytes (checked against what was written, block by block).
TEST_F(RecordArenaTest, LiveBlocksNeverOverlap) {
  std::mt19937 rng(11);
  std::uniform_int_distribution<size_t> size(1, 1200);
  struct Block {
    std::unique_ptr<unsigned char[]> bytes;
    size_t n;
    unsigned char fill;
  };
  std::vector<Block> live;
  const RecordArena::Scope scope;
  for (int i = 0; i < 20000; ++i) {
    if (!live.empty() && rng() % 3 == 0) {
      live.erase(live.begin() + static_cast<std::ptrdiff_t>(rng() % live.size()));
      continue;
    }
    Block b{nullptr, size(rng), static_cast<unsigned char>(rng())};
    b.bytes.reset(new unsigned char[b.n]);
    std::memset(b.bytes.get(), b.fill, b.n);
    live.push_back(std::move(b));
  }
  for (const Block& b : live)
    for (size_t k = 0; k < b.n; ++k) ASSERT_EQ(b.bytes[k], b.fill);
}

// The flight's pattern: each frame leaves a few small records for the rest of the flight and frees its small
// transients. The records fill the arena's pages: what it carves stays within one run per class of what is in use.
TEST_F(RecordArenaTest, RecordsKeptBesideTransientsFillTheirPages) {
  const RecordArena::Counters before = RecordArena::counters();
  std::vector<std::string> names;
  std::vector<std::vector<size_t>> adjacency;
  names.reserve(5000);
  adjacency.reserve(5000);
  for (int frame = 0; frame < 5000; ++frame) {
    const RecordArena::Scope scope;
    std::vector<std::string> transients(8, std::string(40, 't'));
    names.push_back("frame_" + std::to_string(100000 + frame) + ".png");
    adjacency.emplace_back();
    for (size_t e = 0; e < 6; ++e) adjacency.back().push_back(e);
  }
  const RecordArena::Counters after = RecordArena::counters();
  const size_t in_use = after.in_use_bytes - before.in_use_bytes;
  const size_t carved = after.carved_bytes - before.carved_bytes;
  EXPECT_GE(in_use, 5000u * (32 + 64));  // 17-byte names and 48-byte lists
  EXPECT_LE(carved, in_use + 4 * (size_t{64} << 10));
  EXPECT_EQ(names[4999], "frame_104999.png");
  EXPECT_EQ(after.fallbacks, before.fallbacks);
}

// Whether the page holding p is resident (mincore).
bool Resident(const void* p) {
  const auto page = static_cast<uintptr_t>(sysconf(_SC_PAGESIZE));
  unsigned char in_core = 0;
  void* start = reinterpret_cast<void*>(reinterpret_cast<uintptr_t>(p) & ~(page - 1));
  return mincore(start, page, &in_core) == 0 && (in_core & 1) != 0;
}

// The end of a flight deletes most of its edge records at once: the runs left with no live block go back to the
// system, the blocks still alive keep their bytes, and the runs are carved again before any new one.
TEST_F(RecordArenaTest, RunsWithNoLiveBlockGoBackToTheSystemAndAreReused) {
  constexpr size_t kBlocks = 3000;
  constexpr size_t kKept = 100;
  constexpr size_t kBytes = 900;  // the 1024-byte class: 64 blocks a 64 KiB run
  std::vector<std::unique_ptr<unsigned char[]>> blocks;
  // Earlier tests' freed blocks go first, so that this test's blocks fill runs of their own, in order.
  (void)RecordArena::ReturnFreeRuns();
  {
    const RecordArena::Scope scope;
    for (size_t i = 0; i < kBlocks; ++i) {
      blocks.emplace_back(new unsigned char[kBytes]);
      std::memset(blocks.back().get(), static_cast<int>(i % 251), kBytes);
    }
  }
  for (const auto& b : blocks) ASSERT_TRUE(RecordArena::Owns(b.get()));
  std::vector<const void*> freed;
  for (size_t i = kKept; i < kBlocks; ++i) {
    freed.push_back(blocks[i].get());
    blocks[i].reset();
  }
  const RecordArena::Counters before = RecordArena::counters();
  const size_t returned = RecordArena::ReturnFreeRuns();
  // Of 2900 freed blocks, all but those sharing a run with a kept block or the class's current run lie in runs
  // wholly free: at least (2900 - 64 x 4) / 64 runs.
  EXPECT_GE(returned, (kBlocks - kKept - 256) / 64 * (size_t{64} << 10));
  EXPECT_EQ(RecordArena::counters().returned_bytes, before.returned_bytes + returned);
  size_t not_resident = 0;
  for (const void* p : freed) not_resident += Resident(p) ? 0 : 1;
  // All but those sharing a run with a kept block or sitting in the current run: ~2 and 1 runs of 64 blocks.
  EXPECT_GE(not_resident, kBlocks - kKept - 3 * 64);
  for (size_t i = 0; i < kKept; ++i)
    for (size_t k = 0; k < kBytes; ++k) ASSERT_EQ(blocks[i][k], static_cast<unsigned char>(i % 251));
  // New records take the returned runs first: nothing new is carved while they last.
  const size_t carved = RecordArena::counters().carved_bytes;
  {
    const RecordArena::Scope scope;
    for (size_t i = kKept; i < kBlocks; ++i) {
      blocks[i].reset(new unsigned char[kBytes]);
      std::memset(blocks[i].get(), static_cast<int>(i % 251), kBytes);
    }
  }
  EXPECT_EQ(RecordArena::counters().carved_bytes, carved);
  EXPECT_LT(RecordArena::counters().returned_bytes, before.returned_bytes + returned);
  for (size_t i = 0; i < kBlocks; ++i)
    for (size_t k = 0; k < kBytes; ++k) ASSERT_EQ(blocks[i][k], static_cast<unsigned char>(i % 251));
}

// Edge records and frame records of the same size, made in turn as a flight makes them: in groups of their own, the
// edges' runs hold no frame record, so dropping every edge at once leaves their runs wholly free (in one group, each
// run would keep frame records and none could go back).
TEST_F(RecordArenaTest, AGroupFreedAtOnceLeavesItsRunsWhollyFree) {
  constexpr size_t kEach = 2000;
  constexpr size_t kBytes = 500;  // the 512-byte class: 128 blocks a run
  (void)RecordArena::ReturnFreeRuns();
  std::vector<std::unique_ptr<char[]>> frames;
  std::vector<std::unique_ptr<char[]>> edges;
  {
    const RecordArena::Scope flight;
    for (size_t i = 0; i < kEach; ++i) {
      frames.emplace_back(new char[kBytes]);
      const RecordArena::Scope edge_records(RecordArena::Group::kEdges);
      edges.emplace_back(new char[kBytes]);
    }
  }
  std::vector<const void*> freed;
  for (auto& e : edges) {
    ASSERT_TRUE(RecordArena::Owns(e.get()));
    freed.push_back(e.get());
    e.reset();
  }
  const size_t returned = RecordArena::ReturnFreeRuns();
  EXPECT_GE(returned, (kEach - 2 * 128) / 128 * (size_t{64} << 10));
  size_t not_resident = 0;
  for (const void* p : freed) not_resident += Resident(p) ? 0 : 1;
  EXPECT_GE(not_resident, kEach - 2 * 128);  // all but the first run's (earlier blocks) and the current one's
  for (const auto& f : frames) EXPECT_TRUE(RecordArena::Owns(f.get()));
}

// The process's resident file pages, MiB: VmRSS less RssAnon (no shared memory here).
double FileMiB(const RssSample& s) {
  return s.rss_mib - s.anon_mib;
}

// The arena backed by a file: the records are file pages, not anonymous memory, the file is never seen in the
// directory, a run given back leaves the resident set, and runs the disk cannot hold go to malloc instead of faulting.
// The arena is reserved once per process, at its first record: CTest runs each test in a process of its own, and a
// run of the whole binary skips this one (its earlier tests made records).
TEST_F(RecordArenaTest, BackedByAFileTheRecordsAreReclaimableFilePagesNotAnonymousMemory) {
  const std::filesystem::path dir = std::filesystem::current_path() / "record_arena_file_test";
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  struct statfs fs {};
  ASSERT_EQ(statfs(dir.c_str(), &fs), 0);
  // tmpfs pages are memory: the arena refuses them, and nothing is left to test here.
  if (fs.f_type == TMPFS_MAGIC) GTEST_SKIP() << "the build directory is on tmpfs";
  std::string why;
  EXPECT_FALSE(RecordArena::BackWithFile((dir / "missing").string(), &why));
  if (statfs("/dev/shm", &fs) == 0 && fs.f_type == TMPFS_MAGIC) {
    EXPECT_FALSE(RecordArena::BackWithFile("/dev/shm", &why)) << "a memory filesystem was taken";
  }
  if (!RecordArena::BackWithFile(dir.string(), &why)) {
    ASSERT_EQ(why, "records exist already");
    GTEST_SKIP() << "this process made records before the test (run it alone, as CTest does)";
  }
  EXPECT_TRUE(RecordArena::counters().file_backed);
  EXPECT_TRUE(std::filesystem::is_empty(dir)) << "the file is visible in the directory";
  EXPECT_FALSE(RecordArena::BackWithFile(dir.string(), &why));
  constexpr size_t kBlocks = 40000;  // x 512 bytes: 20 MiB of records
  const RssSample before = SampleRss();
  std::vector<char*> blocks;
  blocks.reserve(kBlocks);
  {
    const RecordArena::Scope records;
    for (size_t i = 0; i < kBlocks; ++i) {
      blocks.push_back(new char[500]);
      std::memset(blocks.back(), static_cast<int>(i & 0x7f), 500);
    }
  }
  EXPECT_TRUE(RecordArena::Owns(blocks.front()));
  EXPECT_TRUE(RecordArena::Owns(blocks.back()));
  const RssSample grown = SampleRss();
  EXPECT_LT(grown.anon_mib - before.anon_mib, 3.0);
  EXPECT_GT(FileMiB(grown) - FileMiB(before), 18.0);
  for (size_t i = 0; i < kBlocks; i += 997) EXPECT_EQ(blocks[i][499], static_cast<char>(i & 0x7f));
  for (char* b : blocks) delete[] b;
  blocks.clear();
  EXPECT_GE(RecordArena::ReturnFreeRuns(), size_t{18} << 20);
  EXPECT_LT(FileMiB(SampleRss()) - FileMiB(before), 3.0) << "the runs' pages stayed resident";
  // A disk that fills: the file may not grow now (a 1 MiB file-size limit, below its ~20 MiB). The runs given back are
  // taken again within its length; the ones past its end come from malloc, counted.
  const auto old_handler = std::signal(SIGXFSZ, SIG_IGN);
  rlimit old_limit{};
  ASSERT_EQ(getrlimit(RLIMIT_FSIZE, &old_limit), 0);
  const rlimit one_mib{1 << 20, old_limit.rlim_max};
  ASSERT_EQ(setrlimit(RLIMIT_FSIZE, &one_mib), 0);
  const size_t fallbacks = RecordArena::counters().fallbacks;
  std::vector<std::unique_ptr<char[]>> more;
  {
    const RecordArena::Scope records;
    for (size_t i = 0; i < kBlocks + 8000; ++i) {
      more.emplace_back(new char[500]);
      std::memset(more.back().get(), 1, 500);
    }
  }
  setrlimit(RLIMIT_FSIZE, &old_limit);
  std::signal(SIGXFSZ, old_handler);
  EXPECT_GT(RecordArena::counters().fallbacks, fallbacks) << "no block went to malloc past the disk's end";
  EXPECT_TRUE(RecordArena::Owns(more.front().get()));
  EXPECT_FALSE(RecordArena::Owns(more.back().get()));
  more.clear();
  std::filesystem::remove_all(dir);
}

}  // namespace
}  // namespace uavm
