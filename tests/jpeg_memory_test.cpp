#include "core/imageio/jpeg_memory.h"

#include <gtest/gtest.h>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

namespace uavm {
namespace {

// A real frame's part (texture, edges, colour), not a synthetic gradient: the coder's work is what it would see.
cv::Mat FramePart() {
  const cv::Mat frame =
      cv::imread(std::string(UAVM_TEST_DATA) + "/caliterra_small/images/IMG_9360.jpg", cv::IMREAD_COLOR);
  EXPECT_FALSE(frame.empty());
  return frame(cv::Rect(101, 37, 517, 389)).clone();  // odd sizes: partial MCUs at both edges
}

double MaxDiff(const cv::Mat& a, const cv::Mat& b) {
  if (a.size() != b.size() || a.type() != b.type()) return 1e9;
  double diff = 0;
  cv::Mat d;
  cv::absdiff(a, b, d);
  cv::minMaxLoc(d.reshape(1), nullptr, &diff);
  return diff;
}

// OpenCV's codec (the same libjpeg through its own calls, with a red/blue swap of its own) is the independent
// reference: our copy decodes to the same pixels whichever side decodes it, and as OpenCV's own copy at that quality.
TEST(JpegMemoryTest, RoundTripMatchesOpenCvsCodec) {
  const cv::Mat part = FramePart();
  std::vector<uchar> ours;
  std::string why;
  ASSERT_TRUE(EncodeJpegBgr(part, 95, &ours, &why)) << why;
  EXPECT_LT(ours.size(), part.total() * part.elemSize() / 3);  // a copy worth keeping
  cv::Mat decoded;
  ASSERT_TRUE(DecodeJpegBgr(ours, &decoded, &why)) << why;
  const cv::Mat by_opencv = cv::imdecode(ours, cv::IMREAD_COLOR);
  EXPECT_EQ(MaxDiff(decoded, by_opencv), 0.0);
  std::vector<uchar> theirs;
  ASSERT_TRUE(cv::imencode(".jpg", part, theirs, {cv::IMWRITE_JPEG_QUALITY, 95}));
  cv::Mat theirs_decoded;
  ASSERT_TRUE(DecodeJpegBgr(theirs, &theirs_decoded, &why)) << why;
  EXPECT_EQ(MaxDiff(theirs_decoded, cv::imdecode(theirs, cv::IMREAD_COLOR)), 0.0);
  EXPECT_EQ(MaxDiff(decoded, theirs_decoded), 0.0);
  // And close to the original: quality 95 moves a grey level or a few, not more.
  cv::Mat err;
  cv::absdiff(decoded, part, err);
  EXPECT_LT(cv::mean(err.reshape(1))[0], 2.0);
}

// A part larger than the destination's first guess (noise compresses poorly): the vector grows as libjpeg writes.
TEST(JpegMemoryTest, TheCopyGrowsAsLibjpegWrites) {
  cv::Mat noise(601, 803, CV_8UC3);
  cv::RNG(5).fill(noise, cv::RNG::UNIFORM, 0, 256);
  std::vector<uchar> jpeg(17, 1);  // whatever it held is replaced
  std::string why;
  ASSERT_TRUE(EncodeJpegBgr(noise, 95, &jpeg, &why)) << why;
  EXPECT_GT(jpeg.size(), 2 * noise.total() / 4);  // at least one growth beyond the first guess (pixels / 4 bytes)
  EXPECT_EQ(MaxDiff(cv::imdecode(jpeg, cv::IMREAD_COLOR),
                    [&] {
                      cv::Mat m;
                      EXPECT_TRUE(DecodeJpegBgr(jpeg, &m, &why));
                      return m;
                    }()),
            0.0);
}

TEST(JpegMemoryTest, DamagedOrForeignDataIsRefusedWithAReason) {
  std::vector<uchar> jpeg;
  std::string why;
  ASSERT_TRUE(EncodeJpegBgr(FramePart(), 95, &jpeg, &why)) << why;
  cv::Mat out;
  std::vector<uchar> cut(jpeg.begin(), jpeg.begin() + static_cast<long>(jpeg.size() / 2));
  EXPECT_FALSE(DecodeJpegBgr(cut, &out, &why));
  EXPECT_FALSE(why.empty());
  EXPECT_TRUE(out.empty());
  why.clear();
  EXPECT_FALSE(DecodeJpegBgr({}, &out, &why));
  EXPECT_FALSE(why.empty());
  const std::vector<uchar> foreign = {'P', 'N', 'G', 0, 1, 2, 3};
  why.clear();
  EXPECT_FALSE(DecodeJpegBgr(foreign, &out, &why));
  EXPECT_FALSE(why.empty());
  EXPECT_FALSE(EncodeJpegBgr(cv::Mat(4, 4, CV_16UC3), 95, &jpeg, &why));
  EXPECT_FALSE(EncodeJpegBgr(cv::Mat(), 95, &jpeg, &why));
}

// A grey camera's frame: encoded grey, read back as BGR with three equal channels, as OpenCV reads it.
TEST(JpegMemoryTest, GreyFramesAreEncodedGrey) {
  cv::Mat grey;
  cv::cvtColor(FramePart(), grey, cv::COLOR_BGR2GRAY);
  std::vector<uchar> jpeg;
  std::string why;
  ASSERT_TRUE(EncodeJpegBgr(grey, 95, &jpeg, &why)) << why;
  cv::Mat decoded;
  ASSERT_TRUE(DecodeJpegBgr(jpeg, &decoded, &why)) << why;
  EXPECT_EQ(MaxDiff(decoded, cv::imdecode(jpeg, cv::IMREAD_COLOR)), 0.0);
  std::vector<cv::Mat> channels;
  cv::split(decoded, channels);
  EXPECT_EQ(cv::countNonZero(channels[0] != channels[2]), 0);
  cv::Mat err;
  cv::absdiff(channels[1], grey, err);
  EXPECT_LT(cv::mean(err)[0], 2.0);
}

}  // namespace
}  // namespace uavm
