// The camera source syntax: v4l2:/dev/video0?width=640&height=480&format=YUYV&fps=30 (the part after the scheme).
#include "hal/common/camera_options.h"

#include <gtest/gtest.h>

namespace uavm::hal {
namespace {

TEST(CaptureOptions, DefaultsWhenNoKeys) {
  CaptureOptions o;
  std::string err;
  ASSERT_TRUE(ParseCaptureOptions("/dev/video3", &o, &err)) << err;
  EXPECT_EQ(o.device, "/dev/video3");
  EXPECT_EQ(o.width, 640);
  EXPECT_EQ(o.height, 480);
  EXPECT_EQ(o.format, PixelFormat::kYuyv);
  EXPECT_EQ(o.fps, 30);
  EXPECT_EQ(o.buffers, 6);
  EXPECT_EQ(o.queue, 2);
}

TEST(CaptureOptions, AllKeys) {
  CaptureOptions o;
  std::string err;
  ASSERT_TRUE(ParseCaptureOptions(
      "/dev/video0?width=1280&height=720&format=mjpg&fps=15&buffers=8&queue=3&reconnect_s=2.5", &o, &err))
      << err;
  EXPECT_EQ(o.device, "/dev/video0");
  EXPECT_EQ(o.width, 1280);
  EXPECT_EQ(o.height, 720);
  EXPECT_EQ(o.format, PixelFormat::kMjpeg);
  EXPECT_EQ(o.fps, 15);
  EXPECT_EQ(o.buffers, 8);
  EXPECT_EQ(o.queue, 3);
  EXPECT_DOUBLE_EQ(o.reconnect_s, 2.5);
}

TEST(CaptureOptions, LibcameraIdWithSpaces) {
  CaptureOptions o;
  std::string err;
  ASSERT_TRUE(ParseCaptureOptions("platform/vimc.0 Sensor B?format=RGB24", &o, &err)) << err;
  EXPECT_EQ(o.device, "platform/vimc.0 Sensor B");
  EXPECT_EQ(o.format, PixelFormat::kRgb24);
}

TEST(CaptureOptions, Errors) {
  const char* bad[] = {
      "/dev/video0?width=abc",          // not a number
      "/dev/video0?width=641",          // odd
      "/dev/video0?height=8",           // too small
      "/dev/video0?format=H264",        // unsupported format
      "/dev/video0?colour=red",         // unknown key
      "/dev/video0?width",              // no value
      "/dev/video0?buffers=4&queue=4",  // the driver would have no buffer left to fill
      "/dev/video0?fps=-1",
      "/dev/video0?reconnect_s=-3",
      "?width=640",  // no device
      "/dev/video0?width=640x",
  };
  for (const char* spec : bad) {
    CaptureOptions o;
    std::string err;
    EXPECT_FALSE(ParseCaptureOptions(spec, &o, &err)) << spec;
    EXPECT_FALSE(err.empty()) << spec;
  }
}

TEST(CaptureOptions, CheckOnDefaults) {
  CaptureOptions o;
  std::string err;
  EXPECT_FALSE(o.Check(&err));  // no device
  o.device = "/dev/video0";
  EXPECT_TRUE(o.Check(&err)) << err;
}

}  // namespace
}  // namespace uavm::hal
