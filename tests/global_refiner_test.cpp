#include "core/adjust/global_refiner.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <iostream>
#include <opencv2/calib3d.hpp>
#include <random>

#include "core/adjust/affine_adjuster.h"
#include "tests/edge_lists.h"

namespace uavm {
namespace {

constexpr int kW = 640;
constexpr int kH = 480;
constexpr double kFocal = 600.0;  // px; altitude = focal, so 1 ground unit per pixel at nadir

// ground_from_frame of a pinhole camera at (cx, cy, kFocal) looking down, turned by `yaw` about the vertical and
// tilted by (tilt_x, tilt_y) rad about its own axes.
Mat3 CameraMap(double cx, double cy, double yaw, double tilt_x, double tilt_y) {
  Eigen::Matrix3d K;
  K << kFocal, 0, 0.5 * (kW - 1), 0, kFocal, 0.5 * (kH - 1), 0, 0, 1;
  const Eigen::Matrix3d nadir = Eigen::Vector3d(1, -1, -1).asDiagonal();  // camera z = world down
  const Eigen::Matrix3d R = Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()).toRotationMatrix() * nadir *
                            Eigen::AngleAxisd(tilt_x, Eigen::Vector3d::UnitX()).toRotationMatrix() *
                            Eigen::AngleAxisd(tilt_y, Eigen::Vector3d::UnitY()).toRotationMatrix();
  Mat3 scale_z = Mat3::Identity();
  scale_z(0, 0) = -kFocal;
  scale_z(1, 1) = -kFocal;
  // Image y runs down, ground y north: flip y so the maps keep their orientation (no mirror), as a mosaic does.
  const Mat3 flip_y = Eigen::Vector3d(1, -1, 1).asDiagonal();
  Mat3 H = Translation(cx, cy) * flip_y * scale_z * R * K.inverse();
  return H / H(2, 2);
}

Mat3 AffinePart(const Mat3& h) {
  // First-order map at the frame centre: the affine a nadir solver would start from.
  const Vec2 c(0.5 * (kW - 1), 0.5 * (kH - 1));
  const Vec2 c0 = Apply(h, c);
  const Vec2 dx = Apply(h, c + Vec2(1, 0)) - c0;
  const Vec2 dy = Apply(h, c + Vec2(0, 1)) - c0;
  Mat3 a = Mat3::Identity();
  a.block<2, 1>(0, 0) = dx;
  a.block<2, 1>(0, 1) = dy;
  a.block<2, 1>(0, 2) = c0 - dx * c.x() - dy * c.y();
  return a;
}

// Lawn-mower flight: 4 strips of 8 frames, 75 % forward and 40 % side overlap, return strips turned 180 degrees,
// each frame tilted up to `tilt_deg` at random. Edges between frames whose centres are close, 40 correspondences each.
struct Scene {
  std::vector<Mat3> truth;
  std::vector<Edge> edges;
};

Scene MakeScene(double tilt_deg, double noise_px, unsigned seed) {
  Scene s;
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> tilt(-tilt_deg * M_PI / 180, tilt_deg * M_PI / 180);
  for (int strip = 0; strip < 4; ++strip)
    for (int k = 0; k < 8; ++k) {
      const bool back = strip % 2 == 1;
      const double x = 160.0 * (back ? 7 - k : k);
      s.truth.push_back(CameraMap(x, 288.0 * strip, back ? M_PI : 0.0, tilt(rng), tilt(rng)));
    }
  std::normal_distribution<double> noise(0, noise_px);
  std::uniform_real_distribution<double> ux(0, kW - 1);
  std::uniform_real_distribution<double> uy(0, kH - 1);
  const Vec2 centre(0.5 * (kW - 1), 0.5 * (kH - 1));
  for (int i = 0; i < static_cast<int>(s.truth.size()); ++i)
    for (int j = i + 1; j < static_cast<int>(s.truth.size()); ++j) {
      const Mat3& ti = s.truth[static_cast<size_t>(i)];
      const Mat3& tj = s.truth[static_cast<size_t>(j)];
      if ((Apply(ti, centre) - Apply(tj, centre)).norm() > 400) continue;
      Edge e;
      e.src = i;
      e.tgt = j;
      e.tgt_from_src = tj.inverse() * ti;
      test::EdgeLists lists;
      for (int tries = 0; lists.src.size() < 40 && tries < 4000; ++tries) {
        const Vec2 p(ux(rng), uy(rng));
        const Vec2 q = Apply(e.tgt_from_src, p);
        if (q.x() < 0 || q.y() < 0 || q.x() > kW - 1 || q.y() > kH - 1) continue;
        lists.src.push_back((p + Vec2(noise(rng), noise(rng))).cast<float>());
        lists.tgt.push_back((q + Vec2(noise(rng), noise(rng))).cast<float>());
      }
      e.points = lists.Build();
      if (e.points.size() >= 20) s.edges.push_back(std::move(e));
    }
  return s;
}

std::vector<const Edge*> Pointers(const std::vector<Edge>& edges) {
  std::vector<const Edge*> out;
  for (const auto& e : edges) out.push_back(&e);
  return out;
}

// Error of a solution against the truth with the mosaic's overall frame fitted away (one global homography over a
// grid of every frame), in frame pixels: RMS and max.
std::pair<double, double> ModelFreeError(const Scene& s, const std::unordered_map<int, Mat3>& solution) {
  std::vector<cv::Point2d> from;
  std::vector<cv::Point2d> to;
  std::vector<std::pair<size_t, Vec2>> where;
  for (size_t i = 0; i < s.truth.size(); ++i)
    for (int gy = 0; gy <= 4; ++gy)
      for (int gx = 0; gx <= 4; ++gx) {
        const Vec2 p(gx * (kW - 1) / 4.0, gy * (kH - 1) / 4.0);
        const Vec2 m = Apply(solution.at(static_cast<int>(i)), p);
        const Vec2 g = Apply(s.truth[i], p);
        from.emplace_back(m.x(), m.y());
        to.emplace_back(g.x(), g.y());
        where.emplace_back(i, p);
      }
  const cv::Mat G = cv::findHomography(from, to, 0);
  Mat3 g;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) g(r, c) = G.at<double>(r, c);
  double sq = 0;
  double mx = 0;
  for (size_t k = 0; k < from.size(); ++k) {
    // Back into the frame: ground error divided by the local scale (about 1 here).
    const double e = (Apply(g, Vec2(from[k].x, from[k].y)) - Vec2(to[k].x, to[k].y)).norm();
    sq += e * e;
    mx = std::max(mx, e);
  }
  return {std::sqrt(sq / static_cast<double>(from.size())), mx};
}

