// ImageBuffer (core/buffers/image_buffer.h): views of any size and type in one block that only grows, written in place
// by OpenCV.
#include "core/buffers/image_buffer.h"

#include <gtest/gtest.h>

#include <opencv2/imgproc.hpp>

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

}  // namespace
}  // namespace uavm
