// Self-calibration of radial distortion from synthetic flights with a known lens: correspondences of a planar scene
// made with the true maps on ideal pixels, then recorded through the lens.
#include "core/adjust/lens_calibration.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "core/adjust/affine_adjuster.h"
#include "tests/edge_lists.h"

namespace uavm {
namespace {

constexpr int kW = 640;
constexpr int kH = 480;
constexpr double kFocal = 500.0;

struct Flight {
  std::vector<Mat3> mosaic_from_ideal;
  std::vector<Edge> edges;
};

// A 5 x 4 grid of frames (150 px apart across, 120 along: ~75 % overlap), each turned a little; every pair of frames
// closer than 260 px gets 60 matched points and 20 held-out ones, recorded through `lens` with `noise_px` (frames 10
// to 19, the second half, through `second_half_lens` when there is one).
Flight MakeFlight(const PinholeCamera& lens, double noise_px, unsigned seed,
                  const PinholeCamera* second_half_lens = nullptr) {
  Flight f;
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> turn(-0.15, 0.15);
  for (int row = 0; row < 4; ++row)
    for (int col = 0; col < 5; ++col) {
      const double a = turn(rng);
      Mat3 m = Mat3::Identity();
      m << std::cos(a), -std::sin(a), 150.0 * col, std::sin(a), std::cos(a), 120.0 * row, 0, 0, 1;
      f.mosaic_from_ideal.push_back(m);
    }
  std::uniform_real_distribution<double> ux(0, kW - 1), uy(0, kH - 1);
  std::normal_distribution<double> noise(0, noise_px);
  const auto inside = [](const Vec2& p) { return p.x() >= 0 && p.y() >= 0 && p.x() <= kW - 1 && p.y() <= kH - 1; };
  const auto lens_of = [&](int frame) -> const PinholeCamera& {
    return second_half_lens != nullptr && frame >= 10 ? *second_half_lens : lens;
  };
  const auto record = [&](int frame, const Vec2& ideal) -> Vec2 {
    return lens_of(frame).DistortPixel(ideal) + Vec2(noise(rng), noise(rng));
  };
  for (int i = 0; i < 20; ++i)
    for (int j = i + 1; j < 20; ++j) {
      const Mat3 tgt_from_src = f.mosaic_from_ideal[j].inverse() * f.mosaic_from_ideal[i];
      if (Apply(tgt_from_src, Vec2(kW / 2.0, kH / 2.0)).norm() > 1e9) continue;
      if ((f.mosaic_from_ideal[i].col(2) - f.mosaic_from_ideal[j].col(2)).norm() > 260) continue;
      Edge e;
      e.src = i;
      e.tgt = j;
      test::EdgeLists lists;
      for (int tries = 0; lists.holdout_src.size() < 20 && tries < 20000; ++tries) {
        const Vec2 p(ux(rng), uy(rng));
        const Vec2 q = Apply(tgt_from_src, p);
        // Recorded pixels must exist: the distorted positions inside the frame.
        if (!inside(q) || !inside(lens_of(i).DistortPixel(p)) || !inside(lens_of(j).DistortPixel(q))) continue;
        const bool kept = lists.src.size() < 60;
        (kept ? lists.src : lists.holdout_src).push_back(record(i, p).cast<float>());
        (kept ? lists.tgt : lists.holdout_tgt).push_back(record(j, q).cast<float>());
      }
      e.points = lists.Build();
      e.num_inliers = static_cast<int>(e.points.size());
      if (e.points.size() == 60) f.edges.push_back(std::move(e));
    }
  return f;
}

struct Solved {
  std::vector<const Edge*> edges;
  std::unordered_set<int> variable;
  std::unordered_map<int, double> half_diagonal;
  std::unordered_map<int, Mat3> linear;
};

Solved SolveLinear(const Flight& f) {
  Solved s;
  for (const auto& e : f.edges) s.edges.push_back(&e);
  for (int i = 0; i < 20; ++i) {
    s.linear[i] = i == 0 ? Mat3::Identity() : Translation(150.0 * (i % 5), 120.0 * (i / 5));
    s.half_diagonal[i] = 0.5 * std::hypot(kW, kH);
    if (i > 0) s.variable.insert(i);
  }
  EXPECT_TRUE(AdjustAffine(s.edges, s.variable, s.half_diagonal, AdjustOptions{}, &s.linear).ok);
  return s;
}

PinholeCamera Ideal() {
  return PinholeCamera::Centred(kW, kH, kFocal, {});
}

// A radial lens with k1 only, moving the half-diagonal by `share` of its radius (negative: barrel).
PinholeCamera BarrelLens(double share) {
  PinholeCamera lens = Ideal();
  lens.distortion.k1 = share / (lens.HalfDiagonalRadius() * lens.HalfDiagonalRadius());
  return lens;
}

LensCalibration Calibrate(const Solved& s, const PinholeCamera& prepared,
                          const LensCalibrationOptions& options = LensCalibrationOptions{},
                          const RefineOptions& refine = RefineOptions{}) {
  return CalibrateLens(s.edges, s.variable, 0, s.half_diagonal, refine, prepared, options, s.linear);
}

TEST(LensCalibrationTest, FindsABarrelLensFromTheFlightAlone) {
  // k1 such that the corners are drawn 10 % of their radius inwards, as a small drone camera's.
  const PinholeCamera truth = BarrelLens(-0.1);
  Flight f = MakeFlight(truth, 0.3, 1);
  Solved s = SolveLinear(f);
  const LensCalibration cal = Calibrate(s, Ideal());
  ASSERT_TRUE(cal.tried);
  EXPECT_TRUE(cal.accepted) << cal.why;
  PinholeCamera found = Ideal();
  found.distortion = cal.distortion;
  std::printf("truth %.4f at the half-diagonal, found %.4f (k1 %.4f k2 %.4f); held-out %.3f -> %.3f px\n",
              truth.RadialDistortionAtHalfDiagonal(), cal.distortion_at_half_diagonal, cal.distortion.k1,
              cal.distortion.k2, cal.holdout_without_px, cal.holdout_with_px);
  EXPECT_NEAR(cal.distortion_at_half_diagonal, -0.1, 0.01);
  // The recovered lens makes the same ideal image as the true one, up to a scale (which every frame's map absorbs):
  // within 0.5 px over the frame once that scale is fitted.
  const Vec2 c(truth.cx, truth.cy);
  double num = 0, den = 0;
  for (int y = 0; y < kH; y += 40)
    for (int x = 0; x < kW; x += 40) {
      const Vec2 f_ = found.UndistortPixel(Vec2(x, y)) - c, t_ = truth.UndistortPixel(Vec2(x, y)) - c;
      num += f_.dot(t_);
      den += f_.squaredNorm();
    }
  const double scale = num / den;
  double worst = 0;
  for (int y = 0; y < kH; y += 40)
    for (int x = 0; x < kW; x += 40)
      worst = std::max(
          worst, (scale * (found.UndistortPixel(Vec2(x, y)) - c) - (truth.UndistortPixel(Vec2(x, y)) - c)).norm());
  std::printf("ideal images agree within %.2f px after a scale of %.5f\n", worst, scale);
  EXPECT_LT(worst, 0.5);
  EXPECT_LT(cal.holdout_with_px, 0.3 * cal.holdout_without_px);
  EXPECT_LT(cal.holdout_with_px, 0.75);  // the noise floor: 0.3 px on each coordinate of both points is 0.6 px

  // The edges then move to the calibrated ideal pixels: a linear solve over them agrees with the truth's shape.
  for (auto& e : f.edges) ReprojectEdgePoints(Ideal(), cal.distortion, &e);
  std::unordered_map<int, Mat3> again = s.linear;
  ASSERT_TRUE(AdjustAffine(s.edges, s.variable, s.half_diagonal, AdjustOptions{}, &again).ok);
  EXPECT_LT(TransferErrors(s.edges, again, true).rms, 0.8);
}

// A flight beyond max_frames_per_solve is refined iteratively (SolveTreeLm, the lens a block shared by every edge):
// it finds the lens the factorisation (Ceres) finds.
TEST(LensCalibrationTest, TheIterativeSolveFindsTheFactorisationsLens) {
  const Flight f = MakeFlight(BarrelLens(-0.1), 0.3, 1);
  const Solved s = SolveLinear(f);
  const LensCalibration factored = Calibrate(s, Ideal());
  RefineOptions iterative;
  iterative.max_frames_per_solve = 4;
  const LensCalibration cal = Calibrate(s, Ideal(), LensCalibrationOptions{}, iterative);
  ASSERT_TRUE(factored.accepted) << factored.why;
  ASSERT_TRUE(cal.accepted) << cal.why;
  std::printf("at the half-diagonal: factored %.5f, iterative %.5f; held-out %.4f / %.4f px\n",
              factored.distortion_at_half_diagonal, cal.distortion_at_half_diagonal, factored.holdout_with_px,
              cal.holdout_with_px);
  EXPECT_NEAR(cal.distortion_at_half_diagonal, factored.distortion_at_half_diagonal, 5e-4);
  EXPECT_NEAR(cal.holdout_with_px, factored.holdout_with_px, 0.01 * factored.holdout_with_px);
}

TEST(LensCalibrationTest, AnIdealLensIsLeftAlone) {
  // Noise alone never passes the paired test: five flights of different noise draws.
  for (unsigned seed : {2u, 6u, 7u, 8u, 9u}) {
    Flight f = MakeFlight(Ideal(), 0.3, seed);
    Solved s = SolveLinear(f);
    const LensCalibration cal = Calibrate(s, Ideal());
    ASSERT_TRUE(cal.tried);
    EXPECT_FALSE(cal.accepted) << seed;
    EXPECT_LT(cal.holdout_gain_t, 3.0) << seed;
    EXPECT_NE(cal.why.find("does not determine"), std::string::npos) << cal.why;
    EXPECT_LT(std::abs(cal.distortion_at_half_diagonal), 0.01);
  }
}

TEST(LensCalibrationTest, APreparedLensIsRefinedFromItsStart) {
  // The points were made ideal with a database lens that is 40 % too weak: the calibration finds the rest.
  const PinholeCamera truth = BarrelLens(-0.1);
  Flight f = MakeFlight(truth, 0.3, 3);
  PinholeCamera prepared = Ideal();
  prepared.distortion.k1 = 0.6 * truth.distortion.k1;
  for (auto& e : f.edges)
    for (Vec2f& p : e.points.all()) p = prepared.UndistortPixel(p.cast<double>()).cast<float>();
  Solved s = SolveLinear(f);
  const LensCalibration cal = Calibrate(s, prepared);
  EXPECT_TRUE(cal.accepted) << cal.why;
  EXPECT_NEAR(cal.distortion_at_half_diagonal, -0.1, 0.01);
}

TEST(LensCalibrationTest, AFarWrongPreparedLensGivesWayToTheFlightsLens) {
  // caliterra's case: a database lens calibrated on raw files (-16 % there, -12 % here) on JPEGs the camera already
  // corrected (-1 % left). Its solve either finds the flight's lens or fails and says so (the engine then drops the
  // lens, RegistrationEngine::CalibrateLensAndResolve); it never accepts a lens far from the flight's.
  const PinholeCamera truth = BarrelLens(-0.01);
  Flight f = MakeFlight(truth, 0.3, 5);
  const PinholeCamera prepared = BarrelLens(-0.12);
  for (auto& e : f.edges)
    for (Vec2f& p : e.points.all()) p = prepared.UndistortPixel(p.cast<double>()).cast<float>();
  Solved s = SolveLinear(f);
  const LensCalibration from_wrong = Calibrate(s, prepared);
  std::printf("from the wrong lens: %s (%s)\n", from_wrong.accepted ? "accepted" : "refused", from_wrong.why.c_str());
  if (from_wrong.accepted)
    EXPECT_NEAR(from_wrong.distortion_at_half_diagonal, -0.01, 0.005);
  else
    EXPECT_TRUE(from_wrong.solve_failed) << from_wrong.why;
  // Dropped: the points back at their recorded pixels, maps solved linearly on them, the lens calibrated from none.
  for (auto& e : f.edges) ReprojectEdgePoints(prepared, LensDistortion{}, &e);
  s = SolveLinear(f);
  const LensCalibration cal = Calibrate(s, Ideal());
  std::printf("from the recorded pixels: found %.4f at the half-diagonal; held-out %.3f -> %.3f px\n",
              cal.distortion_at_half_diagonal, cal.holdout_without_px, cal.holdout_with_px);
  ASSERT_TRUE(cal.accepted) << cal.why;
  EXPECT_NEAR(cal.distortion_at_half_diagonal, -0.01, 0.003);
  EXPECT_LT(cal.holdout_with_px, 0.75);  // the noise floor: 0.3 px on each coordinate of both points is 0.6 px
}

TEST(LensCalibrationTest, TooFewFramesAreNotTried) {
  Flight f = MakeFlight(Ideal(), 0.3, 4);
  Solved s = SolveLinear(f);
  LensCalibrationOptions o;
  o.min_frames = 40;
  const LensCalibration cal = Calibrate(s, Ideal(), o);
  EXPECT_FALSE(cal.tried);
  EXPECT_NE(cal.why.find("too few frames"), std::string::npos);
}

TEST(LensCalibrationTest, HoldoutPairedGainIsThePerEdgeTStatistic) {
  // Four edges whose held-out points are off by a_i px without the lens and 1 px with it (translations): per-edge
  // drops a^2 - 1 of 0, 2, 3 and 4 px^2, whatever the number of points on each edge.
  const double a[4] = {1.0, std::sqrt(3.0), 2.0, std::sqrt(5.0)};
  std::vector<Edge> edges(4);
  std::unordered_map<int, Mat3> without, with;
  without[0] = with[0] = Mat3::Identity();
  for (int i = 0; i < 4; ++i) {
    edges[static_cast<size_t>(i)].src = i + 1;
    edges[static_cast<size_t>(i)].tgt = 0;
    test::EdgeLists lists;
    for (int k = 0; k < 5 + i; ++k) {
      lists.holdout_src.emplace_back(100.0 + 10 * k, 50.0 + 7 * k);
      lists.holdout_tgt.emplace_back(100.0 + 10 * k, 50.0 + 7 * k);
    }
    edges[static_cast<size_t>(i)].points = lists.Build();
    without[i + 1] = Translation(a[i], 0.0);
    with[i + 1] = Translation(0.0, 1.0);  // 1 px with the lens: drop a^2 - 1
  }
  std::vector<const Edge*> view;
  for (const auto& e : edges) view.push_back(&e);
  LensRefine identity;  // zero undistortion: Ideal() leaves points where they are
  identity.prepared = Ideal();
  const PairedGain gain = HoldoutPairedGain(view, without, with, identity);
  EXPECT_EQ(gain.edges, 4u);
  EXPECT_NEAR(gain.mean_drop_px2, 2.25, 1e-9);
  const double sd = std::sqrt((2.25 * 2.25 + 0.25 * 0.25 + 0.75 * 0.75 + 1.75 * 1.75) / 3.0);
  EXPECT_NEAR(gain.t, 2.25 / (sd / 2.0), 1e-9);
  // An edge whose frames have no map in one solve is not a sample; fewer than 3 samples give no statistic.
  without.erase(1);
  without.erase(2);
  EXPECT_EQ(HoldoutPairedGain(view, without, with, identity).edges, 2u);
  EXPECT_EQ(HoldoutPairedGain(view, without, with, identity).t, 0.0);
}

TEST(LensCalibrationTest, AWeakButConsistentLensIsAcceptedOnEvidenceNotOnSize) {
  // 0.3 % at the half-diagonal (1.2 px at the corners of a 640 x 480 frame): the held-out RMS drops by less than the
  // 3 % a fixed threshold would ask, yet the edges agree that the lens helps.
  Flight f = MakeFlight(BarrelLens(-0.003), 0.3, 5);
  Solved s = SolveLinear(f);
  const LensCalibration cal = Calibrate(s, Ideal());
  std::printf("held-out %.4f -> %.4f px, paired t %.2f over %zu edges, found %.4f\n", cal.holdout_without_px,
              cal.holdout_with_px, cal.holdout_gain_t, cal.holdout_edges, cal.distortion_at_half_diagonal);
  EXPECT_TRUE(cal.accepted) << cal.why;
  EXPECT_GT(cal.holdout_gain_t, 3.0);
  EXPECT_GT(cal.holdout_with_px, 0.97 * cal.holdout_without_px);
  EXPECT_NEAR(cal.distortion_at_half_diagonal, -0.003, 0.0015);
}

// What a lens absorbs that is not the lens (tilts, relief, a rolling shutter) changes along the flight; a lens does
// not. Here the first half of the flight is recorded through a barrel of 1 % at the half-diagonal and the second half
// through none: one shared lens fits the held-out points better (the paired test alone would take it), but the halves,
// estimated alone, disagree, and it is refused. Each half's own lens is what it was recorded with.
TEST(LensCalibrationTest, ALensTheHalvesOfTheFlightDisagreeOnIsRefused) {
  const PinholeCamera none = Ideal();
  Flight f = MakeFlight(BarrelLens(-0.01), 0.3, 7, &none);
  Solved s = SolveLinear(f);
  const LensCalibration cal = Calibrate(s, Ideal());
  ASSERT_TRUE(cal.tried);
  EXPECT_FALSE(cal.accepted);
  EXPECT_NE(cal.why.find("halves"), std::string::npos) << cal.why;
  EXPECT_GT(cal.holdout_gain_t, 3.0);  // what the paired test alone would have accepted
  EXPECT_NEAR(cal.half_a_at_half_diagonal, -0.01, 0.002);
  EXPECT_NEAR(cal.half_b_at_half_diagonal, 0.0, 0.002);
  // The same flight with one lens throughout: the halves agree and it is accepted.
  Flight one = MakeFlight(BarrelLens(-0.01), 0.3, 7);
  Solved s1 = SolveLinear(one);
  EXPECT_TRUE(Calibrate(s1, Ideal()).accepted);  // its held-out gain (16 %) is too large to ask the halves
  LensCalibrationOptions always;
  always.halves_below_gain = 0.99;
  const LensCalibration cal1 = Calibrate(s1, Ideal(), always);
  EXPECT_TRUE(cal1.accepted) << cal1.why;
  EXPECT_NEAR(cal1.half_a_at_half_diagonal, cal1.half_b_at_half_diagonal, 0.002);
  // With the check off, the paired test alone accepts the first flight's lens.
  LensCalibrationOptions off;
  off.max_halves_disagreement = 0;
  EXPECT_TRUE(Calibrate(s, Ideal(), off).accepted);
}

// A lens that moves the half-diagonal by less than min_effect_px is no lens, however significant.
TEST(LensCalibrationTest, ALensTooSmallToMatterIsRefused) {
  Flight f = MakeFlight(BarrelLens(-0.003), 0.3, 5);
  Solved s = SolveLinear(f);
  LensCalibrationOptions strict;
  strict.min_effect_px = 2.0;  // the lens moves the half-diagonal by ~1 px
  const LensCalibration cal = Calibrate(s, Ideal(), strict);
  EXPECT_FALSE(cal.accepted);
  EXPECT_NE(cal.why.find("too small to matter"), std::string::npos) << cal.why;
  EXPECT_TRUE(Calibrate(s, Ideal()).accepted);  // the default floor, a quarter pixel, lets it through
}

TEST(LensCalibrationTest, UndistortionAndDistortionConvertBothWays) {
  LensDistortion d;
  d.k1 = -0.16;
  d.k2 = 0.03;
  const auto u = UndistortionFromDistortion(d, 0.85);
  const LensDistortion back = DistortionFromUndistortion(u, 0.85);
  for (double r = 0.05; r <= 0.85; r += 0.05) {
    const double rd = d.Distort(Vec2(r, 0)).x();
    const double rd2 = rd * rd;
    EXPECT_NEAR(rd * (1 + rd2 * (u[0] + rd2 * (u[1] + rd2 * u[2]))), r, 2e-4) << r;  // the fit of the inverse
    EXPECT_NEAR(back.Distort(Vec2(r, 0)).x(), rd, 2e-4) << r;
  }
}

// A lens followed by a small correction is one Brown lens again: a barrel with k1 alone, corrected by a lens with k2
// alone, composes to (k1, k2) up to the second-order cross terms (checked against the two applied in turn), and a zero
// correction gives the first lens back.
TEST(LensCalibrationTest, ALensAndItsCorrectionComposeToOneLens) {
  LensDistortion first;
  first.k1 = -0.2;
  LensDistortion correction;
  correction.k1 = -0.004;
  correction.k2 = 0.002;
  const LensDistortion composed = ComposeRadial(first, correction, 0.8);
  for (double r = 0.05; r <= 0.95; r += 0.05) {  // ideal radii up to the recorded 0.8's
    const double both = first.Distort(correction.Distort(Vec2(r, 0))).x();
    EXPECT_NEAR(composed.Distort(Vec2(r, 0)).x(), both, 1e-4) << r;
  }
  const LensDistortion alone = ComposeRadial(first, LensDistortion{}, 0.8);
  EXPECT_NEAR(alone.k1, first.k1, 1e-9);
  EXPECT_NEAR(alone.k2, 0.0, 1e-9);
}

}  // namespace
}  // namespace uavm