// The pipeline's order: linear affine adjustment (anchored on frame 0), then the refinement.
std::unordered_map<int, Mat3> AffineStart(const Scene& s) {
  std::unordered_map<int, Mat3> T;
  std::unordered_set<int> variable;
  std::unordered_map<int, double> hd;
  for (size_t i = 0; i < s.truth.size(); ++i) {
    T[static_cast<int>(i)] = AffinePart(s.truth[0]) * Translation(160.0 * static_cast<double>(i % 8), 0);
    if (i > 0) variable.insert(static_cast<int>(i));
    hd[static_cast<int>(i)] = 400.0;
  }
  const auto r = AdjustAffine(Pointers(s.edges), variable, hd, AdjustOptions{}, &T);
  EXPECT_TRUE(r.ok) << r.failure;
  return T;
}

std::unordered_map<int, double> HalfDiagonals(size_t n) {
  std::unordered_map<int, double> hd;
  for (size_t i = 0; i < n; ++i) hd[static_cast<int>(i)] = 400.0;
  return hd;
}

std::unordered_set<int> AllButFirst(size_t n) {
  std::unordered_set<int> v;
  for (size_t i = 1; i < n; ++i) v.insert(static_cast<int>(i));
  return v;
}

TEST(GlobalRefiner, NoiseFreeTiltedFlightIsRecoveredExactly) {
  const Scene s = MakeScene(1.5, 0.0, 3);
  auto T = AffineStart(s);
  const auto [affine_rms, affine_max] = ModelFreeError(s, T);
  RefineOptions o;
  o.model = MotionModel::kHomography;
  const RefineResult r =
      RefineGlobal(Pointers(s.edges), AllButFirst(s.truth.size()), 0, HalfDiagonals(s.truth.size()), o, &T);
  ASSERT_TRUE(r.ok) << r.failure;
  const auto [rms, max] = ModelFreeError(s, T);
  EXPECT_GT(affine_rms, 0.5);  // a 1.5 degree tilt is beyond what an affine explains
  EXPECT_LT(rms, 0.02) << "affine start " << affine_rms;
  EXPECT_LT(max, 0.1);
  EXPECT_LT(r.final_rms_px, 0.01);
  EXPECT_GT(r.initial_rms_px, 0.5);
}

