// The large-buffer pool behind cv::Mat: reuse, its bounds (peak, cap, slack), flushing, and that OpenCV computes the
// same results on pooled buffers (SIFT before and after the pool is installed).
#include "core/buffers/mat_pool.h"

#include <gtest/gtest.h>

#include <cstdio>
#include <fstream>
#include <opencv2/features2d.hpp>
#include <opencv2/imgproc.hpp>
#include <random>
#include <string>
#include <thread>

#include "tests/test_env.h"

namespace uavm {
namespace {

constexpr size_t kMiB = size_t{1} << 20;

// A Mat of `mib` MiB (rows of 1 KiB) from `pool`.
cv::Mat Make(const MatPool& pool, double mib) {
  cv::Mat m;
  m.allocator = const_cast<MatPool*>(&pool);
  m.create(static_cast<int>(mib * 1024), 1024, CV_8UC1);
  return m;
}

TEST(MatPoolTest, AFreedBlockServesTheNextRequestOfAboutItsSize) {
  MatPool pool(MatPoolOptions{});
  const uchar* first = nullptr;
  {
    cv::Mat a = Make(pool, 4);
    first = a.data;
  }
  EXPECT_EQ(pool.Stats().pooled_bytes, 4 * kMiB);
  cv::Mat b = Make(pool, 3.5);  // within the 25 % slack
  EXPECT_EQ(b.data, first);
  EXPECT_EQ(pool.Stats().hits, 1u);
  EXPECT_EQ(pool.Stats().pooled_bytes, 0u);
  EXPECT_EQ(pool.Stats().in_use_bytes, 4 * kMiB);  // the block keeps its capacity
}

// Where the kernel offers transparent huge pages on request, a block's whole 2 MiB pages are huge: /proc/self/smaps
// shows the mapping holding the touched block with AnonHugePages. Alignment is asserted wherever that page is 2 MiB.
TEST(MatPoolTest, LargeBlocksAreAlignedForHugePages) {
  std::ifstream pmd("/sys/kernel/mm/transparent_hugepage/hpage_pmd_size");
  size_t huge_page = 0;
  if (!(pmd >> huge_page) || huge_page != 2 * kMiB)
    GTEST_SKIP() << "this kernel's huge page is not 2 MiB (" << huge_page << " bytes): blocks are not aligned for it";
  MatPool pool(MatPoolOptions{});
  cv::Mat m = Make(pool, 5);
  m.setTo(1);  // touch every page
  const auto address = reinterpret_cast<uintptr_t>(m.data);
  EXPECT_EQ(address % (2 * kMiB), 0u);
  cv::Mat small = Make(pool, 1.5);  // below one huge page: an ordinary block
  EXPECT_NE(small.data, nullptr);
  // qemu-aarch64 (user mode) takes the advice without acting on it: the host's pages stay small.
  if (test::Emulated()) GTEST_SKIP() << "under emulation madvise(MADV_HUGEPAGE) is not carried out";
  std::ifstream thp("/sys/kernel/mm/transparent_hugepage/enabled");
  std::string mode;
  std::getline(thp, mode);
  if (mode.find("[madvise]") == std::string::npos && mode.find("[always]") == std::string::npos)
    GTEST_SKIP() << "this kernel gives no transparent huge pages on request (" << mode << ")";
  std::ifstream smaps("/proc/self/smaps");
  std::string line;
  bool inside = false;
  long huge_kb = -1;
  while (std::getline(smaps, line)) {
    uintptr_t lo = 0;
    uintptr_t hi = 0;
    if (std::sscanf(line.c_str(), "%lx-%lx ", &lo, &hi) == 2) {  // a mapping's first line; field lines are "Name: n"
      inside = lo <= address && address < hi;
    } else if (inside && line.rfind("AnonHugePages:", 0) == 0) {
      huge_kb = std::stol(line.substr(14));
      break;
    }
  }
  ASSERT_GE(huge_kb, 0) << "the block's mapping is not in /proc/self/smaps";
  EXPECT_GE(huge_kb, 2048) << "a touched 5 MiB block aligned to 2 MiB holds no huge page";
}

TEST(MatPoolTest, ABlockMuchLargerThanTheRequestIsNotUsed) {
  MatPool pool(MatPoolOptions{});
  { cv::Mat a = Make(pool, 4); }
  cv::Mat b = Make(pool, 2);
  EXPECT_EQ(pool.Stats().hits, 0u);
  EXPECT_EQ(pool.Stats().misses, 2u);
}

TEST(MatPoolTest, PooledAndInUseBytesNeverPassThePeakWithoutThePool) {
  MatPool pool(MatPoolOptions{});
  {
    cv::Mat a = Make(pool, 4);
    cv::Mat b = Make(pool, 4);
  }                           // peak 8 MiB in use, now 8 MiB pooled
  cv::Mat c = Make(pool, 6);  // no block fits: both pooled blocks must go (4 + 4 + 6 > 8, then 4 + 6 > 8)
  const MatPoolStats s = pool.Stats();
  EXPECT_EQ(s.pooled_bytes, 0u);
  EXPECT_EQ(s.evictions, 2u);
  EXPECT_EQ(s.in_use_bytes, 6 * kMiB);
  cv::Mat d = Make(pool, 1.5);  // in use 7.5 of a peak of 8: nothing pooled to give back anyway
  EXPECT_LE(pool.Stats().pooled_bytes + pool.Stats().in_use_bytes, 8 * kMiB);
}

TEST(MatPoolTest, TheLeastRecentlyFreedBlockGoesFirst) {
  MatPool pool(MatPoolOptions{});
  const uchar* kept = nullptr;
  {
    cv::Mat a = Make(pool, 2);
    cv::Mat b = Make(pool, 3);
    cv::Mat c = Make(pool, 5);
    kept = c.data;
    a.release();
    b.release();
  }                             // freed in the order a, b, c; peak 10 MiB
  cv::Mat d = Make(pool, 1.2);  // 10 + 1.2 > 10: the 2 MiB block (freed first) goes, not the 5 MiB one
  EXPECT_EQ(pool.Stats().evictions, 1u);
  EXPECT_EQ(pool.Stats().pooled_bytes, 8 * kMiB);
  cv::Mat e = Make(pool, 4.5);
  EXPECT_EQ(e.data, kept);
}

TEST(MatPoolTest, TheCapBoundsWhatIsKept) {
  MatPoolOptions o;
  o.max_pooled_bytes = 5 * kMiB;
  MatPool pool(o);
  {
    cv::Mat a = Make(pool, 4);
    cv::Mat b = Make(pool, 4);
    cv::Mat big = Make(pool, 6);  // larger than the cap: never pooled
  }
  EXPECT_EQ(pool.Stats().pooled_bytes, 4 * kMiB);
  EXPECT_EQ(pool.Stats().in_use_bytes, 0u);
}

TEST(MatPoolTest, FlushReturnsEveryBlockAndStartsANewPeak) {
  MatPool pool(MatPoolOptions{});
  { cv::Mat a = Make(pool, 8); }
  pool.Flush();
  EXPECT_EQ(pool.Stats().pooled_bytes, 0u);
  EXPECT_EQ(pool.Stats().peak_in_use_bytes, 0u);
  { cv::Mat b = Make(pool, 2); }
  cv::Mat c = Make(pool, 3);  // the new peak is 2 MiB: the pooled 2 MiB block goes rather than stay beside c
  EXPECT_EQ(pool.Stats().pooled_bytes, 0u);
}

TEST(MatPoolTest, AWindowKeepsOnlyItsOwnPeak) {
  MatPool pool(MatPoolOptions{});
  {
    cv::Mat a = Make(pool, 4);
    cv::Mat b = Make(pool, 6);
  }                        // a rare peak of 10 MiB in use, now pooled (the 6 MiB block freed first)
  pool.StartPeakWindow();  // the first window's peak was 10: both blocks stay
  EXPECT_EQ(pool.Stats().pooled_bytes, 10 * kMiB);
  EXPECT_EQ(pool.Stats().evictions, 0u);
  { cv::Mat c = Make(pool, 4); }  // this window needs 4 MiB at most
  pool.StartPeakWindow();
  EXPECT_EQ(pool.Stats().pooled_bytes, 4 * kMiB);  // the 6 MiB block, unused in this window, went back
  EXPECT_EQ(pool.Stats().evictions, 1u);
  EXPECT_EQ(pool.Stats().peak_in_use_bytes, 4 * kMiB);
  cv::Mat d = Make(pool, 4);  // the kept block serves the working set again
  EXPECT_EQ(pool.Stats().hits, 2u);
  cv::Mat e = Make(pool, 5);  // a miss: 4 in use + 5 passes nothing pooled, so nothing goes
  EXPECT_EQ(pool.Stats().misses, 3u);
  e.release();  // pooled 5 beside d's 4: within this window's peak of 9
  EXPECT_EQ(pool.Stats().pooled_bytes, 5 * kMiB);
  pool.StartPeakWindow();  // this window's peak was 9: the 5 MiB block stays
  EXPECT_EQ(pool.Stats().pooled_bytes, 5 * kMiB);
  d.release();
  pool.StartPeakWindow();  // nothing was taken in this window: its peak is the 4 MiB d held
  EXPECT_EQ(pool.Stats().pooled_bytes, 4 * kMiB);
  pool.StartPeakWindow();  // a window with nothing in use: every block goes back
  EXPECT_EQ(pool.Stats().pooled_bytes, 0u);
  EXPECT_EQ(pool.Stats().evictions, 3u);
}

TEST(MatPoolTest, SmallMatsAndUserDataAreLeftAlone) {
  MatPool pool(MatPoolOptions{});
  { cv::Mat small = Make(pool, 0.25); }
  std::vector<uchar> mine(4 * kMiB, 7);
  {
    cv::Mat wrapped(4096, 1024, CV_8UC1, mine.data());
    wrapped.allocator = &pool;
    cv::Mat copy;
    copy.allocator = &pool;
    wrapped.copyTo(copy);
    EXPECT_EQ(copy.at<uchar>(4095, 1023), 7);
  }
  EXPECT_EQ(mine[0], 7);
  const MatPoolStats s = pool.Stats();
  EXPECT_EQ(s.misses, 1u);  // the copy only
  EXPECT_EQ(s.pooled_bytes, 4 * kMiB);
}

TEST(MatPoolTest, TwoThreadsShareItSafely) {
  MatPool pool(MatPoolOptions{});
  auto work = [&](unsigned seed) {
    std::mt19937 rng(seed);
    std::uniform_real_distribution<double> mib(1.0, 6.0);
    std::vector<cv::Mat> held;
    for (int i = 0; i < 400; ++i) {
      held.push_back(Make(pool, mib(rng)));
      held.back().setTo(static_cast<int>(i & 0xff));
      EXPECT_EQ(held.back().at<uchar>(0, 0), static_cast<uchar>(i & 0xff));
      if (held.size() > 4) held.erase(held.begin() + static_cast<long>(rng() % held.size()));
    }
  };
  std::thread t1(work, 1u), t2(work, 2u);
  t1.join();
  t2.join();
  const MatPoolStats s = pool.Stats();
  EXPECT_EQ(s.in_use_bytes, 0u);
  EXPECT_GT(s.hits, 0u);
  EXPECT_LE(s.pooled_bytes, s.peak_in_use_bytes);
}

TEST(MatPoolTest, OpenCvComputesTheSameOnPooledBuffers) {
  // Three SIFT runs: a quarter of the pixels under emulation (24 s under qemu at 800x600).
  const int cols = static_cast<int>(800 * test::EmulationImageScale());
  cv::Mat image(cols * 3 / 4, cols, CV_8UC1);
  cv::randu(image, 0, 255);
  cv::GaussianBlur(image, image, cv::Size(0, 0), 2.0);
  auto detect = [&](std::vector<cv::KeyPoint>* kps, cv::Mat* desc) {
    cv::SIFT::create(2000, 3, 0.01)->detectAndCompute(image, cv::noArray(), *kps, *desc);
  };
  std::vector<cv::KeyPoint> before, after, again;
  cv::Mat d_before, d_after, d_again;
  detect(&before, &d_before);
  MatPool* pool = InstallMatPool();
  ASSERT_EQ(InstalledMatPool(), pool);
  detect(&after, &d_after);
  detect(&again, &d_again);  // on the blocks the first call gave back
  EXPECT_GT(pool->Stats().hits, 0u);
  ASSERT_EQ(before.size(), after.size());
  ASSERT_EQ(before.size(), again.size());
  for (size_t i = 0; i < before.size(); ++i) {
    EXPECT_EQ(before[i].pt, after[i].pt);
    EXPECT_EQ(before[i].pt, again[i].pt);
  }
  EXPECT_EQ(cv::norm(d_before, d_after, cv::NORM_INF), 0.0);
  EXPECT_EQ(cv::norm(d_before, d_again, cv::NORM_INF), 0.0);
  FlushMatPool();
  EXPECT_EQ(pool->Stats().pooled_bytes, 0u);
}

}  // namespace
}  // namespace uavm
