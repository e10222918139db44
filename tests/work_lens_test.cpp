#include "core/pipeline/work_lens.h"

#include <gtest/gtest.h>

#include "core/lens/lens_database.h"

namespace uavm {
namespace {

// The database is parsed ahead only when the first frame will look its camera up; the lookup's answer is the same
// after the preload as without it (the parse happens once, whoever gets there first).
TEST(WorkLensTest, TheDatabaseIsPreloadedOnlyForALookupAndAnswersTheSame) {
  CameraOptions off;
  off.database = false;
  EXPECT_FALSE(PreloadLensDatabase(off).joinable());
  CameraOptions configured;
  configured.k1 = -0.1;
  EXPECT_FALSE(PreloadLensDatabase(configured).joinable());
  {
    const std::jthread preload = PreloadLensDatabase(CameraOptions{});
    EXPECT_TRUE(preload.joinable());
  }  // joined here
  if (!LensDatabaseAvailable()) GTEST_SKIP() << "built without lensfun";
  FrameMetadata md;
  md.make = "Canon";
  md.model = "Canon PowerShot SX260 HS";
  md.focal_length_mm = 4.5;
  Frame frame;
  frame.metadata = md;
  frame.original_size = cv::Size(4000, 3000);
  const WorkLens lens{CameraOptions{}};
  (void)lens.For(frame, cv::Size(1000, 750));
  ASSERT_TRUE(lens.chosen());
  EXPECT_EQ(lens.choice().focal_from, "exif_crop_factor");  // the crop factor came from the database
}

}  // namespace
}  // namespace uavm