TEST(GlobalRefiner, HomographyBeatsTheAffineFloorWithNoise) {
  const Scene s = MakeScene(1.0, 0.3, 5);
  auto start = AffineStart(s);
  RefineOptions o;
  o.model = MotionModel::kAffine;
  auto affine = start;
  ASSERT_TRUE(
      RefineGlobal(Pointers(s.edges), AllButFirst(s.truth.size()), 0, HalfDiagonals(s.truth.size()), o, &affine).ok);
  o.model = MotionModel::kHomography;
  auto homography = start;
  const RefineResult r =
      RefineGlobal(Pointers(s.edges), AllButFirst(s.truth.size()), 0, HalfDiagonals(s.truth.size()), o, &homography);
  ASSERT_TRUE(r.ok) << r.failure;
  const auto [affine_rms, affine_max] = ModelFreeError(s, affine);
  const auto [rms, max] = ModelFreeError(s, homography);
  std::cerr << "model-free error RMS / max px: affine " << affine_rms << " / " << affine_max << ", homography " << rms
            << " / " << max << "\n";
  EXPECT_LT(rms, 0.3);
  EXPECT_LT(max, 1.5);
  EXPECT_LT(rms, 0.3 * affine_rms);
  // Every affine frame keeps a (0, 0, 1) last row.
  for (const auto& [id, m] : affine) EXPECT_TRUE(IsAffine(m, 1e-12)) << id;
}

// The linear adjustment measures residuals in mosaic pixels, so with noisy matches it gains by shrinking every frame
// towards the fixed anchor; the transfer error has no such pull. Nadir frames, 1 px noise: the refined affine keeps
// every frame's scale and position relative to the anchor.
// Mean over frames of each frame's scale relative to the truth's, with the anchor (frame 0) at the truth's map.
double MeanRelativeScale(const Scene& s, const std::unordered_map<int, Mat3>& T) {
  const Mat3 mosaic_from_ground = T.at(0) * s.truth[0].inverse();
  double sum = 0;
  for (size_t i = 1; i < s.truth.size(); ++i)
    sum += Decompose(T.at(static_cast<int>(i))).scale / Decompose(mosaic_from_ground * s.truth[i]).scale;
  return sum / static_cast<double>(s.truth.size() - 1);
}

// The linear adjustment measures residuals in mosaic pixels, so with noisy matches it gains by shrinking every frame
// towards the fixed anchor; the transfer error has no such pull. Nadir frames, 1 px noise, 8 flights: the linear
// solution is smaller than the truth on average, the refined one is not.
TEST(GlobalRefiner, AffineRefinementHasNoShrinkBias) {
  double linear_sum = 0;
  double refined_sum = 0;
  constexpr int kFlights = 8;
  for (unsigned seed = 0; seed < kFlights; ++seed) {
    const Scene s = MakeScene(0.0, 1.0, 100 + seed);
    auto T = AffineStart(s);
    linear_sum += MeanRelativeScale(s, T);
    RefineOptions o;
    o.model = MotionModel::kAffine;
    const RefineResult r =
        RefineGlobal(Pointers(s.edges), AllButFirst(s.truth.size()), 0, HalfDiagonals(s.truth.size()), o, &T);
    ASSERT_TRUE(r.ok) << r.failure;
    refined_sum += MeanRelativeScale(s, T);
  }
  const double linear_bias = linear_sum / kFlights - 1.0;
  const double refined_bias = refined_sum / kFlights - 1.0;
  EXPECT_LT(linear_bias, -1e-3);  // the bias this refinement exists to remove
  EXPECT_LT(std::abs(refined_bias), 0.25 * std::abs(linear_bias)) << "linear " << linear_bias;
  std::cerr << "mean relative scale - 1: linear " << linear_bias << ", refined " << refined_bias << "\n";
}

