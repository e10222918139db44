// The libdeflate PNG encoder of the web tiles, read back by an independent decoder (OpenCV's, libpng): every pixel
// and the alpha come back exactly, at any size; a wrong input type is refused.
#include "core/imageio/png_writer.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <filesystem>
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

std::string TempPng(const char* name) {
  return (std::filesystem::temp_directory_path() /
          ("uavm_png_" + std::to_string(::getpid()) + "_" + std::string(name) + ".png"))
      .string();
}

// The row writer (zlib, streamed) against the same independent decoder: every pixel back, from one pixel to rows
// longer than the compressor's 64 KiB output buffer (20000 px: 80 KB a row), over several IDAT chunks.
TEST(PngRowWriterTest, LibpngReadsBackEveryRowWritten) {
  const std::string path = TempPng("rows");
  for (const cv::Size size :
       {cv::Size(1, 1), cv::Size(257, 3), cv::Size(3, 300), cv::Size(2000, 90), cv::Size(20000, 3)}) {
    const cv::Mat bgra = RandomBgra(size, static_cast<uint32_t>(size.area()));
    PngRowWriter writer(1);
    std::string error;
    ASSERT_TRUE(writer.Open(path, size.width, size.height, &error)) << error;
    for (int y = 0; y < size.height; ++y) ASSERT_TRUE(writer.WriteRow(bgra.ptr(y), &error)) << error;
    ASSERT_TRUE(writer.Finish(&error)) << error;
    const cv::Mat back = cv::imread(path, cv::IMREAD_UNCHANGED);
    ASSERT_EQ(back.type(), CV_8UC4);
    ASSERT_EQ(back.size(), size);
    EXPECT_EQ(cv::norm(back, bgra, cv::NORM_INF), 0.0) << size;
  }
  std::filesystem::remove(path);
}

// A file cut short is an error, never a PNG that looks whole: missing rows fail Finish, an extra row fails WriteRow
// and then Finish, and a directory that cannot be written fails Open with its path named.
TEST(PngRowWriterTest, RefusesMissingRowsExtraRowsAndUnwritablePaths) {
  const std::string path = TempPng("short");
  const cv::Mat bgra = RandomBgra({16, 4}, 7);
  std::string error;
  {
    PngRowWriter writer;
    ASSERT_TRUE(writer.Open(path, 16, 4, &error));
    for (int y = 0; y < 3; ++y) ASSERT_TRUE(writer.WriteRow(bgra.ptr(y), &error));
    EXPECT_FALSE(writer.Finish(&error));
    EXPECT_NE(error.find("3 of 4 rows"), std::string::npos) << error;
  }
  {
    PngRowWriter writer;
    ASSERT_TRUE(writer.Open(path, 16, 1, &error));
    ASSERT_TRUE(writer.WriteRow(bgra.ptr(0), &error));
    EXPECT_FALSE(writer.WriteRow(bgra.ptr(1), &error));
    EXPECT_FALSE(writer.Finish(&error)) << "a writer that refused a call stays failed";
    EXPECT_NE(error.find("a row beyond"), std::string::npos) << error;
  }
  PngRowWriter writer;
  const std::string nowhere = "/nonexistent_dir_uavm/q.png";
  EXPECT_FALSE(writer.Open(nowhere, 16, 4, &error));
  EXPECT_NE(error.find(nowhere), std::string::npos) << error;
  EXPECT_FALSE(writer.Finish(&error));
  EXPECT_NE(error.find(nowhere), std::string::npos) << "the first failure's reason is kept: " << error;
  std::filesystem::remove(path);
}

// A full disk (/dev/full: every write fails with ENOSPC) is an error that says so, at the latest when the file is
// finished, whatever the buffering; never a success.
TEST(PngRowWriterTest, AFullDiskFailsWithItsReason) {
  if (!std::filesystem::exists("/dev/full")) GTEST_SKIP() << "no /dev/full";
  const cv::Mat bgra = RandomBgra({300, 200}, 11);
  PngRowWriter writer;
  std::string error;
  bool ok = writer.Open("/dev/full", bgra.cols, bgra.rows, &error);
  for (int y = 0; ok && y < bgra.rows; ++y) ok = writer.WriteRow(bgra.ptr(y), &error);
  EXPECT_FALSE(writer.Finish(&error));
  EXPECT_NE(error.find(std::strerror(ENOSPC)), std::string::npos) << error;
}

}  // namespace
}  // namespace uavm
