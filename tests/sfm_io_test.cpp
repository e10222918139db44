// COLMAP text export/import round trip, the binary PLY bytes, the DSM GeoTIFF and the UTM projection.
#include <gdal_priv.h>
#include <gtest/gtest.h>
#include <ogr_spatialref.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <sstream>

#include "core/georef/georef.h"
#include "core/sfm/cloud_and_dsm.h"
#include "core/sfm/colmap_io.h"
#include "core/sfm/session_import.h"
#include "core/sfm/session_radiometry.h"
#include "sfm_synthetic.h"

namespace uavm::sfm {
namespace {

namespace fs = std::filesystem;

fs::path TempDir(const std::string& name) {
  const fs::path p = fs::temp_directory_path() / ("uavm_sfm_" + name + "_" + std::to_string(::getpid()));
  fs::remove_all(p);
  fs::create_directories(p);
  return p;
}

TEST(SfmIo, ColmapRoundTrip) {
  Reconstruction rec = testing::MakeScene(0.1, 4, 200);
  for (size_t k = 0; k < rec.points.size(); ++k) {
    rec.points[k].bgr = cv::Vec3b(static_cast<uchar>(k), 20, 200);
    rec.points[k].error_px = 0.25;
  }
  const fs::path dir = TempDir("colmap");
  std::string err;
  ASSERT_TRUE(WriteColmapText(rec, dir.string(), &err)) << err;
  // COLMAP 3.8 layout: the camera line with the OPENCV model and the 0.5 px pixel-centre shift.
  std::ifstream cams(dir / "cameras.txt");
  std::string line;
  while (std::getline(cams, line) && line[0] == '#') {
  }
  std::istringstream s(line);
  std::string id, model;
  int w, h;
  double fx, fy, cx, cy;
  s >> id >> model >> w >> h >> fx >> fy >> cx >> cy;
  EXPECT_EQ(model, "OPENCV");
  EXPECT_EQ(w, 1600);
  EXPECT_NEAR(cx, rec.cameras[0].cx + 0.5, 1e-9);

  Reconstruction back;
  ASSERT_TRUE(ReadColmapText(dir.string(), &back, &err)) << err;
  EXPECT_NEAR(back.cameras[0].fx, rec.cameras[0].fx, 1e-9);
  EXPECT_NEAR(back.cameras[0].cy, rec.cameras[0].cy, 1e-9);
  EXPECT_NEAR(back.cameras[0].k1, rec.cameras[0].k1, 1e-12);
  EXPECT_NEAR(back.cameras[0].p2, rec.cameras[0].p2, 1e-12);
  ASSERT_EQ(back.images.size(), rec.images.size());
  for (size_t i = 0; i < rec.images.size(); ++i) {
    EXPECT_EQ(back.images[i].name, rec.images[i].name);
    EXPECT_LT((back.images[i].pose.R - rec.images[i].pose.R).norm(), 1e-12);
    EXPECT_LT((back.images[i].pose.c - rec.images[i].pose.c).norm(), 1e-9);
    ASSERT_EQ(back.images[i].keypoints.size(), rec.images[i].keypoints.size());
    for (size_t k = 0; k < rec.images[i].keypoints.size(); ++k) {
      EXPECT_LT((back.images[i].keypoints[k] - rec.images[i].keypoints[k]).norm(), 1e-9);
    }
  }
  ASSERT_EQ(back.points.size(), rec.points.size());
  for (size_t k = 0; k < rec.points.size(); ++k) {
    EXPECT_LT((back.points[k].X - rec.points[k].X).norm(), 1e-9);
    EXPECT_EQ(back.points[k].track, rec.points[k].track);
    EXPECT_EQ(back.points[k].bgr, rec.points[k].bgr);
  }
  // Reprojection is unchanged by the round trip.
  EXPECT_NEAR(back.ReprojectionRms(), rec.ReprojectionRms(), 1e-9);
  // FULL_OPENCV when k3 is used.
  rec.cameras[0].k3 = 0.01;
  ASSERT_TRUE(WriteColmapText(rec, dir.string(), &err));
  ASSERT_TRUE(ReadColmapText(dir.string(), &back, &err)) << err;
  EXPECT_NEAR(back.cameras[0].k3, 0.01, 1e-15);
  fs::remove_all(dir);
}

// Two cameras (two image sizes in one flight): both written, and every image read back with its own.
TEST(SfmIo, ColmapRoundTripOfTwoCameras) {
  const Reconstruction rec = testing::MakeScene(0.1, 4, 200, /*two_cameras=*/true);
  const fs::path dir = TempDir("colmap2");
  std::string err;
  ASSERT_TRUE(WriteColmapText(rec, dir.string(), &err)) << err;
  Reconstruction back;
  ASSERT_TRUE(ReadColmapText(dir.string(), &back, &err)) << err;
  ASSERT_EQ(back.cameras.size(), 2u);
  for (size_t k = 0; k < 2; ++k) {
    EXPECT_EQ(back.cameras[k].width, rec.cameras[k].width);
    EXPECT_NEAR(back.cameras[k].fx, rec.cameras[k].fx, 1e-9);
    EXPECT_NEAR(back.cameras[k].k1, rec.cameras[k].k1, 1e-12);
  }
  ASSERT_EQ(back.images.size(), rec.images.size());
  for (size_t i = 0; i < rec.images.size(); ++i) EXPECT_EQ(back.images[i].camera, rec.images[i].camera) << i;
  EXPECT_NEAR(back.ReprojectionRms(), rec.ReprojectionRms(), 1e-9);
  EXPECT_LT(rec.ReprojectionRms(), 0.2);  // each image projected through its own camera (the noise is 0.1 px)
  // A camera id no camera line has is refused.
  std::ofstream(dir / "cameras.txt") << "1 PINHOLE 1600 1200 1400 1400 800 600\n";
  EXPECT_FALSE(ReadColmapText(dir.string(), &back, &err));
  EXPECT_NE(err.find("unknown camera id"), std::string::npos) << err;
  fs::remove_all(dir);
}

// The onboard session's camera.yaml reaches the ground tool (the start of its distortion); a session without one has
// no lens, and a damaged one is an error that names the file.
TEST(SfmIo, SessionCameraYaml) {
  const fs::path dir = TempDir("session_lens");
  std::ofstream(dir / "frames.csv")
      << "index,filename,stored_file,width,height,registered\n0,a.jpg,000000_a.jpg,64,48,1\n";
  std::ofstream(dir / "graph.csv") << "src,tgt,src_file,tgt_file,matches,inliers,used\n";
  Session s;
  std::string err;
  ASSERT_TRUE(ReadSession(dir.string(), &s, &err)) << err;
  EXPECT_FALSE(s.lens.has_value());
  std::ofstream(dir / "camera.yaml") << "camera:\n  width: 64\n  height: 48\n  focal_px: 50\n  cx: 31.5\n  cy: 23.5\n"
                                        "  k1: -0.12\n  k2: 0.01\n  p1: 0\n  p2: 0\nsource: self-calibrated\n";
  ASSERT_TRUE(ReadSession(dir.string(), &s, &err)) << err;
  ASSERT_TRUE(s.lens.has_value());
  EXPECT_DOUBLE_EQ(s.lens->focal_px, 50.0);
  EXPECT_DOUBLE_EQ(s.lens->k1, -0.12);
  EXPECT_DOUBLE_EQ(s.lens->k2, 0.01);
  EXPECT_EQ(s.lens->source, "self-calibrated");
  std::ofstream(dir / "camera.yaml") << "camera: [1, 2\n";
  EXPECT_FALSE(ReadSession(dir.string(), &s, &err));
  EXPECT_NE(err.find("camera.yaml"), std::string::npos) << err;
  fs::remove_all(dir);
}

// The onboard radiometry read back for the orthophoto: each frame's gains from radiometry.csv and the shading from
// report.json; the correction divides them out of the frame (here a uniform grey, no shading: the gains alone). A
// session without it, or with a damaged table, gives no correction and says why.
TEST(SfmIo, SessionRadiometryDividesTheOnboardGainsOut) {
  const fs::path dir = TempDir("session_radiometry");
  Reconstruction rec;
  Image im;
  im.frame_index = 3;
  rec.images.push_back(im);
  std::string why;
  EXPECT_FALSE(SessionRadiometryCorrection(dir.string(), rec, &why));
  EXPECT_NE(why.find("report.json"), std::string::npos) << why;
  std::ofstream(dir / "report.json")
      << R"({"radiometry": {"corrected": true, "vignetting": true, "log_falloff_c1_c2_bgr": [[-0.2, 0.01], [-0.3, 0.02],
             [-0.4, 0.03]], "flat_field": false, "hotspot": {"found": true, "antisolar_half_diagonals": [0.1, -0.2],
             "log_weights": [0.05, 0.02, 0.01]}}})";
  std::ofstream(dir / "radiometry.csv") << "frame,name,gain_b,gain_g,gain_r\n3,a.jpg,2.00000,1.00000,0.50000\n";
  RadiometryModel model;
  ASSERT_TRUE(ReadSessionRadiometry(dir.string(), &model, &why)) << why;
  EXPECT_TRUE(model.ok);
  EXPECT_DOUBLE_EQ(model.log_falloff[1][0], -0.3);
  EXPECT_DOUBLE_EQ(model.log_falloff[2][1], 0.03);
  EXPECT_TRUE(model.hotspot.found);
  EXPECT_DOUBLE_EQ(model.hotspot.antisolar_v, -0.2);
  EXPECT_DOUBLE_EQ(model.hotspot.weights[0], 0.05);
  EXPECT_NEAR(model.Gain(3)[0], 2.0, 1e-12);
  EXPECT_NEAR(model.Gain(3)[2], 0.5, 1e-12);
  // Without shading, the correction is the gains: B halved, R doubled.
  std::ofstream(dir / "report.json") << R"({"radiometry": {"corrected": true, "vignetting": false,
      "log_falloff_c1_c2_bgr": [[0, 0], [0, 0], [0, 0]], "flat_field": false, "hotspot": {"found": false}}})";
  const auto correct = SessionRadiometryCorrection(dir.string(), rec, &why);
  ASSERT_TRUE(correct) << why;
  cv::Mat grey(48, 64, CV_8UC3, cv::Scalar(100, 100, 100));
  correct(0, &grey);
  const cv::Vec3b px = grey.at<cv::Vec3b>(20, 30);
  EXPECT_NEAR(px[0], 50, 1);
  EXPECT_NEAR(px[1], 100, 1);
  EXPECT_NEAR(px[2], 200, 1);
  std::ofstream(dir / "radiometry.csv") << "frame,name,gain_b,gain_g,gain_r\n3,a.jpg,2.0,-1,0.5\n";
  EXPECT_FALSE(SessionRadiometryCorrection(dir.string(), rec, &why));
  EXPECT_NE(why.find("radiometry.csv"), std::string::npos) << why;
  std::ofstream(dir / "report.json") << R"({"radiometry": {"corrected": false}})";
  EXPECT_FALSE(SessionRadiometryCorrection(dir.string(), rec, &why));
  EXPECT_NE(why.find("did not correct"), std::string::npos) << why;
  fs::remove_all(dir);
}

