#include "hal/common/metadata.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <vector>

namespace uavm::hal {
namespace {

TEST(MetadataTest, ReadsDjiGpsAndXmp) {
  const auto md = ReadMetadata(std::string(UAVM_TEST_DATA) + "/brighton_beach_small/images/DJI_0018.JPG");
  ASSERT_TRUE(md.HasGps());
  // manifest.csv of the flight: 46.8426070833333, -91.9945598888889, +39.80 m relative, gimbal yaw +45.
  EXPECT_NEAR(*md.latitude_deg, 46.8426070833333, 1e-7);
  EXPECT_NEAR(*md.longitude_deg, -91.9945598888889, 1e-7);
  ASSERT_TRUE(md.relative_altitude_m.has_value());
  EXPECT_NEAR(*md.relative_altitude_m, 39.8, 1e-6);
  ASSERT_TRUE(md.gimbal_yaw_deg.has_value());
  EXPECT_NEAR(*md.gimbal_yaw_deg, 45.0, 1e-6);
  ASSERT_TRUE(md.focal_length_mm.has_value());
  EXPECT_NEAR(*md.focal_length_mm, 3.6, 0.01);  // as written in this file's EXIF (manifest.csv: 3.6)
  EXPECT_EQ(md.make, "DJI");
}

TEST(MetadataTest, CanonExifWithoutXmp) {
  const auto md = ReadMetadata(std::string(UAVM_TEST_DATA) + "/caliterra_small/images/IMG_9354.jpg");
  ASSERT_TRUE(md.HasGps());
  EXPECT_NEAR(*md.latitude_deg, 30.1712233333333, 1e-6);
  EXPECT_LT(*md.longitude_deg, 0.0);  // West
  EXPECT_FALSE(md.relative_altitude_m.has_value());
}

TEST(MetadataTest, GarbageGivesEmptyMetadataNotAnException) {
  const auto p = std::filesystem::temp_directory_path() / "uavm_garbage_meta.jpg";
  std::ofstream(p) << "\xFF\xD8\xFF\xE1 garbage exif that ends early";
  std::string warning;
  const auto md = ReadMetadata(p.string(), &warning);
  EXPECT_FALSE(md.HasGps());
  const auto missing = ReadMetadata("/nonexistent.jpg", &warning);
  EXPECT_FALSE(missing.HasGps());
  EXPECT_FALSE(warning.empty());
}

TEST(MetadataTest, ReadsFromBytesInMemoryOnlyFrameFormats) {
  std::ifstream in(std::string(UAVM_TEST_DATA) + "/brighton_beach_small/images/DJI_0018.JPG", std::ios::binary);
  const std::vector<unsigned char> bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const auto md = ReadMetadata(bytes.data(), bytes.size());
  ASSERT_TRUE(md.HasGps());
  EXPECT_NEAR(*md.latitude_deg, 46.8426070833333, 1e-7);
  ASSERT_TRUE(md.gimbal_yaw_deg.has_value());
  EXPECT_NEAR(*md.gimbal_yaw_deg, 45.0, 1e-6);
  // Formats frames never come in are not parsed at all (an empty result, no exception).
  const std::string gif = "GIF89a\x01\x00\x01\x00";
  EXPECT_FALSE(ReadMetadata(reinterpret_cast<const unsigned char*>(gif.data()), gif.size()).HasGps());
  EXPECT_FALSE(ReadMetadata(nullptr, 0).HasGps());
}

}  // namespace
}  // namespace uavm::hal
