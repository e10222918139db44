// core/frame/frame.h on its own (uavm_core_frame: OpenCV core, nothing from hal), and hal's names for the same types.
#include "core/frame/frame.h"

#include <gtest/gtest.h>

#include <type_traits>

#include "hal/common/frame_source.h"

namespace uavm {
namespace {

static_assert(std::is_same_v<hal::Frame, Frame>);
static_assert(std::is_same_v<hal::FrameMetadata, FrameMetadata>);
static_assert(std::is_same_v<hal::CaptureCounters, CaptureCounters>);

TEST(FrameTest, DefaultsAndGps) {
  Frame f;
  EXPECT_EQ(f.index, 0u);
  EXPECT_EQ(f.decode_scale, 1.0);
  EXPECT_TRUE(f.image.empty());
  EXPECT_FALSE(f.metadata.HasGps());
  f.metadata.latitude_deg = 47.0;
  EXPECT_FALSE(f.metadata.HasGps());
  f.metadata.longitude_deg = 8.0;
  EXPECT_TRUE(f.metadata.HasGps());
  const CaptureCounters c;
  EXPECT_EQ(c.captured + c.dropped + c.driver_gaps + c.reconnects, 0u);
}

}  // namespace
}  // namespace uavm
