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
                                               std::mt19937* rng) {
  std::uniform_real_distribution<double> r2(0.0, 1.0), scene(30.0, 200.0);
  std::normal_distribution<double> n01(0.0, noise);
  std::vector<RadiometrySample> samples;
  const int frames = static_cast<int>(log_gain.size());
  for (int a = 0; a + 1 < frames; ++a)
    for (int b : {a + 1, a + 5}) {
      if (b >= frames) continue;
      for (int k = 0; k < 64; ++k) {
        RadiometrySample s;
        s.a = a;
        s.b = b;
        s.r2_a = static_cast<float>(r2(*rng));
        s.r2_b = static_cast<float>(r2(*rng));
        const double l = std::log(scene(*rng));
        for (int c = 0; c < 3; ++c) {
          s.log_a[c] =
              static_cast<float>(l + log_gain[static_cast<size_t>(a)][c] + TrueLogFalloff(c, s.r2_a) + n01(*rng));
          s.log_b[c] =
              static_cast<float>(l + log_gain[static_cast<size_t>(b)][c] + TrueLogFalloff(c, s.r2_b) + n01(*rng));
        }
        samples.push_back(s);
      }
    }
  // Moving objects: a few samples that disagree wildly.
  for (int k = 0; k < outliers; ++k) samples[static_cast<size_t>(k * 7 % samples.size())].log_a += cv::Vec3f(1, 1, 1);
  return samples;
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
  SampleOverlap(0, 1, ta, tb, work, work, Translation(-200, 0), 64, &samples);
  ASSERT_GE(samples.size(), 32u);
  EXPECT_LE(samples.size(), 64u);
  for (const auto& s : samples) {
    const double expected = std::log(truth.Falloff(0, s.r2_a)) - std::log(1.2) - std::log(truth.Falloff(0, s.r2_b));
    EXPECT_NEAR(s.log_a[1] - s.log_b[1], expected, 0.02);
  }
  // Correction of a part of frame 1 at half resolution: flat at 150 grey levels.
  cv::Mat half;
  cv::resize(frames[1], half, cv::Size(300, 200), 0, 0, cv::INTER_AREA);
  cv::Mat part = half(cv::Rect(10, 20, 200, 150)).clone();
  CorrectRadiometry(truth, 1, half.size(), cv::Point2d(10, 20), &part);
  double lo = 0, hi = 0;
  cv::minMaxLoc(part.reshape(1), &lo, &hi);
  EXPECT_GE(lo, 147);
  EXPECT_LE(hi, 153);
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
    live.AddFrame(id, MakeThumbnail(f, RadiometryOptions{}.thumb_long_side), f.size());
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
}

}  // namespace
}  // namespace uavm
