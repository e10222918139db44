// Pixel-format conversion to BGR against known values (BT.601 limited range), and damaged buffers.
#include "hal/common/pixel_convert.h"

#include <gtest/gtest.h>

#include <opencv2/imgcodecs.hpp>
#include <vector>

namespace uavm::hal {
namespace {

// BT.601 limited-range codes of reference colours, and their BGR values.
struct Ycc {
  uint8_t y, cb, cr;
  cv::Vec3b bgr;
};
const Ycc kWhite{235, 128, 128, {255, 255, 255}};
const Ycc kBlack{16, 128, 128, {0, 0, 0}};
const Ycc kRed{81, 90, 240, {0, 0, 255}};
const Ycc kGreen{145, 54, 34, {0, 255, 0}};
const Ycc kBlue{41, 240, 110, {255, 0, 0}};
const Ycc kGrey{126, 128, 128, {128, 128, 128}};  // 16 + 219 * 128/255 = 125.9

void ExpectNear(const cv::Vec3b& got, const cv::Vec3b& want, int tol, const std::string& what) {
  for (int c = 0; c < 3; ++c) EXPECT_NEAR(got[c], want[c], tol) << what << " channel " << c;
}

// A 4x2 image: left half colour a, right half colour b, as YUYV.
std::vector<uint8_t> Yuyv(const Ycc& a, const Ycc& b, int stride) {
  std::vector<uint8_t> buf(static_cast<size_t>(stride) * 2, 0xEE);
  for (int row = 0; row < 2; ++row) {
    uint8_t* p = buf.data() + row * stride;
    const uint8_t q[8] = {a.y, a.cb, a.y, a.cr, b.y, b.cb, b.y, b.cr};
    std::copy(q, q + 8, p);
  }
  return buf;
}

TEST(PixelConvert, YuyvKnownColours) {
  const std::pair<Ycc, Ycc> pairs[] = {{kWhite, kBlack}, {kRed, kGreen}, {kBlue, kGrey}};
  for (const auto& [a, b] : pairs) {
    const auto buf = Yuyv(a, b, 8);
    RawImage raw{buf.data(), buf.size(), 4, 2, 8, PixelFormat::kYuyv};
    cv::Mat out;
    std::string err;
    ASSERT_EQ(ConvertToBgr(raw, &out, &err), Status::kOk) << err;
    ASSERT_EQ(out.type(), CV_8UC3);
    ASSERT_EQ(out.size(), cv::Size(4, 2));
    ExpectNear(out.at<cv::Vec3b>(1, 0), a.bgr, 3, "left");
    ExpectNear(out.at<cv::Vec3b>(0, 3), b.bgr, 3, "right");
  }
}

TEST(PixelConvert, YuyvHonoursStride) {
  const auto buf = Yuyv(kRed, kBlue, 12);  // 4 bytes of padding per row
  RawImage raw{buf.data(), buf.size(), 4, 2, 12, PixelFormat::kYuyv};
  cv::Mat out;
  std::string err;
  ASSERT_EQ(ConvertToBgr(raw, &out, &err), Status::kOk) << err;
  ExpectNear(out.at<cv::Vec3b>(1, 1), kRed.bgr, 3, "row 1");
  ExpectNear(out.at<cv::Vec3b>(1, 2), kBlue.bgr, 3, "row 1");
}

TEST(PixelConvert, Nv12KnownColours) {
  // 4x4: quadrants of four colours (one chroma sample per 2x2 block).
  const Ycc q[2][2] = {{kWhite, kRed}, {kGreen, kBlue}};
  const int stride = 6;
  std::vector<uint8_t> buf(static_cast<size_t>(stride) * 6, 0);
  for (int y = 0; y < 4; ++y)
    for (int x = 0; x < 4; ++x) buf[y * stride + x] = q[y / 2][x / 2].y;
  for (int by = 0; by < 2; ++by)
    for (int bx = 0; bx < 2; ++bx) {
      buf[(4 + by) * stride + bx * 2] = q[by][bx].cb;
      buf[(4 + by) * stride + bx * 2 + 1] = q[by][bx].cr;
    }
  RawImage raw{buf.data(), buf.size(), 4, 4, stride, PixelFormat::kNv12};
  cv::Mat out;
  std::string err;
  ASSERT_EQ(ConvertToBgr(raw, &out, &err), Status::kOk) << err;
  ExpectNear(out.at<cv::Vec3b>(0, 0), kWhite.bgr, 3, "white");
  ExpectNear(out.at<cv::Vec3b>(1, 3), kRed.bgr, 3, "red");
  ExpectNear(out.at<cv::Vec3b>(3, 0), kGreen.bgr, 3, "green");
  ExpectNear(out.at<cv::Vec3b>(2, 2), kBlue.bgr, 3, "blue");
}

TEST(PixelConvert, Rgb24AndBgr24ByteOrder) {
  const uint8_t rgb[6] = {250, 10, 20, 1, 2, 3};
  cv::Mat out;
  std::string err;
  ASSERT_EQ(ConvertToBgr({rgb, 6, 2, 1, 0, PixelFormat::kRgb24}, &out, &err), Status::kOk);
  EXPECT_EQ(out.at<cv::Vec3b>(0, 0), cv::Vec3b(20, 10, 250));
  ASSERT_EQ(ConvertToBgr({rgb, 6, 2, 1, 0, PixelFormat::kBgr24}, &out, &err), Status::kOk);
  EXPECT_EQ(out.at<cv::Vec3b>(0, 1), cv::Vec3b(1, 2, 3));
}

TEST(PixelConvert, MjpegDecodesToTheNegotiatedSize) {
  cv::Mat img(48, 64, CV_8UC3, cv::Scalar(0, 0, 0));
  img(cv::Rect(0, 0, 32, 48)).setTo(cv::Scalar(255, 0, 0));   // blue left
  img(cv::Rect(32, 0, 32, 48)).setTo(cv::Scalar(0, 255, 0));  // green right
  std::vector<uchar> jpeg;
  ASSERT_TRUE(cv::imencode(".jpg", img, jpeg, {cv::IMWRITE_JPEG_QUALITY, 95}));
  cv::Mat out;
  std::string err;
  ASSERT_EQ(ConvertToBgr({jpeg.data(), jpeg.size(), 64, 48, 0, PixelFormat::kMjpeg}, &out, &err), Status::kOk) << err;
  ExpectNear(out.at<cv::Vec3b>(24, 8), {255, 0, 0}, 6, "blue");
  ExpectNear(out.at<cv::Vec3b>(24, 56), {0, 255, 0}, 6, "green");
  // Another size than negotiated, a truncated stream and garbage are skipped with a reason, never a crash.
  EXPECT_EQ(ConvertToBgr({jpeg.data(), jpeg.size(), 640, 480, 0, PixelFormat::kMjpeg}, &out, &err), Status::kSkipped);
  EXPECT_NE(err.find("negotiated"), std::string::npos) << err;
  const std::vector<uint8_t> garbage(100, 0x42);
  EXPECT_EQ(ConvertToBgr({garbage.data(), garbage.size(), 64, 48, 0, PixelFormat::kMjpeg}, &out, &err),
            Status::kSkipped);
  EXPECT_EQ(ConvertToBgr({jpeg.data(), 20, 64, 48, 0, PixelFormat::kMjpeg}, &out, &err), Status::kSkipped);
}

TEST(PixelConvert, ShortBuffersAreSkipped) {
  const std::vector<uint8_t> buf(100, 128);
  cv::Mat out;
  std::string err;
  EXPECT_EQ(ConvertToBgr({buf.data(), buf.size(), 640, 480, 0, PixelFormat::kYuyv}, &out, &err), Status::kSkipped);
  EXPECT_NE(err.find("needed"), std::string::npos) << err;
  EXPECT_EQ(ConvertToBgr({buf.data(), buf.size(), 640, 480, 0, PixelFormat::kNv12}, &out, &err), Status::kSkipped);
  EXPECT_EQ(ConvertToBgr({buf.data(), buf.size(), 640, 480, 0, PixelFormat::kRgb24}, &out, &err), Status::kSkipped);
  EXPECT_EQ(ConvertToBgr({nullptr, 0, 640, 480, 0, PixelFormat::kYuyv}, &out, &err), Status::kSkipped);
  // Exactly large enough is fine (no off-by-one: a 4x2 YUYV frame is 16 bytes).
  EXPECT_EQ(ConvertToBgr({buf.data(), 16, 4, 2, 0, PixelFormat::kYuyv}, &out, &err), Status::kOk);
  EXPECT_EQ(ConvertToBgr({buf.data(), 15, 4, 2, 0, PixelFormat::kYuyv}, &out, &err), Status::kSkipped);
}

TEST(PixelConvert, FormatNames) {
  PixelFormat f;
  ASSERT_TRUE(ParsePixelFormat("mjpg", &f));
  EXPECT_EQ(f, PixelFormat::kMjpeg);
  ASSERT_TRUE(ParsePixelFormat("nv12", &f));
  EXPECT_STREQ(ToString(f), "NV12");
  EXPECT_FALSE(ParsePixelFormat("H264", &f));
}

}  // namespace
}  // namespace uavm::hal