// 5 % of the correspondences are moved by 6-12 px (moving water, a repeated pattern): the outlier pass drops them
// and the maps are as good as without them.
TEST(GlobalRefiner, OutliersBeyondTheInlierThresholdAreDropped) {
  Scene s = MakeScene(1.0, 0.3, 21);
  std::mt19937 rng(4);
  std::uniform_real_distribution<double> u(0, 1);
  size_t injected = 0;
  for (auto& e : s.edges) {
    test::EdgeLists lists = test::ListsOf(e.points);
    for (auto& q : lists.tgt)
      if (u(rng) < 0.05) {
        const double a = 2 * M_PI * u(rng);
        q += ((6 + 6 * u(rng)) * Vec2(std::cos(a), std::sin(a))).cast<float>();
        ++injected;
      }
    e.points = lists.Build();
  }
  auto T = AffineStart(s);
  RefineOptions o;
  const RefineResult r =
      RefineGlobal(Pointers(s.edges), AllButFirst(s.truth.size()), 0, HalfDiagonals(s.truth.size()), o, &T);
  ASSERT_TRUE(r.ok) << r.failure;
  EXPECT_NEAR(static_cast<double>(r.outliers), static_cast<double>(injected), 0.1 * static_cast<double>(injected));
  EXPECT_LT(r.final_rms_px, 0.6);      // inliers: the 0.3 px noise on both sides, ~0.42 px per axis pair
  EXPECT_GT(r.final_all_rms_px, 1.5);  // the outliers are still there when all are counted
  const auto [rms, max] = ModelFreeError(s, T);
  EXPECT_LT(rms, 0.3);
  EXPECT_LT(max, 1.5);
}

TEST(GlobalRefiner, FixedFramesStayAndOptionsAreChecked) {
  const Scene s = MakeScene(1.0, 0.0, 9);
  std::unordered_map<int, Mat3> T;
  for (size_t i = 0; i < s.truth.size(); ++i) T[static_cast<int>(i)] = s.truth[i];
  // Only frame 5 is variable, started off by a few pixels; everything else is the truth and stays.
  T[5] = Translation(3, -2) * s.truth[5];
  RefineOptions o;
  const RefineResult r = RefineGlobal(Pointers(s.edges), {5}, -1, HalfDiagonals(s.truth.size()), o, &T);
  ASSERT_TRUE(r.ok) << r.failure;
  EXPECT_EQ(r.num_variables, 1u);
  for (const Vec2& c : ImageCorners(kW, kH)) EXPECT_LT((Apply(T.at(5), c) - Apply(s.truth[5], c)).norm(), 0.01);
  EXPECT_EQ(T.at(4), s.truth[4]);

  // A perspective beyond max_perspective_ratio is refused and nothing is changed.
  auto tilted = AffineStart(s);
  const auto before = tilted;
  RefineOptions strict;
  strict.max_perspective_ratio = 1.0001;
  const RefineResult refused =
      RefineGlobal(Pointers(s.edges), AllButFirst(s.truth.size()), 0, HalfDiagonals(s.truth.size()), strict, &tilted);
  EXPECT_FALSE(refused.ok);
  EXPECT_NE(refused.failure.find("implausible perspective"), std::string::npos) << refused.failure;
  for (const auto& [id, m] : before) EXPECT_EQ(tilted.at(id), m);

  std::string why;
  o.huber_px = 0;
  EXPECT_FALSE(o.Check(&why));
  EXPECT_FALSE(why.empty());
  MotionModel m = MotionModel::kAffine;
  EXPECT_TRUE(ParseMotionModel("homography", &m));
  EXPECT_EQ(m, MotionModel::kHomography);
  EXPECT_FALSE(ParseMotionModel("projective-ish", &m));
}

}  // namespace
}  // namespace uavm

