#include "core/radiometry/radiometry.h"

#include <gtest/gtest.h>

#include <cmath>
#include <opencv2/imgproc.hpp>
#include <random>

namespace uavm {
namespace {

// Truth: a corner falloff of 0.6 in green (cos^4-like), slightly different in blue and red; gains within +-25 %.
double TrueLogFalloff(int c, double r2) {
  const double corner[3] = {0.55, 0.6, 0.65};
  // log V = c1 r^2 + c2 r^4 with c2 = -0.2 c1, V(1) = corner.
  const double c1 = std::log(corner[c]) / 0.8;
  return c1 * r2 - 0.2 * c1 * r2 * r2;
}

std::vector<RadiometrySample> SyntheticSamples(const std::vector<cv::Vec3d>& log_gain, double noise, int outliers,
                                               std::mt19937* rng, int per_edge = 64) {
  std::uniform_real_distribution<double> u(-0.8, 0.8), v(-0.6, 0.6), scene(30.0, 200.0);
  std::normal_distribution<double> n01(0.0, noise);
  std::vector<RadiometrySample> samples;
  const int frames = static_cast<int>(log_gain.size());
  for (int a = 0; a + 1 < frames; ++a)
    for (int b : {a + 1, a + 5}) {
      if (b >= frames) continue;
      for (int k = 0; k < per_edge; ++k) {
        RadiometrySample s;
        s.a = a;
        s.b = b;
        s.in_a = {static_cast<float>(u(*rng)), static_cast<float>(v(*rng)), 0.0f};
        s.in_b = {static_cast<float>(u(*rng)), static_cast<float>(v(*rng)), 0.0f};
        const double l = std::log(scene(*rng));
        for (int c = 0; c < 3; ++c) {
          s.log_a[c] =
              static_cast<float>(l + log_gain[static_cast<size_t>(a)][c] + TrueLogFalloff(c, s.in_a.R2()) + n01(*rng));
          s.log_b[c] =
              static_cast<float>(l + log_gain[static_cast<size_t>(b)][c] + TrueLogFalloff(c, s.in_b.R2()) + n01(*rng));
        }
        samples.push_back(s);
      }
    }
  // Moving objects: a few samples that disagree wildly.
  for (int k = 0; k < outliers; ++k) samples[static_cast<size_t>(k * 7 % samples.size())].log_a += cv::Vec3f(1, 1, 1);
  return samples;
}

// Frames 0..count-1 with grey exposures within +-20 % (one draw each, in frame order).
void GreyExposures(int count, std::mt19937* rng, std::vector<cv::Vec3d>* log_gain, std::vector<int>* frames) {
  std::uniform_real_distribution<double> g(std::log(0.8), std::log(1.2));
  for (int i = 0; i < count; ++i) {
    const double e = g(*rng);
    log_gain->push_back({e, e, e});
    frames->push_back(i);
  }
}

// A long flight's edges share max_samples (SolveEndRadiometry): down to one point per edge. One per edge over 1000
// frames (~2000 edges: enough for the held-out fifth that chooses the terms) still ties every frame's gain and fits
// the falloff.
TEST(RadiometryTest, OneSamplePerEdgeStillFindsEveryGain) {
  std::mt19937 rng(5);
  constexpr int kFrames = 1000;
  std::vector<cv::Vec3d> log_gain;
  std::vector<int> frames;
  GreyExposures(kFrames, &rng, &log_gain, &frames);
  const auto samples = SyntheticSamples(log_gain, 0.01, 0, &rng, 1);
  ASSERT_LT(samples.size(), 2000u);
  const RadiometryModel m = SolveRadiometry(samples, frames, RadiometryOptions{});
  ASSERT_TRUE(m.ok);
  ASSERT_TRUE(m.vignetting) << m.note;
  EXPECT_GT(m.holdout_cost[0], 0.0) << "the held-out edges chose the terms: " << m.note;
  EXPECT_NEAR(m.Falloff(1, 1.0), std::exp(TrueLogFalloff(1, 1.0)), 0.03);
  double mean = 0;
  for (const auto& lg : log_gain) mean += lg[1] / kFrames;
  double worst = 0;
  for (int i = 0; i < kFrames; ++i)
    worst = std::max(worst, std::abs(std::log(m.Gain(i)[1]) - (log_gain[static_cast<size_t>(i)][1] - mean)));
  EXPECT_LT(worst, 0.05);
}

// Beyond direct_max_frames the gains are solved by conjugate gradients instead of the sparse factorisation: the same
// model, with white balance, vignetting and outliers, on 1200 frames solved both ways.
TEST(RadiometryTest, IterativeSolveMatchesTheFactorisation) {
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> g(std::log(0.8), std::log(1.2));
  constexpr int kFrames = 1200;
  std::vector<cv::Vec3d> log_gain(kFrames);
  std::vector<int> frames;
  for (int i = 0; i < kFrames; ++i) {
    const double e = g(rng);
    log_gain[static_cast<size_t>(i)] = {e + 0.2 * g(rng), e, e + 0.2 * g(rng)};
    frames.push_back(i);
  }
  const auto samples = SyntheticSamples(log_gain, 0.01, 200, &rng, 16);
  RadiometryOptions direct;
  direct.direct_max_frames = kFrames;
  RadiometryOptions iterative;
  iterative.direct_max_frames = 0;
  const RadiometryModel a = SolveRadiometry(samples, frames, direct);
  const RadiometryModel b = SolveRadiometry(samples, frames, iterative);
  ASSERT_TRUE(a.ok && b.ok);
  EXPECT_FALSE(a.iterative);
  ASSERT_TRUE(b.iterative) << "above direct_max_frames the gains are solved by conjugate gradients";
  EXPECT_GT(b.most_iterative_steps, 1);
  EXPECT_LT(b.most_iterative_steps, iterative.max_iterative_steps);
  EXPECT_EQ(b.failed_solves, 0);
  ASSERT_TRUE(a.vignetting && b.vignetting);
  EXPECT_EQ(a.flat_field, b.flat_field);
  EXPECT_EQ(a.hotspot.found, b.hotspot.found);
  double worst = 0;
  for (int i = 0; i < kFrames; ++i)
    for (int c = 0; c < 3; ++c) worst = std::max(worst, std::abs(std::log(a.Gain(i)[c]) - std::log(b.Gain(i)[c])));
  EXPECT_LT(worst, 1e-6);
  for (int c = 0; c < 3; ++c) EXPECT_NEAR(a.Falloff(c, 1.0), b.Falloff(c, 1.0), 1e-6) << "channel " << c;
  EXPECT_NEAR(a.rms_log_after, b.rms_log_after, 1e-7);
  // And both find the truth (up to the common factor of each channel).
  double mean = 0;
  for (const auto& lg : log_gain) mean += lg[1] / kFrames;
  double off = 0;
  for (int i = 0; i < kFrames; ++i)
    off = std::max(off, std::abs(std::log(b.Gain(i)[1]) - (log_gain[static_cast<size_t>(i)][1] - mean)));
  EXPECT_LT(off, 0.05);
}

// Conjugate gradients that do not converge refuse the model (no correction, saying why) instead of handing on gains
// the solve never reached.
TEST(RadiometryTest, AnUnconvergedIterativeSolveRefusesTheModel) {
  std::mt19937 rng(13);
  constexpr int kFrames = 300;
  std::vector<cv::Vec3d> log_gain;
  std::vector<int> frames;
  GreyExposures(kFrames, &rng, &log_gain, &frames);
  const auto samples = SyntheticSamples(log_gain, 0.01, 0, &rng, 16);
  RadiometryOptions o;
  o.direct_max_frames = 0;
  const RadiometryModel enough = SolveRadiometry(samples, frames, o);
  ASSERT_TRUE(enough.ok) << enough.note;
  ASSERT_GT(enough.most_iterative_steps, 3);
  o.max_iterative_steps = 3;
  const RadiometryModel cut = SolveRadiometry(samples, frames, o);
  EXPECT_FALSE(cut.ok);
  EXPECT_TRUE(cut.iterative);
  EXPECT_GT(cut.failed_solves, 0);
  EXPECT_NE(cut.note.find("did not reach their tolerance (stopped after 3 of at most 3 steps)"), std::string::npos)
      << cut.note;
  EXPECT_EQ(cut.Gain(7), cv::Vec3d(1, 1, 1)) << "a refused model corrects nothing";
}

TEST(RadiometryTest, RecoversGainsAndFalloffFromPairs) {
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> g(std::log(0.75), std::log(1.25));
  std::vector<cv::Vec3d> log_gain(40);
  std::vector<int> frames;
  for (int i = 0; i < 40; ++i) {
    const double e = g(rng);
    log_gain[static_cast<size_t>(i)] = {e + 0.3 * g(rng), e, e + 0.3 * g(rng)};  // exposure and white balance
    frames.push_back(i);
  }
  const auto samples = SyntheticSamples(log_gain, 0.01, 100, &rng);
  const RadiometryModel m = SolveRadiometry(samples, frames, RadiometryOptions{});
  ASSERT_TRUE(m.ok);
  ASSERT_TRUE(m.vignetting) << m.note;
  for (int c = 0; c < 3; ++c) {
    EXPECT_NEAR(m.Falloff(c, 1.0), std::exp(TrueLogFalloff(c, 1.0)), 0.01) << "channel " << c;
    EXPECT_NEAR(m.Falloff(c, 0.5), std::exp(TrueLogFalloff(c, 0.5)), 0.01) << "channel " << c;
  }
  // Gains are known up to one common factor per channel (the mean frame keeps its brightness); within 2 %: the
  // Huber loss bounds, not removes, the pull of the outliers on frame 0, which has most of them, and the priors
  // (towards the mean exposure, and the stronger one towards no colour change) shrink the +-9 % white balance a little.
  for (int c = 0; c < 3; ++c) {
    double mean = 0;
    for (const auto& lg : log_gain) mean += lg[c] / 40;
    for (int i = 0; i < 40; ++i)
      EXPECT_NEAR(std::log(m.Gain(i)[c]), log_gain[static_cast<size_t>(i)][c] - mean, 0.02) << i << " " << c;
  }
  EXPECT_LT(m.rms_log_after, 0.3 * m.rms_log_before);
  EXPECT_FALSE(m.hotspot.found);  // none in the data: the held-out pairs keep the lens model
}

// A flight of three strips (the middle one flown the other way) under a high sun: every frame's gain, a 0.6-corner
// lens, and the opposition hotspot (log(1 + A exp(-d^2 / 2 w^2)) about the antisolar point, which turns with the
// heading), with an optional off-centre falloff. Samples at random places of both frames of each pair.
struct SunFlight {
  double hotspot = 0.35;
  double width = 0.22;                   // half-diagonals
  cv::Point2d antisolar{0.12, 0.30};     // at heading 0
  cv::Point2d falloff_centre{0.0, 0.0};  // the lens's falloff about this point
  [[nodiscard]] double TrueLogShading(const ImagePoint& p) const {
    const double du = p.u - falloff_centre.x;
    const double dv = p.v - falloff_centre.y;
    double s = TrueLogFalloff(1, du * du + dv * dv);
    Hotspot at;
    at.antisolar_u = antisolar.x;
    at.antisolar_v = antisolar.y;
    const cv::Point2d c = at.Centre(p.heading);
    const double d2 = (p.u - c.x) * (p.u - c.x) + (p.v - c.y) * (p.v - c.y);
    return s + std::log(1 + hotspot * std::exp(-d2 / (2 * width * width)));
  }
};

std::vector<RadiometrySample> SunFlightSamples(const SunFlight& flight, std::vector<double>* log_gain,
                                               std::mt19937* rng) {
  constexpr int kStrip = 20;
  std::uniform_real_distribution<double> u(-0.8, 0.8), v(-0.6, 0.6), scene(30.0, 200.0), g(-0.2, 0.2);
  std::normal_distribution<double> n01(0.0, 0.01);
  log_gain->clear();
  for (int i = 0; i < 3 * kStrip; ++i) log_gain->push_back(g(*rng));
  auto heading = [](int id) { return (id / kStrip) % 2 == 1 ? static_cast<float>(M_PI) : 0.0f; };
  std::vector<RadiometrySample> samples;
  for (int a = 0; a < 3 * kStrip; ++a)
    for (int b : {a + 1, a + 2, a + kStrip}) {
      if (b >= 3 * kStrip || (b < a + kStrip && b / kStrip != a / kStrip)) continue;
      for (int k = 0; k < 64; ++k) {
        RadiometrySample s;
        s.a = a;
        s.b = b;
        s.in_a = {static_cast<float>(u(*rng)), static_cast<float>(v(*rng)), heading(a)};
        s.in_b = {static_cast<float>(u(*rng)), static_cast<float>(v(*rng)), heading(b)};
        const double l = std::log(scene(*rng));
        s.log_a = cv::Vec3f::all(
            static_cast<float>(l + (*log_gain)[static_cast<size_t>(a)] + flight.TrueLogShading(s.in_a) + n01(*rng)));
        s.log_b = cv::Vec3f::all(
            static_cast<float>(l + (*log_gain)[static_cast<size_t>(b)] + flight.TrueLogShading(s.in_b) + n01(*rng)));
        samples.push_back(s);
      }
    }
  return samples;
}

// The frames SunFlightSamples flies (3 strips of 20).
std::vector<int> SunFlightFrames() {
  std::vector<int> frames(60);
  for (int i = 0; i < 60; ++i) frames[static_cast<size_t>(i)] = i;
  return frames;
}

// RMS over the frame and both headings of the fitted shading against the truth, up to a constant (the gauge the gains
// share).
double ShadingError(const RadiometryModel& m, const SunFlight& flight) {
  std::vector<double> d;
  for (float heading : {0.0f, static_cast<float>(M_PI)})
    for (float v = -0.58f; v <= 0.58f; v += 0.04f)
      for (float u = -0.78f; u <= 0.78f; u += 0.04f) {
        const ImagePoint p{u, v, heading};
        d.push_back(m.LogShading(1, p) - flight.TrueLogShading(p));
      }
  double mean = 0, sq = 0;
  for (double x : d) mean += x / static_cast<double>(d.size());
  for (double x : d) sq += (x - mean) * (x - mean) / static_cast<double>(d.size());
  return std::sqrt(sq);
}

TEST(RadiometryTest, FindsTheHotspotWhereTheSunPutsIt) {
  std::mt19937 rng(5);
  const SunFlight flight;
  std::vector<double> log_gain;
  const auto samples = SunFlightSamples(flight, &log_gain, &rng);
  const std::vector<int> frames = SunFlightFrames();
  const RadiometryModel m = SolveRadiometry(samples, frames, RadiometryOptions{});
  ASSERT_TRUE(m.ok) << m.note;
  ASSERT_TRUE(m.hotspot.found) << m.note;
  EXPECT_NEAR(m.hotspot.antisolar_u, flight.antisolar.x, 0.04);
  EXPECT_NEAR(m.hotspot.antisolar_v, flight.antisolar.y, 0.04);
  EXPECT_NEAR(std::exp(m.hotspot.LogBoost(0)), 1.35, 0.05);
  EXPECT_LT(m.holdout_cost[2], 0.5 * m.holdout_cost[0]);
  EXPECT_LT(ShadingError(m, flight), 0.02);
  // The radial model alone cannot take it.
  RadiometryOptions radial_only;
  radial_only.hotspot = false;
  radial_only.flat_field = false;
  EXPECT_GT(ShadingError(SolveRadiometry(samples, frames, radial_only), flight), 0.04);
  // Gains: their differences (the gauge is the mean frame).
  double mean_true = 0, mean_fit = 0;
  for (int i = 0; i < 60; ++i) {
    mean_true += log_gain[static_cast<size_t>(i)] / 60;
    mean_fit += std::log(m.Gain(i)[1]) / 60;
  }
  for (int i = 0; i < 60; ++i)
    EXPECT_NEAR(std::log(m.Gain(i)[1]) - mean_fit, log_gain[static_cast<size_t>(i)] - mean_true, 0.03) << i;
}

TEST(RadiometryTest, OffCentreFalloffKeepsTheFlatField) {
  std::mt19937 rng(6);
  SunFlight flight;
  flight.hotspot = 0.0;
  flight.falloff_centre = {0.12, -0.08};
  std::vector<double> log_gain;
  const auto samples = SunFlightSamples(flight, &log_gain, &rng);
  const std::vector<int> frames = SunFlightFrames();
  const RadiometryModel m = SolveRadiometry(samples, frames, RadiometryOptions{});
  ASSERT_TRUE(m.ok) << m.note;
  EXPECT_TRUE(m.flat_field);
  EXPECT_FALSE(m.hotspot.found);
  EXPECT_LT(ShadingError(m, flight), 0.015);
}

// Nothing beyond the lens: the held-out pairs keep the radial model alone.
TEST(RadiometryTest, NoSunNoHotspot) {
  std::mt19937 rng(7);
  SunFlight flight;
  flight.hotspot = 0.0;
  std::vector<double> log_gain;
  const auto samples = SunFlightSamples(flight, &log_gain, &rng);
  const std::vector<int> frames = SunFlightFrames();
  const RadiometryModel m = SolveRadiometry(samples, frames, RadiometryOptions{});
  ASSERT_TRUE(m.ok) << m.note;
  EXPECT_FALSE(m.flat_field);
  EXPECT_FALSE(m.hotspot.found);
  EXPECT_GT(m.holdout_cost[2], 0.0);  // tried
  EXPECT_LT(ShadingError(m, flight), 0.01);
}

// The end of the flight gives the heap's pages back once the terms are chosen (a hook): it runs once, after the
// held-out pairs were tried, and the model is the one without it to the last bit.
TEST(RadiometryTest, TheHookAfterTheChoiceOfTermsRunsOnceAndChangesNothing) {
  std::mt19937 rng(7);
  SunFlight flight;
  std::vector<double> log_gain;
  const auto samples = SunFlightSamples(flight, &log_gain, &rng);
  const std::vector<int> frames = SunFlightFrames();
  const RadiometryModel plain = SolveRadiometry(samples, frames, RadiometryOptions{});
  int calls = 0;
  const RadiometryModel hooked = SolveRadiometry(samples, frames, RadiometryOptions{}, [&] { ++calls; });
  EXPECT_EQ(calls, 1);
  ASSERT_TRUE(plain.ok && hooked.ok) << plain.note;
  EXPECT_EQ(hooked.holdout_cost, plain.holdout_cost);
  for (int id : frames) EXPECT_EQ(hooked.Gain(id), plain.Gain(id)) << id;
  RadiometryOptions gains_only;
  gains_only.flat_field = gains_only.hotspot = false;  // no choice to make: no hook
  calls = 0;
  EXPECT_TRUE(SolveRadiometry(samples, frames, gains_only, [&] { ++calls; }).ok);
  EXPECT_EQ(calls, 0);
}

// The correction of a frame with every term: a uniform grey ground comes back uniform, and the avoid disc sits at
// the antisolar point.
TEST(RadiometryTest, CorrectionRemovesTheHotspotAndFlatField) {
  RadiometryModel m;
  m.ok = true;
  m.vignetting = true;
  for (int c = 0; c < 3; ++c) m.log_falloff[static_cast<size_t>(c)] = {std::log(0.6) / 0.8, -0.2 * std::log(0.6) / 0.8};
  m.flat_field = true;
  m.log_flat = {0.05, -0.03, 0.02, 0.01, -0.04, 0.02};
  m.hotspot.found = true;
  m.hotspot.antisolar_u = 0.2;
  m.hotspot.antisolar_v = -0.1;
  m.hotspot.weights = {0.1, 0.15, 0.05};
  m.log_gain[3] = cv::Vec3d::all(std::log(1.1));
  const cv::Size size(600, 400);
  const double heading = 2.0;
  cv::Mat frame(size, CV_8UC3);
  const double hd = 0.5 * std::hypot(600.0, 400.0);
  for (int y = 0; y < size.height; ++y)
    for (int x = 0; x < size.width; ++x) {
      const ImagePoint p{static_cast<float>((x - 299.5) / hd), static_cast<float>((y - 199.5) / hd),
                         static_cast<float>(heading)};
      frame.at<cv::Vec3b>(y, x) = cv::Vec3b::all(cv::saturate_cast<uchar>(120 * 1.1 * std::exp(m.LogShading(1, p))));
    }
  cv::Mat part = frame(cv::Rect(37, 11, 500, 300)).clone();
  CorrectRadiometry(m, 3, heading, size, cv::Point2d(37, 11), &part);
  double lo = 0, hi = 0;
  cv::minMaxLoc(part.reshape(1), &lo, &hi);
  EXPECT_GE(lo, 118);
  EXPECT_LE(hi, 122);
  const AvoidDisc disc = HotspotDisc(m, heading, size);
  const cv::Point2d c = m.hotspot.Centre(heading);
  EXPECT_NEAR(disc.centre.x, 299.5 + c.x * hd, 1e-6);
  EXPECT_NEAR(disc.centre.y, 199.5 + c.y * hd, 1e-6);
  EXPECT_GT(disc.radius, 0.06 * hd - 1e-6);
  // The heading turns it: a frame turned by pi sees the antisolar point on the other side of its centre.
  EXPECT_NEAR(m.hotspot.Centre(M_PI).x, -0.2, 1e-9);
}

TEST(RadiometryTest, HeadingOfARotation) {
  const double angle = 0.7;
  Mat3 h = Mat3::Identity();
  h << 2 * std::cos(angle), -2 * std::sin(angle), 50, 2 * std::sin(angle), 2 * std::cos(angle), -20, 0, 0, 1;
  EXPECT_NEAR(HeadingOf(h, cv::Size(640, 480)), angle, 1e-9);
}

TEST(RadiometryTest, TooFewSamplesGiveGainsOnly) {
  std::mt19937 rng(5);
  std::vector<cv::Vec3d> log_gain(3, cv::Vec3d(0, 0, 0));
  log_gain[1] = {0.2, 0.2, 0.2};
  auto samples = SyntheticSamples(log_gain, 0.0, 0, &rng);
  samples.resize(40);
  const RadiometryModel m = SolveRadiometry(samples, {0, 1, 2}, RadiometryOptions{});
  ASSERT_TRUE(m.ok);
  EXPECT_FALSE(m.vignetting);
  EXPECT_FALSE(m.note.empty());
  EXPECT_EQ(m.Falloff(1, 1.0), 1.0);
  EXPECT_EQ(SolveRadiometry({}, {0, 1}, RadiometryOptions{}).ok, false);
}

// A flat grey ground seen through a vignetting lens by two frames shifted by a third of their width: the samples of
// their overlap carry exactly the falloff at both radii, and correcting each frame makes it flat again.
TEST(RadiometryTest, OverlapSamplesAndCorrectionOfRenderedFrames) {
  const cv::Size work(600, 400);
  RadiometryModel truth;
  truth.ok = true;
  truth.vignetting = true;
  for (int c = 0; c < 3; ++c)
    truth.log_falloff[static_cast<size_t>(c)] = {std::log(0.6) / 0.8, -0.2 * std::log(0.6) / 0.8};
  truth.log_gain[0] = {0, 0, 0};
  truth.log_gain[1] = {std::log(1.2), std::log(1.2), std::log(1.2)};
  std::vector<cv::Mat> frames;
  for (int id = 0; id < 2; ++id) {
    cv::Mat f(work, CV_8UC3);
    const double hd2 = (work.width * work.width + work.height * work.height) / 4.0;
    for (int y = 0; y < work.height; ++y)
      for (int x = 0; x < work.width; ++x) {
        const double r2 = ((x - 299.5) * (x - 299.5) + (y - 199.5) * (y - 199.5)) / hd2;
        f.at<cv::Vec3b>(y, x) =
            cv::Vec3b::all(cv::saturate_cast<uchar>(150 * truth.Gain(id)[0] * truth.Falloff(0, r2)));
      }
    frames.push_back(f);
  }
  std::vector<RadiometrySample> samples;
  const cv::Mat ta = MakeThumbnail(frames[0], 128), tb = MakeThumbnail(frames[1], 128);
  SampleOverlap({0, &ta, work, 0.0}, {1, &tb, work, 0.0}, Translation(-200, 0), 64, &samples);
  ASSERT_GE(samples.size(), 32u);
  EXPECT_LE(samples.size(), 64u);
  for (const auto& s : samples) {
    const double expected =
        std::log(truth.Falloff(0, s.in_a.R2())) - std::log(1.2) - std::log(truth.Falloff(0, s.in_b.R2()));
    EXPECT_NEAR(s.log_a[1] - s.log_b[1], expected, 0.02);
  }
  // Correction of a part of frame 1 at half resolution: flat at 150 grey levels.
  cv::Mat half;
  cv::resize(frames[1], half, cv::Size(300, 200), 0, 0, cv::INTER_AREA);
  cv::Mat part = half(cv::Rect(10, 20, 200, 150)).clone();
  CorrectRadiometry(truth, 1, 0.0, half.size(), cv::Point2d(10, 20), &part);
  double lo = 0, hi = 0;
  cv::minMaxLoc(part.reshape(1), &lo, &hi);
  EXPECT_GE(lo, 147);
  EXPECT_LE(hi, 153);
}

// The radial correction of a textured part inside the frame (odd sizes, full resolution and halved) against the model
// evaluated pixel by pixel: within the grey level its table over r^2 and the rounding allow; and a part corrected at
// its origin is, bit for bit, the same part of the whole frame corrected.
TEST(RadiometryTest, RadialCorrectionIsTheModelPixelByPixel) {
  RadiometryModel m;
  m.ok = true;
  m.vignetting = true;
  m.log_falloff = {std::array<double, 2>{-0.5, 0.1}, std::array<double, 2>{-0.6, 0.12},
                   std::array<double, 2>{-0.7, 0.15}};
  m.log_gain[7] = {std::log(0.9), std::log(1.05), std::log(1.2)};
  ASSERT_FALSE(m.BeyondRadial());
  cv::RNG rng(7);
  for (const cv::Size full : {cv::Size(1000, 750), cv::Size(500, 375)}) {
    const cv::Point2d origin(full.width / 7 + 0.0, full.height / 5 + 0.0);
    cv::Mat part(full.height / 2 + 3, full.width / 2 + 5, CV_8UC3);
    rng.fill(part, cv::RNG::UNIFORM, 20, 200);
    cv::Mat corrected = part.clone();
    CorrectRadiometry(m, 7, 0.0, full, origin, &corrected);
    const double hd = 0.5 * std::hypot(full.width, full.height);
    const cv::Vec3d gain = m.Gain(7);
    int worst = 0;
    for (int y = 0; y < part.rows; ++y)
      for (int x = 0; x < part.cols; ++x) {
        const double u = (origin.x + x - 0.5 * (full.width - 1)) / hd;
        const double v = (origin.y + y - 0.5 * (full.height - 1)) / hd;
        const double r2 = std::min(1.0, u * u + v * v);
        for (int c = 0; c < 3; ++c) {
          const double expected = part.at<cv::Vec3b>(y, x)[c] / (gain[c] * m.Falloff(c, r2));
          worst = std::max(worst, std::abs(corrected.at<cv::Vec3b>(y, x)[c] - cv::saturate_cast<uchar>(expected)));
        }
      }
    EXPECT_LE(worst, 1) << full;
    cv::Mat frame(full, CV_8UC3);
    rng.fill(frame, cv::RNG::UNIFORM, 20, 200);
    const cv::Rect rect(static_cast<int>(origin.x) + 1, static_cast<int>(origin.y) + 3, part.cols, part.rows);
    cv::Mat alone = frame(rect).clone();
    CorrectRadiometry(m, 7, 0.0, full, cv::Point2d(rect.tl()), &alone);
    CorrectRadiometry(m, 7, 0.0, full, cv::Point2d(), &frame);
    EXPECT_EQ(cv::norm(alone, frame(rect), cv::NORM_INF), 0.0) << full;
  }
}

// During the flight: frames of a textured ground seen through a 0.6-corner lens, each overlapping the previous two;
// after `solve_every` frames the live model has the lens's falloff (and no gains), from the window only.
TEST(RadiometryTest, LiveFitFindsTheVignettingFromRecentFrames) {
  const cv::Size work(600, 400);
  cv::Mat ground(work.height, work.width + 40 * 120, CV_8UC3);
  cv::randu(ground, cv::Scalar::all(60), cv::Scalar::all(200));
  cv::GaussianBlur(ground, ground, cv::Size(0, 0), 25);  // low-frequency texture: the thumbnails see the same values
  RadiometryModel lens;
  lens.ok = true;
  lens.vignetting = true;
  for (int c = 0; c < 3; ++c)
    lens.log_falloff[static_cast<size_t>(c)] = {std::log(0.6) / 0.8, -0.2 * std::log(0.6) / 0.8};
  const double hd2 = (work.width * work.width + work.height * work.height) / 4.0;
  LiveRadiometry live(RadiometryOptions{}, 24, 20);
  for (int id = 0; id < 30; ++id) {
    cv::Mat f = ground(cv::Rect(120 * id, 0, work.width, work.height)).clone();
    for (int y = 0; y < work.height; ++y)
      for (int x = 0; x < work.width; ++x) {
        const double v = lens.Falloff(0, ((x - 299.5) * (x - 299.5) + (y - 199.5) * (y - 199.5)) / hd2);
        auto& p = f.at<cv::Vec3b>(y, x);
        for (int c = 0; c < 3; ++c) p[c] = cv::saturate_cast<uchar>(p[c] * v);
      }
    live.AddFrame(id, MakeThumbnail(f, RadiometryOptions{}.thumb_long_side), f.size(), 0.0);
    for (int back : {1, 2, 3})  // frame id - back seen 120 * back px further along
      if (id - back >= 0) live.AddEdge(id, id - back, Translation(120.0 * back, 0));
    const bool solved = live.MaybeSolve();
    EXPECT_EQ(solved, id == 19) << id;  // 20 frames, then the next solve would come at 40
  }
  ASSERT_TRUE(live.model().ok);
  ASSERT_TRUE(live.model().vignetting);
  EXPECT_TRUE(live.model().log_gain.empty());
  for (int c = 0; c < 3; ++c) EXPECT_NEAR(live.model().Falloff(c, 1.0), 0.6, 0.03);
}

TEST(RadiometryTest, OptionsAreChecked) {
  std::string why;
  EXPECT_TRUE(RadiometryOptions{}.Check(&why)) << why;
  RadiometryOptions o;
  o.samples_per_edge = 0;
  EXPECT_FALSE(o.Check(&why));
  o = {};
  o.max_corner_falloff = 1.5;
  EXPECT_FALSE(o.Check(&why));
  o = {};
  o.max_iterative_steps = 0;
  EXPECT_FALSE(o.Check(&why));
  EXPECT_NE(why.find("max_iterative_steps"), std::string::npos);
  o = {};
  o.iterative_tolerance = 0;
  EXPECT_FALSE(o.Check(&why));
}

}  // namespace
}  // namespace uavm
