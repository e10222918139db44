// ImageBuffer (core/buffers/image_buffer.h): views of any size and type in one block that only grows, written in place
// by OpenCV.
#include "core/buffers/image_buffer.h"

#include <gtest/gtest.h>
#include <sys/mman.h>
#include <unistd.h>

#include <cstdint>
#include <opencv2/imgproc.hpp>
#include <vector>

namespace uavm {
namespace {

TEST(ImageBufferTest, SmallerViewsReuseTheBlockAndALargerOneGrowsIt) {
  ImageBuffer buffer;
  cv::Mat a = buffer.View({300, 200}, CV_16SC3);
  ASSERT_EQ(a.size(), cv::Size(300, 200));
  ASSERT_EQ(a.type(), CV_16SC3);
  EXPECT_TRUE(a.isContinuous());
  EXPECT_GE(buffer.capacity(), 300u * 200u * 6u);
  const uchar* block = a.data;
  const size_t capacity = buffer.capacity();
  for (const auto& [size, type] : {std::pair{cv::Size(300, 200), CV_32F}, std::pair{cv::Size(17, 5), CV_8UC3},
                                   std::pair{cv::Size(600, 300), CV_8U}}) {
    const cv::Mat v = buffer.View(size, type);
    EXPECT_EQ(v.data, block) << size;
    EXPECT_EQ(buffer.capacity(), capacity);
  }
  const cv::Mat grown = buffer.View({301, 200}, CV_16SC3);
  EXPECT_GT(buffer.capacity(), capacity);
  EXPECT_EQ(grown.size(), cv::Size(301, 200));
}

TEST(ImageBufferTest, OpenCvWritesIntoAViewOfTheRightSizeAndType) {
  ImageBuffer buffer;
  cv::Mat src(64, 48, CV_8UC3, cv::Scalar(10, 20, 30));
  cv::Mat dst = buffer.View({24, 32}, CV_8UC3);
  const uchar* block = dst.data;
  cv::resize(src, dst, dst.size());
  cv::Mat down = buffer.View({24, 32}, CV_8UC3);
  EXPECT_EQ(dst.data, block);
  EXPECT_EQ(down.at<cv::Vec3b>(5, 5), cv::Vec3b(10, 20, 30));
  cv::Mat wide;
  buffer.Reserve(size_t{1} << 20);
  wide = buffer.View({1024, 1024}, CV_8U);
  wide.setTo(7);
  EXPECT_EQ(cv::countNonZero(wide != 7), 0);
}

TEST(ImageBufferTest, AnEmptyViewNeedsNoBlock) {
  ImageBuffer buffer;
  const cv::Mat v = buffer.View({0, 0}, CV_8U);
  EXPECT_TRUE(v.empty());
  EXPECT_EQ(buffer.capacity(), 0u);
}

// Share of the pages under `view` that are resident (mincore).
double ResidentShare(const cv::Mat& view) {
  const auto page = static_cast<uintptr_t>(sysconf(_SC_PAGESIZE));
  const auto begin = reinterpret_cast<uintptr_t>(view.data) / page * page;
  const auto end = (reinterpret_cast<uintptr_t>(view.data) + view.total() * view.elemSize() + page - 1) / page * page;
  std::vector<unsigned char> resident((end - begin) / page);
  if (mincore(reinterpret_cast<void*>(begin), end - begin, resident.data()) != 0) return -1.0;
  size_t count = 0;
  for (unsigned char r : resident) count += r & 1U;
  return static_cast<double>(count) / static_cast<double>(resident.size());
}

// A reserved block is mapped, not resident, until written; ReserveResident writes it all (zeros), so that the holder's
// memory does not depend on how much of it later views touch.
TEST(ImageBufferTest, ReserveResidentMakesTheWholeBlockResident) {
  constexpr size_t kBytes = size_t{48} << 20;  // above glibc's largest mmap threshold: a fresh mapping either way
  const cv::Size whole(4096, static_cast<int>(kBytes / 4096));
  ImageBuffer lazy;
  lazy.Reserve(kBytes);
  const double lazy_share = ResidentShare(lazy.View(whole, CV_8U));
  ASSERT_GE(lazy_share, 0.0) << "mincore failed";
  EXPECT_LT(lazy_share, 0.5);
  ImageBuffer resident;
  resident.ReserveResident(kBytes);
  const cv::Mat view = resident.View(whole, CV_8U);
  EXPECT_EQ(ResidentShare(view), 1.0);
  EXPECT_EQ(cv::countNonZero(view.reshape(1, 1024)), 0);
  EXPECT_GE(resident.capacity(), kBytes);
}

}  // namespace
}  // namespace uavm