namespace uavm {
namespace {

// A set of frames larger than max_frames_per_solve is solved by conjugate gradients (bounded memory at the end of a
// long flight, no factorisation): on a tilted, noisy flight it reaches the factorisation's solution, against the
// truth as well as in transfer error. (Windows of frames solved in turn with the others fixed, tried before, fitted the
// transfers within 4 % but left 0.5-0.8 px against the truth where one solve had 0.18: the tilts are a soft mode of
// the problem that block sweeps relax only slowly.)
TEST(GlobalRefiner, ConjugateGradientsReachTheFactorisationsSolution) {
  const Scene s = MakeScene(1.0, 0.3, 5);
  const auto start = AffineStart(s);
  RefineOptions o;
  o.model = MotionModel::kHomography;
  auto direct = start;
  const RefineResult rd =
      RefineGlobal(Pointers(s.edges), AllButFirst(s.truth.size()), 0, HalfDiagonals(s.truth.size()), o, &direct);
  ASSERT_TRUE(rd.ok) << rd.failure;
  EXPECT_FALSE(rd.iterative);
  o.max_frames_per_solve = 16;
  auto iterative = start;
  const RefineResult r =
      RefineGlobal(Pointers(s.edges), AllButFirst(s.truth.size()), 0, HalfDiagonals(s.truth.size()), o, &iterative);
  ASSERT_TRUE(r.ok) << r.failure;
  EXPECT_TRUE(r.iterative);
  const auto [start_rms, start_max] = ModelFreeError(s, start);
  const auto [direct_rms, direct_max] = ModelFreeError(s, direct);
  const auto [rms, max] = ModelFreeError(s, iterative);
  std::cerr << "model-free error RMS px: affine start " << start_rms << ", factored " << direct_rms
            << ", conjugate gradients " << rms << "; transfer RMS " << rd.final_all_rms_px << ", " << r.final_all_rms_px
            << "\n";
  EXPECT_LT(r.final_all_rms_px, 1.01 * rd.final_all_rms_px);
  EXPECT_LT(rms, 1.05 * direct_rms);
  EXPECT_LT(rms, 0.2 * start_rms);
  EXPECT_EQ(r.num_variables, s.truth.size() - 1);
  EXPECT_NEAR(r.initial_rms_px, rd.initial_rms_px, 1e-9);
  // A solve that fails (a perspective beyond what is allowed) leaves every map at its start.
  o.max_perspective_ratio = 1.0000001;
  auto failed = start;
  const RefineResult rf =
      RefineGlobal(Pointers(s.edges), AllButFirst(s.truth.size()), 0, HalfDiagonals(s.truth.size()), o, &failed);
  EXPECT_FALSE(rf.ok);
  for (const auto& [id, m] : failed) EXPECT_TRUE(m.isApprox(start.at(id), 1e-15)) << id;
}

// The whole scene refined from `maps` with every frame but the first variable.
RefineResult RefineScene(const Scene& s, const RefineOptions& o, std::unordered_map<int, Mat3>* maps) {
  return RefineGlobal(Pointers(s.edges), AllButFirst(s.truth.size()), 0, HalfDiagonals(s.truth.size()), o, maps);
}

// A flight long enough that the correspondence cap leaves its edges 3 points each (beyond ~5000 frames at the
// defaults: 12 points an edge, stride 4) still has a spanning tree to precondition the iterative solve: its edges
// keep 4. (Before, the tree was empty and Ceres refused the problem: the flight kept its linear solution.)
TEST(GlobalRefiner, ACapThatLeavesEdgesThreePointsStillRefinesIteratively) {
  Scene s = MakeScene(1.0, 0.3, 5);
  size_t total = 0;
  for (Edge& e : s.edges) {
    e.points.Thin(12, 0);
    total += e.points.size();
  }
  const auto start = AffineStart(s);
  RefineOptions o;
  o.model = MotionModel::kHomography;
  o.max_frames_per_solve = 16;
  o.max_correspondences = static_cast<int>(total / 4);  // stride 4: 3 of an edge's 12 points
  ASSERT_GE(o.max_correspondences, 100);
  auto capped = start;
  const RefineResult r = RefineScene(s, o, &capped);
  ASSERT_TRUE(r.ok) << r.failure;
  EXPECT_TRUE(r.iterative);
  // The cap plus at most a point for each tree edge (one fewer than the frames).
  EXPECT_LE(r.num_used, total / 4 + s.truth.size());
  // Against the factorisation on the same cap (3 points an edge: no tree needed).
  o.max_frames_per_solve = 600;
  auto factored = start;
  const RefineResult rd = RefineScene(s, o, &factored);
  ASSERT_TRUE(rd.ok) << rd.failure;
  const auto [start_rms, start_max] = ModelFreeError(s, start);
  const auto [direct_rms, direct_max] = ModelFreeError(s, factored);
  const auto [rms, max] = ModelFreeError(s, capped);
  std::cerr << "model-free error RMS px: affine start " << start_rms << ", factored on 3 points an edge " << direct_rms
            << ", iterative on 3-4 " << rms << "\n";
  EXPECT_LT(rms, 1.1 * direct_rms);
  EXPECT_LT(rms, 0.5 * start_rms);
}

}  // namespace
}  // namespace uavm
