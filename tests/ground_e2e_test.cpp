// End to end: uavmosaic-onboard on brighton_beach_small into a temp session, then uavmosaic-ground on it; every
// product is checked on disk.
#include <gdal_priv.h>
#include <gtest/gtest.h>
#include <ogr_spatialref.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>

#include "core/sfm/colmap_io.h"
#include "core/sfm/products.h"
#include "tests/test_env.h"

namespace uavm::sfm {
namespace {

namespace fs = std::filesystem;

int RunCommand(const std::string& cmd) {
  const int status = std::system(cmd.c_str());
  return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

// Under emulation (tests/test_env.h) the ground tool works on fewer keypoints and fewer, coarser stereo pairs: the
// same stages on less work (SIFT and dense matching run ~40x slower under qemu-user).
std::string GroundEmulationArgs() {
  return test::Emulated() ? " --max-dense-pairs 10 --dense-scale 0.5 --feature-scale 0.5 --max-features 4000" : "";
}

TEST(GroundE2e, BrightonBeachSmall) {
  const fs::path tmp = fs::temp_directory_path() / ("uavm_ground_e2e_" + std::to_string(::getpid()));
  fs::remove_all(tmp);
  const fs::path session = tmp / "session", out = tmp / "ground";
  // Under emulation the first 12 frames (two strips: stereo pairs along and across them).
  const test::FlightForTest flight(fs::path(UAVM_TEST_DATA) / "brighton_beach_small/images", 12, tmp / "flight");
  const int frames = flight.frames();
  ASSERT_EQ(RunCommand(std::string(UAVM_ONBOARD_BIN) + " --source replay:" + flight.string() + " --out " +
                       session.string() + " --log-level warn --no-tiff" + test::EmulationArgsString()),
            0);
  ASSERT_EQ(
      RunCommand(std::string(UAVM_GROUND_BIN) + " " + session.string() + " --out " + out.string() +
                 " --threads 2 --render-previews" + GroundEmulationArgs() + " 2>" + (tmp / "stderr.txt").string()),
      0);
  for (const char* f : {"cloud.ply", "dsm.tif", "summary.json", "sparse/cameras.txt", "sparse/images.txt",
                        "sparse/points3D.txt", "preview_cloud.png", "preview_dsm.png"}) {
    EXPECT_TRUE(fs::exists(out / f)) << f;
  }
  std::ifstream js_in(out / "summary.json");
  const auto js = nlohmann::json::parse(js_in);
  std::printf("ground: %s\n", js["timings"].dump().c_str());
  EXPECT_EQ(js["frames_used"].get<int>(), frames);
  const double before = js["ba_rms_before_px"].get<double>(), after = js["ba_rms_after_px"].get<double>();
  EXPECT_LT(after, before);
  EXPECT_LT(after, 0.6);  // 1000x562 frames; measured 3.99 -> 0.32 px
  EXPECT_GT(js["sparse_points"].get<int>(), 1000);
  EXPECT_EQ(js["crs"].get<std::string>(), "EPSG:32615");

  // The PLY parses and holds a real cloud.
  std::vector<CloudPoint> cloud;
  std::string err;
  ASSERT_TRUE(ReadPly((out / "cloud.ply").string(), &cloud, &err)) << err;
  EXPECT_GT(cloud.size(), test::Emulated() ? 5000u : 20000u);
  EXPECT_EQ(cloud.size(), js["dense_points"].get<size_t>());

  // The COLMAP model reads back with every frame and the sparse points.
  Reconstruction rec;
  ASSERT_TRUE(ReadColmapText((out / "sparse").string(), &rec, &err)) << err;
  EXPECT_EQ(rec.images.size(), static_cast<size_t>(frames));
  EXPECT_EQ(rec.points.size(), js["sparse_points"].get<size_t>());
  EXPECT_NEAR(rec.ReprojectionRms(), after, 1e-6);

  // DSM: float32 with nodata, UTM 15N, heights of a flat beach.
  GDALAllRegister();
  GDALDataset* ds = static_cast<GDALDataset*>(GDALOpen((out / "dsm.tif").c_str(), GA_ReadOnly));
  ASSERT_NE(ds, nullptr);
  GDALRasterBand* band = ds->GetRasterBand(1);
  EXPECT_EQ(band->GetRasterDataType(), GDT_Float32);
  int has_nodata = 0;
  const double nodata = band->GetNoDataValue(&has_nodata);
  EXPECT_TRUE(has_nodata);
  const OGRSpatialReference* srs = ds->GetSpatialRef();
  ASSERT_NE(srs, nullptr);
  EXPECT_TRUE(srs->IsProjected());
  EXPECT_STREQ(srs->GetAuthorityCode(nullptr), "32615");
  double gt[6];
  ds->GetGeoTransform(gt);
  EXPECT_NEAR(gt[0], 576000.0, 5000.0);  // Brighton Beach, Duluth MN (46.84 N, 92.0 W): UTM 15N
  const int w = ds->GetRasterXSize(), h = ds->GetRasterYSize();
  std::vector<float> v(static_cast<size_t>(w) * static_cast<size_t>(h));
  ASSERT_EQ(band->RasterIO(GF_Read, 0, 0, w, h, v.data(), w, h, GDT_Float32, 0, 0), CE_None);
  GDALClose(ds);
  std::vector<float> valid;
  for (float z : v) {
    if (z != static_cast<float>(nodata)) valid.push_back(z);
  }
  ASSERT_GT(valid.size(), v.size() / 4);
  std::sort(valid.begin(), valid.end());
  const float p05 = valid[valid.size() / 20], p50 = valid[valid.size() / 2], p95 = valid[valid.size() * 19 / 20];
  // Heights relative to take-off (DJI relative altitude): a beach is a few metres below/around the take-off point and
  // gently sloping park. Measured: p05 -3.92, p50 0.14, p95 1.31 m (spread 5.2 m).
  std::printf("DSM heights p05 %.2f p50 %.2f p95 %.2f m (%zu cells)\n", p05, p50, p95, valid.size());
  EXPECT_LT(std::abs(p50), 15.0);
  EXPECT_LT(p95 - p05, 8.0);
  fs::remove_all(tmp);
}

}  // namespace
}  // namespace uavm::sfm
