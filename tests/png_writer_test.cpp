// The libdeflate PNG encoder of the web tiles, read back by an independent decoder (OpenCV's, libpng): every pixel
// and the alpha come back exactly, at any size; a wrong input type is refused.
#include "core/imageio/png_writer.h"

#include <gtest/gtest.h>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <random>

namespace uavm {
namespace {

cv::Mat RandomBgra(cv::Size size, uint32_t seed) {
  cv::Mat m(size, CV_8UC4);
  cv::RNG rng(seed);
  rng.fill(m, cv::RNG::UNIFORM, 0, 256);
  return m;
}

void ExpectRoundTrip(const cv::Mat& bgra, PngWriter* writer) {
  std::vector<uint8_t> png;
  ASSERT_TRUE(writer->Encode(bgra, &png));
  const cv::Mat back = cv::imdecode(png, cv::IMREAD_UNCHANGED);
  ASSERT_EQ(back.type(), CV_8UC4);
  ASSERT_EQ(back.size(), bgra.size());
  EXPECT_EQ(cv::norm(back, bgra, cv::NORM_INF), 0.0) << bgra.size();
}

TEST(PngWriterTest, LibpngReadsBackEveryPixelAtAnySize) {
  PngWriter writer(1);
  for (const cv::Size size : {cv::Size(1, 1), cv::Size(256, 256), cv::Size(257, 3), cv::Size(3, 300)})
    ExpectRoundTrip(RandomBgra(size, static_cast<uint32_t>(size.area())), &writer);
  // A tile-like picture: smooth colour, a transparent half, hard edges; and a view into a bigger image (row stride).
  cv::Mat tile(256, 256, CV_8UC4, cv::Scalar(0, 0, 0, 0));
  for (int y = 0; y < 256; ++y)
    for (int x = 0; x < 160; ++x) tile.at<cv::Vec4b>(y, x) = cv::Vec4b(uint8_t(x), uint8_t(y), uint8_t(x ^ y), 255);
  cv::circle(tile, {128, 128}, 40, cv::Scalar(10, 200, 30, 255), -1);
  ExpectRoundTrip(tile, &writer);
  const cv::Mat big = RandomBgra({600, 400}, 3);
  ExpectRoundTrip(big(cv::Rect(17, 5, 256, 256)), &writer);
  PngWriter best(12);
  ExpectRoundTrip(tile, &best);
}

TEST(PngWriterTest, CompressesASmoothTileAndRefusesOtherTypes) {
  cv::Mat tile(256, 256, CV_8UC4);
  for (int y = 0; y < 256; ++y)
    for (int x = 0; x < 256; ++x) tile.at<cv::Vec4b>(y, x) = cv::Vec4b(uint8_t(x), uint8_t(y), 128, 255);
  PngWriter writer(1);
  std::vector<uint8_t> png;
  ASSERT_TRUE(writer.Encode(tile, &png));
  EXPECT_LT(png.size(), tile.total() * 4 / 20);  // SUB-filtered gradients compress well
  EXPECT_FALSE(writer.Encode(cv::Mat(8, 8, CV_8UC3, cv::Scalar(1, 2, 3)), &png));
  EXPECT_TRUE(png.empty());
  EXPECT_FALSE(writer.Encode(cv::Mat(), &png));
}

}  // namespace
}  // namespace uavm
