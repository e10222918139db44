// Ground control points: gcp_list.txt parsing and its error messages, the CRS, tying GCPs to images, and the
// adjustment on a synthetic survey with known truth (checkpoint error within the click noise).
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <sstream>

#include "core/sfm/bundle_adjuster.h"
#include "core/sfm/control_points.h"
#include "core/sfm/gcp.h"
#include "sfm_synthetic.h"

namespace uavm::sfm {
namespace {

bool Parse(const std::string& text, GcpList* list, std::string* err) {
  std::istringstream in(text);
  return ParseGcpList(in, "gcp_list.txt", list, err);
}

TEST(GcpList, ParsesNamedAndUnnamedRows) {
  GcpList list;
  std::string err;
  ASSERT_TRUE(
      Parse("EPSG:32615\n"
            "# a comment\n"
            "576100.10 5188200.20 190.5 100 200 a.jpg gcp1\n"
            "576100.10 5188200.20 190.5 150 260 b.jpg gcp1\n"
            "\n"
            "576150.00 5188230.00 191.0 400 300 a.jpg\n"
            "576150.00 5188230.00 191.0 450 350 c.jpg\n",
            &list, &err))
      << err;
  EXPECT_EQ(list.crs_line, "EPSG:32615");
  ASSERT_EQ(list.points.size(), 2u);
  EXPECT_EQ(list.points[0].name, "gcp1");
  EXPECT_EQ(list.points[0].clicks.size(), 2u);
  EXPECT_DOUBLE_EQ(list.points[0].geo.z(), 190.5);
  EXPECT_EQ(list.points[1].name, "gcp-2");  // unnamed rows grouped by their coordinates
  EXPECT_FALSE(list.points[1].named);
  ASSERT_EQ(list.points[1].clicks.size(), 2u);
  EXPECT_EQ(list.points[1].clicks[1].image, "c.jpg");
  EXPECT_EQ(list.points[1].clicks[1].line, 7);
  EXPECT_DOUBLE_EQ(list.points[1].clicks[1].pixel.y(), 350.0);
}

// Each bad file is refused with a message naming the line and the problem.
TEST(GcpList, RefusesBadFilesWithClearMessages) {
  struct Case {
    const char* text;
    const char* expected;
  };
  const Case cases[] = {
      {"", "empty"},
      {"EPSG:32615\n", "no GCP rows"},
      {"EPSG:32615\n1 2 3 4 5\n", "line 2: expected `geo_x geo_y geo_z im_x im_y image_name [gcp_name]`"},
      {"EPSG:32615\n1 2 x 4 5 a.jpg\n", "line 2: field 3 ('x') is not a number"},
      {"EPSG:32615\n1 2 3 4 5 a.jpg p\n1 2 4 4 5 b.jpg p\n", "line 3: GCP 'p' has other coordinates than on line 2"},
      {"EPSG:32615\n1 2 3 4 5 a.jpg p\n1 2 3 9 9 b.jpg q\n", "'q' has the coordinates of 'p' (line 2)"},
      {"EPSG:32615\n1 2 3 4 5 a.jpg p\n1 2 3 40 50 a.jpg p\n", "clicked twice in a.jpg (lines 2 and 3)"},
      {"EPSG:32615\n1 2 3 400 500 a.jpg p\n7 8 9 400.5 500.5 a.jpg q\n",
       "'q' and 'p' (line 2) are clicked at the same pixel of a.jpg"},
  };
  for (const auto& c : cases) {
    GcpList list;
    std::string err;
    EXPECT_FALSE(Parse(c.text, &list, &err)) << c.text;
    EXPECT_NE(err.find(c.expected), std::string::npos) << "got: " << err;
  }
}

TEST(GcpCrs, ProjectedGeographicAndRefused) {
  {
    GcpCrs crs;
    std::vector<Eigen::Vector3d> pts = {{576100.0, 5188200.0, 190.0}};
    std::string err;
    ASSERT_TRUE(crs.Init("EPSG:32615", &pts, &err)) << err;
    EXPECT_EQ(crs.epsg(), 32615);
    EXPECT_EQ(crs.name(), "EPSG:32615");
    EXPECT_DOUBLE_EQ(pts[0].x(), 576100.0);
    // Brighton Beach, Duluth: (46.84 N, 92.0 W) is about 576 km east of zone 15's false origin... back and forth.
    const auto ll = crs.ToLatLon(pts[0].head<2>());
    ASSERT_TRUE(ll);
    const auto xy = crs.FromLatLon(ll->x(), ll->y());
    ASSERT_TRUE(xy);
    EXPECT_NEAR((*xy - pts[0].head<2>()).norm(), 0.0, 1e-4);
  }
  {
    // Degrees (x = longitude): moved to their UTM zone, z unchanged.
    GcpCrs crs;
    std::vector<Eigen::Vector3d> pts = {{-92.0, 46.84, 190.0}, {-91.999, 46.841, 191.0}};
    std::string err;
    ASSERT_TRUE(crs.Init("EPSG:4326", &pts, &err)) << err;
    EXPECT_TRUE(crs.converted_from_geographic());
    EXPECT_EQ(crs.epsg(), 32615);
    EXPECT_NEAR(pts[0].x(), 576230.0, 200.0);
    EXPECT_NEAR(pts[0].y(), 5187500.0, 500.0);
    EXPECT_NEAR((pts[1] - pts[0]).head<2>().norm(), 134.0, 5.0);  // 0.001 deg of each at 46.8 N: 76 m E, 111 m N
    EXPECT_DOUBLE_EQ(pts[1].z(), 191.0);
  }
  for (const char* bad : {"EPSG:2263" /* NY state plane, US feet */, "not a crs", "EPSG:4978" /* geocentric */}) {
    GcpCrs crs;
    std::vector<Eigen::Vector3d> pts = {{1.0, 2.0, 3.0}};
    std::string err;
    EXPECT_FALSE(crs.Init(bad, &pts, &err)) << bad;
    EXPECT_NE(err.find(bad), std::string::npos) << err;
  }
}

TEST(GcpBinding, RefusesUnknownImagesPixelsOutsideAndTooFewPoints) {
  const std::vector<ImageInfo> images = {{"a.jpg", 1000, 750, 0}, {"b.jpg", 1000, 750, 1}, {"c.jpg", 1000, 750, -1}};
  auto bind = [&](const std::string& rows, const std::vector<std::string>& checks, GcpBinding* out, std::string* err) {
    GcpList list;
    if (!Parse("EPSG:32615\n" + rows, &list, err)) return false;
    std::vector<Eigen::Vector3d> world;
    for (const auto& p : list.points) world.push_back(p.geo);
    return BindGcps(list, world, Eigen::Vector2d(100, 200), images, checks, out, err);
  };
  const std::string three =
      "110 210 5 10 10 a.jpg p\n110 210 5 20 20 b.jpg p\n"
      "120 210 5 30 30 a.jpg q\n120 210 5 40 40 b.jpg q\n"
      "110 230 5 50 50 a.jpg r\n110 230 5 60 60 b.jpg r\n110 230 5 60 60 c.jpg r\n";
  GcpBinding b;
  std::string err;
  ASSERT_TRUE(bind(three, {}, &b, &err)) << err;
  ASSERT_EQ(b.points.size(), 3u);
  EXPECT_EQ(b.clicks_skipped, 1);  // c.jpg is not in the reconstruction
  EXPECT_EQ(b.points[1].world, Eigen::Vector3d(20, 10, 5));
  EXPECT_EQ(b.points[2].observations.size(), 2u);

  EXPECT_FALSE(bind(three + "1 1 1 5 5 nope.jpg s\n", {}, &b, &err));
  EXPECT_NE(err.find("image 'nope.jpg' is not a frame of this session"), std::string::npos) << err;
  EXPECT_FALSE(bind(three + "1 1 1 1005 5 a.jpg s\n", {}, &b, &err));
  EXPECT_NE(err.find("line 9: pixel (1005, 5) is outside a.jpg (1000 x 750)"), std::string::npos) << err;
  EXPECT_FALSE(bind(three, {"r"}, &b, &err));  // a checkpoint does not count: two control points left
  EXPECT_NE(err.find("gives 2 control points"), std::string::npos) << err;
  EXPECT_FALSE(bind(three, {"zz"}, &b, &err));
  EXPECT_NE(err.find("no GCP named 'zz'"), std::string::npos) << err;
}

// "g<k>" (string concatenation here trips a GCC 12 -Wstringop-overflow false positive).
std::string Name(size_t k) {
  char name[24];
  std::snprintf(name, sizeof name, "g%zu", k);
  return name;
}

// The point's clicks in every frame that sees it, with click_px of noise on each coordinate.
void AddClicks(const Reconstruction& truth, const Eigen::Vector3d& X, double click_px, PortableRandom* rng,
               ControlPoint* cp) {
  for (size_t i = 0; i < truth.images.size(); ++i) {
    const double nx = rng->Normal(click_px), ny = rng->Normal(click_px);
    const auto m = Project(truth.cameras[0], truth.images[i].pose, X);
    if (!m || m->x() < 0 || m->y() < 0 || m->x() > truth.cameras[0].width - 1 || m->y() > truth.cameras[0].height - 1)
      continue;
    cp->observations.emplace_back(static_cast<int>(i), *m + Eigen::Vector2d(nx, ny));
  }
}

// A survey with known truth: the reconstruction starts in an arbitrary frame (as without GPS), the control points'
// clicks carry 0.5 px of noise, their surveys 1 cm. The checkpoints, which never enter the adjustment, must land
// within the click noise on the ground.
TEST(GcpAdjustment, CheckpointsWithinClickNoise) {
  const Reconstruction truth = testing::MakeScene(0.3, 5);
  PortableRandom rng(21);
  const double click_px = 0.5;
  std::vector<ControlPoint> cps;
  const double grid[][2] = {{-5, -5}, {20, -5}, {42, -5}, {-5, 15}, {20, 15}, {42, 15},
                            {-5, 33}, {20, 33}, {42, 33}, {8, 5},   {31, 24}};
  for (size_t k = 0; k < std::size(grid); ++k) {
    ControlPoint cp;
    const Eigen::Vector3d X(grid[k][0], grid[k][1], testing::Terrain(grid[k][0], grid[k][1]));
    cp.name = Name(k);
    cp.checkpoint = k >= 8;  // the last three
    const double sx = rng.Normal(0.01), sy = rng.Normal(0.01), sz = rng.Normal(0.01);
    cp.world = X + Eigen::Vector3d(sx, sy, sz);  // the survey's error
    AddClicks(truth, X, click_px, &rng, &cp);
    ASSERT_GE(cp.observations.size(), 2u) << cp.name;
    cps.push_back(cp);
  }
  // The reconstruction in an arbitrary frame (scaled, turned, shifted: what a pose-free start gives) and bent: the
  // cameras 0.5 m and 0.6 degrees off, the points 0.3 m, the focal length 2 % long.
  Reconstruction rec = truth;
  for (auto& im : rec.images) {
    const double ax = rng.Normal(1.0), ay = rng.Normal(1.0), az = rng.Normal(1.0);
    im.pose.R = Eigen::AngleAxisd(0.01, Eigen::Vector3d(ax, ay, az).normalized()).toRotationMatrix() * im.pose.R;
    const double cx = rng.Normal(0.5), cy = rng.Normal(0.5), cz = rng.Normal(0.5);
    im.pose.c += Eigen::Vector3d(cx, cy, cz);
  }
  for (auto& p : rec.points) {
    const double px = rng.Normal(0.3), py = rng.Normal(0.3), pz = rng.Normal(0.3);
    p.X += Eigen::Vector3d(px, py, pz);
  }
  rec.cameras[0].fx = rec.cameras[0].fy = truth.cameras[0].fx * 1.02;
  Similarity3 arbitrary;
  arbitrary.scale = 0.37;
  arbitrary.rotation = Eigen::AngleAxisd(1.1, Eigen::Vector3d(0.2, -0.3, 1.0).normalized()).toRotationMatrix();
  arbitrary.translation = Eigen::Vector3d(-40.0, 700.0, 12.0);
  rec.Transform(arbitrary);

  ControlOptions copt;
  copt.sigma_m = 0.01;
  copt.click_px = click_px;
  ControlReport report;
  std::vector<std::optional<Eigen::Vector3d>> priors(rec.images.size());
  std::string err;
  ASSERT_TRUE(AlignToControl(cps, copt, &rec, &priors, &report, &err)) << err;
  EXPECT_NEAR(report.alignment.scale * 0.37, 1.0, 0.05);  // undoes the arbitrary scale (the bend aside)
  EXPECT_TRUE(report.warnings.empty());
  MeasureControl(rec, cps, &report);  // after the similarity alone: the bend is still there
  const double aligned_only = report.ToJson()["checkpoint_rms"]["total_m"].get<double>();
  BundleOptions bo;
  bo.control = ControlConstraints(cps, rec, copt);
  EXPECT_EQ(bo.control.size(), 8u);
  bo.control_sigma_m = copt.sigma_m;
  bo.control_click_px = click_px;
  BundleSummary bs;
  ASSERT_TRUE(BundleAdjust(&rec, bo, &bs, &err)) << err;
  MeasureControl(rec, cps, &report);
  const auto js = report.ToJson();
  std::printf("%s\n", js.dump(1).c_str());
  const double gsd = report.gsd_m;
  EXPECT_NEAR(gsd, 60.0 / 1400.0, 0.005);
  const auto& check = js["checkpoint_rms"];
  ASSERT_EQ(check["points"].get<int>(), 3);
  // The click noise on the ground is 0.5 GSD per axis; a checkpoint seen in 4-6 images averages it down.
  EXPECT_LT(check["x_m"].get<double>(), click_px * gsd);
  EXPECT_LT(check["y_m"].get<double>(), click_px * gsd);
  EXPECT_LT(check["z_m"].get<double>(), 3.0 * click_px * gsd);  // height: baselines of 12-14 m at 60 m
  std::printf("checkpoint RMS %.3f m after the similarity alone, %.3f m after the adjustment\n", aligned_only,
              check["total_m"].get<double>());
  EXPECT_GT(aligned_only, 3.0 * check["total_m"].get<double>());
  // The cameras are back on the truth, in the survey frame (they started hundreds of metres away). Their errors
  // (measured: 0.096 m horizontally, 0.082 m in height) are loose against the checkpoints' centimetre because a small
  // tilt and a shift of a camera trade against each other over nearly flat ground, as do focal length and height.
  double worst_xy = 0.0, worst_z = 0.0;
  for (size_t i = 0; i < rec.images.size(); ++i) {
    const Eigen::Vector3d d = rec.images[i].pose.c - truth.images[i].pose.c;
    worst_xy = std::max(worst_xy, d.head<2>().norm());
    worst_z = std::max(worst_z, std::abs(d.z()));
  }
  std::printf("camera centres: worst %.3f m horizontally, %.3f m in height; focal %.1f (truth %.1f)\n", worst_xy,
              worst_z, rec.cameras[0].fx, truth.cameras[0].fx);
  EXPECT_LT(worst_xy, 0.2);
  EXPECT_LT(worst_z, 0.2);
}

// Targets measured with a handheld GPS: a GCP file whose heights are all 0. The flight's own GPS places the model
// (1.5 m off horizontally, 0.8 m in height, 0.3 m noise per camera). Tied in 3-D, the block is pulled down onto
// height 0 and bends; as horizontal control the GCPs remove the horizontal offset and the heights stay the GPS's.
TEST(GcpAdjustment, GcpsWithoutHeightsAreHorizontalControl) {
  const Reconstruction truth = testing::MakeScene(0.3, 5);
  PortableRandom rng(23);
  std::vector<ControlPoint> cps;
  std::vector<Eigen::Vector3d> true_points;
  const double grid[][2] = {{-5, -5}, {20, -5}, {42, -5}, {-5, 33}, {20, 33}, {42, 33}, {8, 5}, {31, 24}, {20, 15}};
  for (size_t k = 0; k < std::size(grid); ++k) {
    ControlPoint cp;
    const Eigen::Vector3d X(grid[k][0], grid[k][1], testing::Terrain(grid[k][0], grid[k][1]));
    cp.name = Name(k);
    cp.checkpoint = k >= 6;                         // the last three
    cp.world = Eigen::Vector3d(X.x(), X.y(), 0.0);  // no height in the file
    AddClicks(truth, X, 0.5, &rng, &cp);
    ASSERT_GE(cp.observations.size(), 2u) << cp.name;
    cps.push_back(cp);
    true_points.push_back(X);
  }
  const Eigen::Vector3d gps_bias(1.2, -0.9, 0.8);
  auto fly = [&](bool horizontal_only, Reconstruction* rec) {
    *rec = truth;
    std::vector<std::optional<Eigen::Vector3d>> priors;
    PortableRandom noise(31);
    for (auto& im : rec->images) {
      const double nx = noise.Normal(0.3), ny = noise.Normal(0.3), nz = noise.Normal(0.3);
      priors.emplace_back(im.pose.c + gps_bias + Eigen::Vector3d(nx, ny, nz));
      im.pose.c += gps_bias;  // the model as the GPS placed it
    }
    ControlOptions copt;
    copt.horizontal_only = horizontal_only;
    ControlReport report;
    std::string err;
    EXPECT_TRUE(AlignToControl(cps, copt, rec, &priors, &report, &err)) << err;
    BundleOptions bo;
    bo.centre_priors = priors;
    bo.control = ControlConstraints(cps, *rec, copt);
    bo.control_sigma_m = copt.sigma_m;
    if (horizontal_only) bo.control_sigma_z_m = copt.free_height_sigma_m;
    BundleSummary bs;
    EXPECT_TRUE(BundleAdjust(rec, bo, &bs, &err)) << err;
    MeasureControl(*rec, cps, &report);
    return report;
  };
  // Each checkpoint triangulated, against its true position.
  auto check_errors = [&](const Reconstruction& rec, double* horizontal, double* vertical) {
    double sh = 0, sv = 0;
    for (size_t k = 6; k < cps.size(); ++k) {
      const auto X = TriangulateClicks(rec, cps[k]);
      ASSERT_TRUE(X.has_value());
      sh += (X->head<2>() - true_points[k].head<2>()).squaredNorm();
      sv += std::pow(X->z() - true_points[k].z() - gps_bias.z(), 2);  // the GPS's height reference is kept
    }
    *horizontal = std::sqrt(sh / 3);
    *vertical = std::sqrt(sv / 3);
  };
  Reconstruction horizontal, in_3d;
  const ControlReport report = fly(true, &horizontal);
  double h_ours = 0, v_ours = 0, h_3d = 0, v_3d = 0;
  check_errors(horizontal, &h_ours, &v_ours);
  fly(false, &in_3d);
  check_errors(in_3d, &h_3d, &v_3d);
  std::printf(
      "checkpoints: horizontal control %.3f m horizontally, %.3f m in height (about the GPS's); tied in 3-D "
      "to height 0: %.3f m, %.3f m\n",
      h_ours, v_ours, h_3d, v_3d);
  EXPECT_LT(h_ours, 0.1);  // the 1.5 m GPS offset is gone
  EXPECT_LT(v_ours, 0.5);  // the GPS's heights kept (its 0.3 m noise averaged over 12 cameras)
  // The same file tied in 3-D pulls the block towards height 0 (1.2 m here) and bends it sideways (0.23 m).
  EXPECT_GT(v_3d, 10 * v_ours);
  EXPECT_GT(h_3d, 5 * h_ours);
  const auto js = report.ToJson();
  EXPECT_TRUE(js["horizontal_only"].get<bool>());
  EXPECT_TRUE(js["checkpoint_rms"]["z_m"].is_null());
  EXPECT_LT(js["checkpoint_rms"]["total_m"].get<double>(), 0.1);
}

TEST(GcpAdjustment, AMisclickedControlPointIsReported) {
  const Reconstruction truth = testing::MakeScene(0.2, 9);
  std::vector<ControlPoint> cps;
  const double grid[][2] = {{-5, -5}, {42, -5}, {-5, 33}, {42, 33}};
  for (size_t k = 0; k < 4; ++k) {
    ControlPoint cp;
    cp.name = Name(k);
    const Eigen::Vector3d X(grid[k][0], grid[k][1], testing::Terrain(grid[k][0], grid[k][1]));
    cp.world = X;
    for (size_t i = 0; i < truth.images.size(); ++i) {
      const auto m = Project(truth.cameras[0], truth.images[i].pose, X);
      if (m && m->x() >= 0 && m->y() >= 0 && m->x() < truth.cameras[0].width && m->y() < truth.cameras[0].height) {
        cp.observations.emplace_back(static_cast<int>(i), *m);
      }
    }
    cps.push_back(cp);
  }
  cps[3].world.x() += 8.0;  // a wrong coordinate (a digit off in the survey)
  Reconstruction rec = truth;
  std::vector<std::optional<Eigen::Vector3d>> priors(rec.images.size());
  ControlReport report;
  std::string err;
  ASSERT_TRUE(AlignToControl(cps, ControlOptions{}, &rec, &priors, &report, &err)) << err;
  ASSERT_FALSE(report.warnings.empty());
  EXPECT_NE(report.warnings[0].find("GCP 'g"), std::string::npos) << report.warnings[0];
  EXPECT_GT(report.alignment_rms_m, 1.0);
}

}  // namespace
}  // namespace uavm::sfm