TEST(SfmIo, PlyBytes) {
  const fs::path dir = TempDir("ply");
  std::vector<CloudPoint> pts = {{{1.5f, -2.25f, 3.0f}, {10, 20, 30}}, {{-7.f, 8.f, 1e4f}, {255, 0, 128}}};
  std::string err;
  ASSERT_TRUE(WritePly((dir / "c.ply").string(), pts, &err)) << err;
  // Header, then 15 bytes per vertex: x y z float32 LE, r g b.
  std::ifstream in(dir / "c.ply", std::ios::binary);
  const std::string all((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const auto end = all.find("end_header\n");
  ASSERT_NE(end, std::string::npos);
  EXPECT_NE(all.find("format binary_little_endian 1.0"), std::string::npos);
  EXPECT_NE(all.find("element vertex 2"), std::string::npos);
  const std::string body = all.substr(end + 11);
  ASSERT_EQ(body.size(), 30u);
  EXPECT_EQ(static_cast<unsigned char>(body[12]), 30);   // red = bgr[2]
  EXPECT_EQ(static_cast<unsigned char>(body[14]), 10);   // blue
  const unsigned char x0[4] = {0x00, 0x00, 0xC0, 0x3F};  // 1.5f little endian
  EXPECT_EQ(std::memcmp(body.data(), x0, 4), 0);
  std::vector<CloudPoint> back;
  ASSERT_TRUE(ReadPly((dir / "c.ply").string(), &back, &err)) << err;
  ASSERT_EQ(back.size(), 2u);
  EXPECT_EQ(back[1].xyz, pts[1].xyz);
  EXPECT_EQ(back[1].bgr, pts[1].bgr);
  fs::remove_all(dir);
}

TEST(SfmIo, DsmGeoTiffAndUtm) {
  std::string err;
  // Brighton (UK), 50.82 N, 0.14 W: UTM zone 30N (the ground tool projects GPS through core/georef).
  const int epsg = UtmEpsg(50.82, -0.14);
  EXPECT_EQ(epsg, 32630);
  ProjectedConverter utm;
  Vec2 en;
  ASSERT_TRUE(utm.ToProjected(epsg, 50.82, -0.14, &en, &err)) << err;
  EXPECT_NEAR(en.x(), 701443.7, 0.5);  // gdaltransform -s_srs EPSG:4326 -t_srs EPSG:32630
  EXPECT_NEAR(en.y(), 5633707.3, 0.5);

  std::vector<CloudPoint> pts;
  for (int i = 0; i < 10; ++i)
    for (int j = 0; j < 6; ++j)
      pts.push_back({{static_cast<float>(i) + 0.5f, static_cast<float>(-j) - 0.5f, static_cast<float>(i)}, {0, 0, 0}});
  pts.push_back({{0.5f, -0.5f, 100.f}, {0, 0, 0}});  // a second value in cell (0,0): median of {0, 100}
  pts.push_back({{0.6f, -0.6f, -100.f}, {0, 0, 0}});
  DsmGrid g;
  g.x0 = 0;
  g.y0 = 0;
  g.cell = 1.0;
  g.width = 12;
  g.height = 6;
  const cv::Mat1f dsm = RasterizeMedian(pts, g, -9999.f);
  EXPECT_FLOAT_EQ(dsm(0, 0), 0.f);
  EXPECT_FLOAT_EQ(dsm(3, 7), 7.f);
  EXPECT_FLOAT_EQ(dsm(0, 11), -9999.f);
  const fs::path dir = TempDir("dsm");
  ASSERT_TRUE(
      WriteDsmGeoTiff((dir / "d.tif").string(), dsm, g, Eigen::Vector2d(700000, 5600000), EpsgWkt(epsg), -9999.f, &err))
      << err;
  GDALAllRegister();
  GDALDataset* ds = static_cast<GDALDataset*>(GDALOpen((dir / "d.tif").c_str(), GA_ReadOnly));
  ASSERT_NE(ds, nullptr);
  EXPECT_EQ(ds->GetRasterXSize(), 12);
  EXPECT_EQ(ds->GetRasterBand(1)->GetRasterDataType(), GDT_Float32);
  int has = 0;
  EXPECT_EQ(ds->GetRasterBand(1)->GetNoDataValue(&has), -9999.0);
  EXPECT_TRUE(has);
  double gt[6];
  ds->GetGeoTransform(gt);
  EXPECT_DOUBLE_EQ(gt[0], 700000.0);
  EXPECT_DOUBLE_EQ(gt[3], 5600000.0);
  EXPECT_DOUBLE_EQ(gt[5], -1.0);
  const OGRSpatialReference* srs = ds->GetSpatialRef();
  ASSERT_NE(srs, nullptr);
  EXPECT_STREQ(srs->GetAuthorityCode(nullptr), "32630");
  float v = 0;
  ASSERT_EQ(ds->GetRasterBand(1)->RasterIO(GF_Read, 7, 3, 1, 1, &v, 1, 1, GDT_Float32, 0, 0), CE_None);
  EXPECT_FLOAT_EQ(v, 7.f);
  GDALClose(ds);
  fs::remove_all(dir);
}

}  // namespace
}  // namespace uavm::sfm
