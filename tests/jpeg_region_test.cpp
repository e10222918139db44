#include "core/imageio/jpeg_region.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

namespace uavm {
namespace {

const std::string kFrame = std::string(UAVM_TEST_DATA) + "/caliterra_small/images/IMG_9360.jpg";

int ReducedFlag(unsigned denom) {
  switch (denom) {
    case 2:
      return cv::IMREAD_REDUCED_COLOR_2;
    case 4:
      return cv::IMREAD_REDUCED_COLOR_4;
    case 8:
      return cv::IMREAD_REDUCED_COLOR_8;
    default:
      return cv::IMREAD_COLOR;
  }
}

std::filesystem::path TempFile(const std::string& name) {
  return std::filesystem::temp_directory_path() / ("uavm_jpeg_region_" + std::to_string(::getpid()) + "_" + name);
}

// Largest per-channel difference between the decoded part and the same rectangle of OpenCV's whole decode (OpenCV
// reads JPEG through the system libjpeg with the same DCT scaling: an independent path to the same pixels).
double MaxDiffToWholeDecode(const std::string& path, unsigned denom, const cv::Rect& region) {
  const cv::Mat whole = cv::imread(path, ReducedFlag(denom) | cv::IMREAD_IGNORE_ORIENTATION);
  JpegRegion part;
  std::string why;
  EXPECT_TRUE(DecodeJpegRegion(path, denom, region, &part, &why)) << why;
  EXPECT_FALSE(part.corrupt);
  EXPECT_EQ(part.scaled_size, whole.size());
  const cv::Rect clipped = region & cv::Rect(cv::Point(), whole.size());
  const cv::Rect in_part = clipped - part.origin;
  EXPECT_EQ((in_part & cv::Rect(cv::Point(), part.bgr.size())), in_part) << "the part must cover the region";
  // The part is widened to MCU columns only: at most one 16-px iMCU on each side, never more rows than asked.
  EXPECT_LE(part.bgr.cols, clipped.width + 32);
  EXPECT_EQ(part.bgr.rows, clipped.height);
  if ((in_part & cv::Rect(cv::Point(), part.bgr.size())) != in_part) return 1e9;
  cv::Mat diff;
  cv::absdiff(part.bgr(in_part), whole(clipped), diff);
  double max_diff = 0;
  cv::minMaxLoc(diff.reshape(1), nullptr, &max_diff);
  return max_diff;
}

TEST(JpegRegionTest, PartsEqualTheWholeDecodeAtEveryScale) {
  for (unsigned denom : {1u, 2u, 4u, 8u}) {
    const cv::Size s((1000 + denom - 1) / denom, (750 + denom - 1) / denom);
    for (const cv::Rect& r :
         {cv::Rect(0, 0, s.width, s.height), cv::Rect(s.width / 7, s.height / 9, s.width / 3, s.height / 4),
          cv::Rect(s.width - 5, s.height - 3, 5, 3), cv::Rect(1, 1, 1, 1),
          cv::Rect(s.width / 2 + 3, 17 / static_cast<int>(denom), s.width, s.height)})
      EXPECT_EQ(MaxDiffToWholeDecode(kFrame, denom, r), 0.0) << "denom " << denom << " region " << r;
  }
}

TEST(JpegRegionTest, ProgressiveAndGreyFilesToo) {
  const cv::Mat frame = cv::imread(kFrame);
  ASSERT_FALSE(frame.empty());
  const auto progressive = TempFile("progressive.jpg");
  ASSERT_TRUE(cv::imwrite(progressive.string(), frame, {cv::IMWRITE_JPEG_PROGRESSIVE, 1}));
  EXPECT_EQ(MaxDiffToWholeDecode(progressive.string(), 2, cv::Rect(100, 60, 200, 90)), 0.0);
  cv::Mat grey;
  cv::cvtColor(frame, grey, cv::COLOR_BGR2GRAY);
  const auto grey_path = TempFile("grey.jpg");
  ASSERT_TRUE(cv::imwrite(grey_path.string(), grey));
  EXPECT_EQ(MaxDiffToWholeDecode(grey_path.string(), 1, cv::Rect(333, 222, 111, 99)), 0.0);
  std::filesystem::remove(progressive);
  std::filesystem::remove(grey_path);
}

TEST(JpegRegionTest, BadInputGivesAReasonNotACrash) {
  JpegRegion part;
  std::string why;
  EXPECT_FALSE(DecodeJpegRegion(TempFile("missing.jpg").string(), 1, cv::Rect(0, 0, 10, 10), &part, &why));
  EXPECT_NE(why.find("cannot open"), std::string::npos) << why;
  EXPECT_FALSE(DecodeJpegRegion(kFrame, 1, cv::Rect(2000, 0, 10, 10), &part, &why));
  EXPECT_NE(why.find("outside"), std::string::npos) << why;
  EXPECT_TRUE(part.bgr.empty());
  // Not a JPEG at all: libjpeg's fatal error comes back as a message.
  const auto text = TempFile("text.jpg");
  std::ofstream(text) << "not a jpeg";
  EXPECT_FALSE(DecodeJpegRegion(text.string(), 1, cv::Rect(0, 0, 10, 10), &part, &why));
  EXPECT_NE(why.find("corrupt JPEG data"), std::string::npos) << why;
  // Cut short: rows past the end are libjpeg's grey fill, reported as corrupt; rows before it decode.
  std::ifstream in(kFrame, std::ios::binary);
  std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const auto truncated = TempFile("truncated.jpg");
  std::ofstream(truncated, std::ios::binary) << bytes.substr(0, bytes.size() / 2);
  ASSERT_TRUE(DecodeJpegRegion(truncated.string(), 1, cv::Rect(0, 700, 100, 50), &part, &why)) << why;
  EXPECT_TRUE(part.corrupt);
  ASSERT_TRUE(DecodeJpegRegion(truncated.string(), 1, cv::Rect(0, 0, 100, 50), &part, &why)) << why;
  EXPECT_FALSE(part.corrupt);
  std::filesystem::remove(text);
  std::filesystem::remove(truncated);
}

}  // namespace
}  // namespace uavm
