// The ground reconstruction's stages one by one (core/sfm/frame_selection, feature_stage, pair_matching,
// initial_poses, sparse_stage, dense_stage) on a synthetic nadir survey with known truth: a textured flat field (a real
// aerial photograph as its texture) seen by a 3 x 2 grid of frames whose onboard maps are exact.
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "core/session/session_dir.h"
#include "core/sfm/dense_stage.h"
#include "core/sfm/feature_stage.h"
#include "core/sfm/frame_selection.h"
#include "core/sfm/initial_poses.h"
#include "core/sfm/pair_matching.h"
#include "core/sfm/sparse_stage.h"
#include "core/sfm/tracks.h"

namespace uavm::sfm {
namespace {

namespace fs = std::filesystem;

// The field: the texture's pixel (u, v) is the ground point (kGsd u, -kGsd v, 0), metres east and north. Each frame is
// a nadir pinhole (kFocal px, no distortion) at kHeight over its centre, north up: one frame pixel covers kHeight /
// kFocal = 0.125 m, i.e. 1.25 texture pixels.
constexpr double kGsd = 0.1;
constexpr double kFocal = 400.0;
constexpr double kHeight = 50.0;
constexpr int kWidth = 400;
constexpr int kHeightPx = 300;
constexpr double kTexPerFramePx = kHeight / kFocal / kGsd;

struct Survey {
  fs::path dir;
  std::vector<cv::Point2d> centre_tex;  // each frame's centre in texture pixels
  std::vector<Mat3> tex_from_frame;
};

Mat3 TexFromFrame(const cv::Point2d& centre) {
  Mat3 m = Mat3::Identity();
  m(0, 0) = m(1, 1) = kTexPerFramePx;
  m(0, 2) = centre.x - kTexPerFramePx * 0.5 * (kWidth - 1);
  m(1, 2) = centre.y - kTexPerFramePx * 0.5 * (kHeightPx - 1);
  return m;
}

// A session directory as the onboard program leaves it (frames.csv, transforms.csv with exact maps, graph.csv with
// each frame's neighbours, frames/), frame 6 registered but in no used edge, frame 7 not registered.
Survey MakeSurvey(const std::string& name) {
  Survey s;
  s.dir = fs::temp_directory_path() / ("uavm_stages_" + name + "_" + std::to_string(::getpid()));
  fs::remove_all(s.dir);
  fs::create_directories(s.dir / "frames");
  const cv::Mat texture = cv::imread(std::string(UAVM_TEST_DATA) + "/caliterra_small/images/IMG_9360.jpg");
  EXPECT_FALSE(texture.empty());
  std::ofstream frames(s.dir / "frames.csv");
  frames << "index,filename,stored_file,width,height,registered,relative_altitude_m\n";
  std::vector<TransformRow> rows;
  for (int i = 0; i < 8; ++i) {
    // Two strips of three, 40 % of a frame apart along the strip and 55 % across; frames 6 and 7 off to the side.
    const int strip = std::min(i, 6) / 3, along = std::min(i, 6) % 3;
    const cv::Point2d centre(300 + along * 0.4 * kWidth * kTexPerFramePx + (i >= 6 ? 150 : 0),
                             230 + strip * 0.45 * kHeightPx * kTexPerFramePx);
    s.centre_tex.push_back(centre);
    s.tex_from_frame.push_back(TexFromFrame(centre));
    cv::Mat M(2, 3, CV_64F);
    for (int r = 0; r < 2; ++r)
      for (int c = 0; c < 3; ++c) M.at<double>(r, c) = s.tex_from_frame.back()(r, c);
    cv::Mat image;
    cv::warpAffine(texture, image, M, cv::Size(kWidth, kHeightPx), cv::INTER_AREA | cv::WARP_INVERSE_MAP,
                   cv::BORDER_REFLECT);
    const std::string file = "f" + std::to_string(i) + ".png";
    cv::imwrite((s.dir / "frames" / file).string(), image);
    frames << i << ",f" << i << ".jpg," << file << "," << kWidth << "," << kHeightPx << "," << (i < 7 ? 1 : 0) << ","
           << kHeight << "\n";
    TransformRow row;
    row.index = i;
    row.filename = "f" + std::to_string(i) + ".jpg";
    row.registered = i < 7;
    row.mosaic_from_frame = s.tex_from_frame.back();
    row.placed_by = row.registered ? "image" : "";
    rows.push_back(row);
  }
  std::ofstream(s.dir / "transforms.csv") << FormatTransformsCsv(rows);
  std::ofstream graph(s.dir / "graph.csv");
  graph << "src,tgt,src_file,tgt_file,matches,inliers,used\n";
  for (const auto& [a, b] : std::vector<std::pair<int, int>>{{0, 1}, {1, 2}, {3, 4}, {4, 5}, {0, 3}, {1, 4}, {2, 5}})
    graph << a << "," << b << ",f" << a << ".jpg,f" << b << ".jpg,100,80,1\n";
  graph << "5,6,f5.jpg,f6.jpg,30,10,0\n";  // refused onboard: not a used edge
  return s;
}

ReconstructionOptions SurveyOptions() {
  ReconstructionOptions o;
  o.default_hfov_deg =
      2.0 * std::atan(0.5 * kWidth / kFocal) * 180.0 / M_PI;  // no EXIF: the field of view is the guess
  o.max_features = 3000;
  o.dense = false;
  return o;
}

TEST(FrameSelection, TakesRegisteredFramesWithAUsedEdge) {
  const Survey s = MakeSurvey("select");
  SelectedFrames sel;
  std::string err;
  ASSERT_TRUE(SelectFrames(s.dir.string(), &sel, &err)) << err;
  ASSERT_EQ(sel.frames.size(), 6u);
  for (size_t i = 0; i < 6; ++i) {
    EXPECT_EQ(sel.frames[i]->index, static_cast<int>(i));
    EXPECT_EQ(sel.slot_of.at(static_cast<int>(i)), i);
  }
  EXPECT_EQ(sel.slot_of.count(6), 0u) << "registered, but in no used edge";
  EXPECT_EQ(sel.slot_of.count(7), 0u) << "not registered";
  fs::remove_all(s.dir);
  EXPECT_FALSE(SelectFrames(s.dir.string(), &sel, &err)) << "no session";
}

TEST(FeatureStage, KeypointsInOriginalPixelsAndAnUnreadableFrameLeftOut) {
  const Survey s = MakeSurvey("features");
  SelectedFrames sel;
  std::string err;
  ASSERT_TRUE(SelectFrames(s.dir.string(), &sel, &err)) << err;
  fs::remove(s.dir / "frames" / "f5.png");
  ReconstructionOptions o = SurveyOptions();
  std::vector<FrameFeatures> full;
  nlohmann::json js;
  ASSERT_TRUE(ExtractFeatures(s.dir.string(), &sel, o, nullptr, &full, &js, &err)) << err;
  ASSERT_EQ(sel.frames.size(), 5u);
  ASSERT_EQ(sel.left_out.size(), 1u);
  EXPECT_EQ(sel.left_out[0].first->index, 5);
  EXPECT_NE(sel.left_out[0].second.find("f5.png"), std::string::npos) << sel.left_out[0].second;
  EXPECT_EQ(js["frames_not_used"].size(), 1u);
  // Detected at half size, the keypoints are still in the stored frame's pixels: most of them lie on a full-size one.
  o.feature_long_side_px = kWidth / 2;
  EXPECT_DOUBLE_EQ(FeatureScale(o, *sel.frames[0]), 0.5);
  SelectedFrames half_sel;
  ASSERT_TRUE(SelectFrames(s.dir.string(), &half_sel, &err)) << err;
  std::vector<FrameFeatures> half;
  ASSERT_TRUE(ExtractFeatures(s.dir.string(), &half_sel, o, nullptr, &half, &js, &err)) << err;
  ASSERT_GT(half[0].points.size(), 50u);
  int near = 0;
  for (const auto& p : half[0].points) {
    EXPECT_GE(p.x(), -0.5);
    EXPECT_LE(p.x(), kWidth - 0.5);
    double best = 1e9;
    for (const auto& q : full[0].points) best = std::min(best, (p - q).norm());
    near += best < 2.0 ? 1 : 0;
  }
  EXPECT_GT(near, static_cast<int>(half[0].points.size()) / 2) << near << " of " << half[0].points.size();
  fs::remove_all(s.dir);
}

// The survey's selected frames and their features, shared by the later stages' tests.
struct Prepared {
  Survey survey;
  SelectedFrames sel;
  std::vector<FrameFeatures> feats;
  ReconstructionOptions options = SurveyOptions();
};

void Prepare(const std::string& name, Prepared* p) {
  p->survey = MakeSurvey(name);
  std::string err;
  nlohmann::json js;
  ASSERT_TRUE(SelectFrames(p->survey.dir.string(), &p->sel, &err)) << err;
  ASSERT_TRUE(ExtractFeatures(p->survey.dir.string(), &p->sel, p->options, nullptr, &p->feats, &js, &err)) << err;
}

TEST(PairMatching, GuidedMatchesAgreeWithTheTrueMap) {
  Prepared p;
  ASSERT_NO_FATAL_FAILURE(Prepare("match", &p));
  const PairMatch m = MatchPair(0, 1, p.feats[0], p.feats[1], *p.sel.frames[0], *p.sel.frames[1], p.options);
  ASSERT_GT(m.inliers, 100);
  ASSERT_EQ(m.matches.size(), static_cast<size_t>(m.inliers));
  const Mat3 b_from_a = p.survey.tex_from_frame[1].inverse() * p.survey.tex_from_frame[0];
  int wrong = 0;
  for (const FeatureMatch& fm : m.matches) {
    const Vec2 predicted = Apply(b_from_a, p.feats[0].points[static_cast<size_t>(fm.feature1)]);
    wrong += (predicted - p.feats[1].points[static_cast<size_t>(fm.feature2)]).norm() > 2.0 ? 1 : 0;
  }
  EXPECT_LE(wrong, m.inliers / 100) << wrong << " of " << m.inliers << " inliers off the true map by > 2 px";
  nlohmann::json js;
  const std::vector<FeatureMatch> all = MatchGraphPairs(p.sel, p.feats, p.options, nullptr, &js);
  EXPECT_EQ(js["pairs_listed"], 7) << "graph.csv's used pairs among the selected frames";
  EXPECT_EQ(js["pairs_verified"], 7);
  EXPECT_EQ(all.size(), js["matches"].get<size_t>());
  fs::remove_all(p.survey.dir);
}

TEST(InitialPoses, FromExactOnboardMapsAndTheRelativeAltitude) {
  Prepared p;
  ASSERT_NO_FATAL_FAILURE(Prepare("poses", &p));
  Reconstruction rec;
  InitialModel init;
  nlohmann::json js;
  std::string err;
  ASSERT_TRUE(InitialPoses(p.sel.frames, p.feats, p.sel.session.lens, p.options, &rec, &init, &js, &err)) << err;
  EXPECT_EQ(init.pose_source, "onboard_maps+relative_altitude");
  ASSERT_EQ(rec.images.size(), p.sel.frames.size());
  ASSERT_EQ(rec.cameras.size(), 1u);
  EXPECT_NEAR(rec.cameras[0].fx, kFocal, 1e-6);
  for (size_t i = 0; i < rec.images.size(); ++i) {
    const cv::Point2d c = p.survey.centre_tex[static_cast<size_t>(p.sel.frames[i]->index)];
    const Eigen::Vector3d truth(kGsd * c.x, -kGsd * c.y, kHeight);
    EXPECT_LT((rec.images[i].pose.c - truth).norm(), 0.01) << "frame " << i;
    // Nadir, north up: the camera's z axis points down, its x axis east.
    EXPECT_NEAR(rec.images[i].pose.R(2, 2), -1.0, 1e-9);
    EXPECT_NEAR(rec.images[i].pose.R(0, 0), 1.0, 1e-9);
  }
  fs::remove_all(p.survey.dir);
}

TEST(InitialPoses, MosaicToWorldFitsGpsWithTheMosaicsReflection) {
  // Five frame centres in the mosaic and their GPS positions under a known similarity with a reflection (mosaic rows
  // go south): the fit recovers it.
  const double scale = 0.07, angle = 0.3;
  Eigen::Matrix2d Q;
  Q << std::cos(angle), std::sin(angle), std::sin(angle), -std::cos(angle);
  const Eigen::Vector2d t(12.0, -40.0);
  std::vector<SessionFrame> frames(5);
  std::vector<const SessionFrame*> ptrs;
  GpsPositions gps;
  std::vector<Eigen::Vector2d> centres;
  for (int i = 0; i < 5; ++i) {
    centres.emplace_back(100.0 * i, 37.0 * (i % 2) + 5.0 * i * i);
    const Eigen::Vector2d en = scale * Q * centres.back() + t;
    gps.local.emplace_back(Eigen::Vector3d(en.x(), en.y(), 50.0));
    ptrs.push_back(&frames[static_cast<size_t>(i)]);
  }
  const std::vector<Eigen::Matrix2d> jac(5, Eigen::Matrix2d::Identity());
  const std::vector<double> fpx(5, 1000.0);
  const MosaicToWorld m = FitMosaicToWorld(ptrs, gps, centres, jac, fpx);
  EXPECT_EQ(m.pose_source, "onboard_maps+gps");
  EXPECT_NEAR(m.s, scale, 1e-9);
  EXPECT_LT((m.Q - Q).norm(), 1e-9);
  EXPECT_LT((m.t - t).norm(), 1e-6);
}

TEST(SparseStage, TriangulatesTheFieldFlatAndAdjusts) {
  Prepared p;
  ASSERT_NO_FATAL_FAILURE(Prepare("sparse", &p));
  nlohmann::json js;
  std::string err;
  const std::vector<FeatureMatch> matches = MatchGraphPairs(p.sel, p.feats, p.options, nullptr, &js);
  TrackStats stats;
  const std::vector<Track> tracks = BuildTracks(matches, 2, &stats);
  Reconstruction rec;
  InitialModel init;
  ASSERT_TRUE(InitialPoses(p.sel.frames, p.feats, p.sel.session.lens, p.options, &rec, &init, &js, &err)) << err;
  ASSERT_TRUE(TriangulateAndAdjust(p.sel.frames, p.feats, tracks, init, p.options, nullptr, &rec, &js, &err)) << err;
  EXPECT_GT(rec.points.size(), 300u);
  EXPECT_LT(js["ba_rms_after_px"].get<double>(), 0.7);
  // The field is flat at height 0: its points' heights, relative to the first camera's, within a few centimetres.
  std::vector<double> depth;
  for (const auto& pt : rec.points) depth.push_back(rec.images[0].pose.c.z() - pt.X.z());
  std::sort(depth.begin(), depth.end());
  const double median = depth[depth.size() / 2];
  EXPECT_NEAR(median, kHeight, 0.05 * kHeight) << "the first camera's height over the field";
  const double spread = depth[depth.size() * 9 / 10] - depth[depth.size() / 10];
  EXPECT_LT(spread, 0.02 * kHeight) << "80 % of the points within 2 % of the height of a plane";
  // Each camera's centre, relative to the first, as surveyed (the adjustment holds the first camera).
  for (size_t i = 1; i < rec.images.size(); ++i) {
    const cv::Point2d a = p.survey.centre_tex[static_cast<size_t>(p.sel.frames[0]->index)];
    const cv::Point2d b = p.survey.centre_tex[static_cast<size_t>(p.sel.frames[i]->index)];
    const Eigen::Vector3d truth(kGsd * (b.x - a.x), -kGsd * (b.y - a.y), 0.0);
    EXPECT_LT((rec.images[i].pose.c - rec.images[0].pose.c - truth).norm(), 0.02 * truth.norm()) << "frame " << i;
  }
  fs::remove_all(p.survey.dir);
}

TEST(DenseStage, WithoutDensePointsTheSurfaceIsTheSparseOneAndSaysSo) {
  Reconstruction rec;
  rec.cameras = {Camera{}};
  rec.cameras[0].width = kWidth;
  rec.cameras[0].height = kHeightPx;
  rec.cameras[0].fx = rec.cameras[0].fy = kFocal;
  Image im;
  im.camera = 0;
  im.pose.R << 1, 0, 0, 0, -1, 0, 0, 0, -1;
  im.pose.c = Eigen::Vector3d(5, 5, kHeight);
  rec.images = {im};
  for (int k = 0; k < 100; ++k) {
    Point3D pt;
    pt.X = Eigen::Vector3d(k % 10, k / 10, 0.1 * (k % 3));
    pt.track = {{0, k}};
    rec.points.push_back(pt);
  }
  ReconstructionOptions o = SurveyOptions();
  o.dense = true;  // asked for, made nothing
  o.dsm_cell_m = 1.0;
  nlohmann::json js;
  const SurfaceModel surface = FuseAndRasterize(DenseCloud{}, rec, o, &js);
  EXPECT_EQ(js["dsm_source"], "sparse");
  ASSERT_EQ(js["warnings"].size(), 1u);
  EXPECT_NE(js["warnings"][0].get<std::string>().find("dense matching made no point"), std::string::npos);
  EXPECT_EQ(surface.cloud.size(), rec.points.size());
  EXPECT_EQ(surface.grid.width, 10);
  EXPECT_EQ(surface.grid.height, 10);
  ASSERT_EQ(surface.dsm.size(), cv::Size(10, 10));
  // Every cell holds its point's height (north up: row 0 is the northernmost, y = 9).
  EXPECT_NEAR(surface.dsm(0, 0), 0.1 * (90 % 3), 1e-5);
  EXPECT_NEAR(surface.dsm(9, 4), 0.1 * (4 % 3), 1e-5);
  EXPECT_EQ(cv::countNonZero(surface.dsm_provenance == 255), 100);
}

}  // namespace
}  // namespace uavm::sfm
