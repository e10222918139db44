// The true orthophoto on a synthetic relief scene (core/eval/relief_scene.h): frames rendered by ray casting over
// buildings and trees, the true DSM, the adjusted cameras exact; the orthophoto against the true one rendered from
// above.
#include <gtest/gtest.h>

#include <cstdlib>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "core/eval/relief_scene.h"
#include "core/sfm/orthophoto.h"
#include "tests/sfm_synthetic.h"

namespace uavm::sfm {
namespace {

struct ReliefFlight {
  eval::ReliefScene scene;
  Reconstruction rec;
  std::vector<cv::Mat> frames;
  cv::Mat1f dsm;
  DsmGrid dsm_grid;
};

Camera OrthoTestCamera() {
  Camera c;
  c.width = 400;
  c.height = 300;
  c.fx = c.fy = 330.0;
  c.cx = 199.2;
  c.cy = 150.7;
  c.k1 = -0.05;
  c.k2 = 0.01;
  return c;
}

// 4 x 4 frames at 60 m (GSD 0.18 m) over a 80 x 80 m scene of 4 buildings (8-25 m) and 6 trees; the DSM is the true
// surface sampled at 0.5 m.
ReliefFlight MakeReliefFlight() {
  ReliefFlight f;
  f.scene = eval::MakeReliefScene(7, 40.0, 4, 6);
  f.scene.texture_scale = 3.0 * 0.18;
  f.rec.cameras = {OrthoTestCamera()};
  const Camera& cam = f.rec.cameras[0];
  for (int r = 0; r < 4; ++r) {
    for (int k = 0; k < 4; ++k) {
      Image im;
      im.frame_index = r * 4 + k;
      const Eigen::Vector3d centre(-24.0 + 16.0 * k, -30.0 + 20.0 * r, 60.0);
      im.pose = testing::NadirPose(centre, 0.05 * (k - r), 0.02 * (k % 2), -0.02 * (r % 2));
      const Pose pose = im.pose;
      f.frames.push_back(eval::RenderView(f.scene, cv::Size(cam.width, cam.height), centre, [&](double u, double v) {
        const Eigen::Vector2d xn = cam.Undistort(Eigen::Vector2d(u, v));
        return Eigen::Vector3d(pose.R.transpose() * Eigen::Vector3d(xn.x(), xn.y(), 1.0));
      }));
      f.rec.images.push_back(im);
    }
  }
  f.dsm_grid.x0 = -40.0;
  f.dsm_grid.y0 = 40.0;
  f.dsm_grid.cell = 0.5;
  f.dsm_grid.width = f.dsm_grid.height = 160;
  eval::TruthGrid g{f.dsm_grid.x0, f.dsm_grid.y0, f.dsm_grid.cell, f.dsm_grid.width, f.dsm_grid.height};
  f.dsm = eval::RenderTrueSurface(f.scene, g);
  return f;
}

struct OrthoOutcome {
  cv::Mat image;
  cv::Mat1b mask;
  OrthoReport report;
};

OrthoOutcome RunOrtho(const ReliefFlight& f, const DsmGrid& grid, OrthoOptions options) {
  OrthoOutcome out;
  out.image = cv::Mat(grid.height, grid.width, CV_8UC3, cv::Scalar::all(0));
  out.mask = cv::Mat1b(grid.height, grid.width, uchar{0});
  std::string error;
  const bool ok = MakeOrthophoto(
      f.rec, f.dsm, cv::Mat1f(), f.dsm_grid, -9999.0f, grid, options, [&](size_t i) { return f.frames[i]; },
      [&](const cv::Mat& image, const cv::Mat& mask, cv::Point at, std::string*) {
        image.copyTo(out.image(cv::Rect(at, image.size())));
        mask.copyTo(out.mask(cv::Rect(at, mask.size())));
        return true;
      },
      &out.report, &error);
  EXPECT_TRUE(ok) << error;
  return out;
}

// Covered ground pixels whose distance to the nearest building or crown lies in [lo_m, hi_m).
cv::Mat1b GroundBand(const eval::ReliefScene& scene, const eval::TruthGrid& g, const cv::Mat1b& covered, double lo_m,
                     double hi_m) {
  const cv::Mat ground = eval::RenderCover(scene, g) == 0;
  cv::Mat1f dist;
  cv::distanceTransform(ground, dist, cv::DIST_L2, cv::DIST_MASK_PRECISE);
  dist *= g.gsd;
  cv::Mat band = (dist >= lo_m) & (dist < hi_m) & (covered > 0);
  return cv::Mat1b(band);
}

double MeanAbsDiff(const cv::Mat& a, const cv::Mat& b, const cv::Mat1b& where) {
  cv::Mat diff;
  cv::absdiff(a, b, diff);
  return cv::mean(diff, where)[0] + cv::mean(diff, where)[1] + cv::mean(diff, where)[2];
}

// Share of `where` whose colour is grossly wrong (another surface's, not a resampled neighbour's).
double GrossShare(const cv::Mat& a, const cv::Mat& b, const cv::Mat1b& where) {
  cv::Mat diff;
  cv::absdiff(a, b, diff);
  cv::Mat sum;
  cv::transform(diff, sum, cv::Matx13f(1, 1, 1));
  const cv::Mat gross = (sum > 90) & where;
  return cv::countNonZero(gross) / static_cast<double>(cv::countNonZero(where));
}

int WallPixels(const cv::Mat& image, const cv::Mat1b& where) {
  cv::Mat1b red;
  cv::inRange(image, cv::Scalar(0, 0, 150), cv::Scalar(80, 70, 255), red);
  return cv::countNonZero(red & where);
}

TEST(Orthophoto, TrueOrthoOfAReliefSceneMatchesTheTruthAndShowsNoWall) {
  const ReliefFlight f = MakeReliefFlight();
  const DsmGrid grid = OrthoGridOver(f.dsm_grid, 0.2);
  ASSERT_EQ(grid.width, 400);
  const eval::TruthGrid g{grid.x0, grid.y0, grid.cell, grid.width, grid.height};
  const cv::Mat truth = eval::RenderTrueOrtho(f.scene, g);
  OrthoOptions options;
  options.tile_size = 128;  // several tiles, their seams inside the scene
  const OrthoOutcome ours = RunOrtho(f, grid, options);
  // The flown area (the frames' footprints: -60..60 m by -47..47 m) holds the whole 80 m scene.
  EXPECT_GT(cv::countNonZero(ours.mask), 0.97 * grid.width * grid.height);
  EXPECT_EQ(ours.report.images_used, 16);
  // Those left are on the DSM's walls (a slope over one cell, under the roof's edge in every view): < 1 %.
  EXPECT_LT(ours.report.cells_occluded_everywhere, 400u);
  EXPECT_GT(ours.report.cells_taken_from_another_view, 100u) << "the scene's buildings occlude ground in some views";
  // Far from relief the orthophoto differs from the truth by resampling alone; next to a building (beyond the DSM's
  // smoothing of its walls over a 0.5 m cell) the most nadir frame often sees the roof or wall instead of the ground.
  const cv::Mat1b far = GroundBand(f.scene, g, ours.mask, 4.0, 1e9);
  const cv::Mat1b near = GroundBand(f.scene, g, ours.mask, 0.8, 4.0);
  ASSERT_GT(cv::countNonZero(far), grid.width * grid.height / 3);
  ASSERT_GT(cv::countNonZero(near), 2000);
  const double err_far = MeanAbsDiff(ours.image, truth, far);
  const double err_near = MeanAbsDiff(ours.image, truth, near);
  const int walls = WallPixels(ours.image, near);
  // The same frames without the z-buffer (every point taken as seen).
  options.occlusion_tolerance_cells = 1e6;
  const OrthoOutcome blind = RunOrtho(f, grid, options);
  const double err_blind = MeanAbsDiff(blind.image, truth, near);
  const double gross = GrossShare(ours.image, truth, near), gross_blind = GrossShare(blind.image, truth, near);
  const int walls_blind = WallPixels(blind.image, near);
  std::printf(
      "orthophoto vs truth, mean |diff| (sum of BGR): ground far from relief %.2f, next to it %.2f (wall pixels %d); "
      "without the z-buffer next to it %.2f (wall pixels %d); grossly wrong next to it %.4f, without the z-buffer "
      "%.4f; "
      "%zu seam cells taken from another view\n",
      err_far, err_near, walls, err_blind, walls_blind, gross, gross_blind, ours.report.cells_taken_from_another_view);
  if (const char* dir = std::getenv("UAVM_TEST_PICTURES")) {  // for looking at them
    cv::imwrite(std::string(dir) + "/ortho.png", ours.image);
    cv::imwrite(std::string(dir) + "/ortho_truth.png", truth);
    cv::imwrite(std::string(dir) + "/ortho_blind.png", blind.image);
    cv::imwrite(std::string(dir) + "/ortho_frame0.png", f.frames[0]);
    cv::Mat diff;
    cv::absdiff(ours.image, truth, diff);
    cv::imwrite(std::string(dir) + "/ortho_diff.png", diff * 4);
    cv::Mat crop;
    cv::Mat3b both;
    cv::hconcat(std::vector<cv::Mat>{ours.image(cv::Rect(60, 230, 120, 150)), blind.image(cv::Rect(60, 230, 120, 150)),
                                     truth(cv::Rect(60, 230, 120, 150))},
                both);
    cv::resize(both, crop, cv::Size(), 3, 3, cv::INTER_NEAREST);
    cv::imwrite(std::string(dir) + "/ortho_bl.png", crop);
    cv::resize(ours.image(cv::Rect(150, 150, 100, 100)), crop, cv::Size(), 4, 4, cv::INTER_NEAREST);
    cv::imwrite(std::string(dir) + "/ortho_crop.png", crop);
    cv::resize(truth(cv::Rect(150, 150, 100, 100)), crop, cv::Size(), 4, 4, cv::INTER_NEAREST);
    cv::imwrite(std::string(dir) + "/ortho_truth_crop.png", crop);
  }
  EXPECT_LT(err_far, 15.0);
  EXPECT_LT(err_near, 1.5 * err_far);
  EXPECT_GT(err_blind, err_near);
  EXPECT_GT(gross_blind, 2.0 * gross);
  EXPECT_GT(walls_blind, 5 * std::max(walls, 5));
  // Position: phase correlation of the ortho against the truth over the covered middle.
  const cv::Rect mid(100, 100, 200, 200);
  cv::Mat a, b;
  cv::cvtColor(ours.image(mid), a, cv::COLOR_BGR2GRAY);
  cv::cvtColor(truth(mid), b, cv::COLOR_BGR2GRAY);
  a.convertTo(a, CV_32F);
  b.convertTo(b, CV_32F);
  const cv::Point2d shift = cv::phaseCorrelate(a, b);
  EXPECT_LT(std::hypot(shift.x, shift.y), 0.25) << shift;
}

TEST(Orthophoto, EmptyDsmIsAnError) {
  const ReliefFlight f = MakeReliefFlight();
  OrthoOptions options;
  OrthoReport report;
  std::string error;
  EXPECT_FALSE(MakeOrthophoto(
      f.rec, cv::Mat1f(), cv::Mat1f(), f.dsm_grid, -9999.0f, OrthoGridOver(f.dsm_grid, 0.2), options,
      [&](size_t i) { return f.frames[i]; },
      [](const cv::Mat&, const cv::Mat&, cv::Point, std::string*) { return true; }, &report, &error));
  EXPECT_NE(error.find("no DSM"), std::string::npos);
  options.seam_cell = 0;
  EXPECT_FALSE(options.Check(&error));
}

}  // namespace
}  // namespace uavm::sfm
