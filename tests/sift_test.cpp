#include "core/features/sift.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <iostream>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <vector>

#include "tests/test_env.h"
#include "tests/test_frames.h"

namespace uavm {
namespace {

using test::WorkingGray;

TEST(SiftTest, FindsManyKeypointsOnASoftAerialFrame) {
  const cv::Mat gray = WorkingGray(800);
  const Features f = SiftExtractor(FeatureOptions{}).Extract(gray);
  EXPECT_GE(f.size(), 1500u);
  EXPECT_LE(f.size(), 3000u);
  EXPECT_EQ(f.descriptors.rows, static_cast<int>(f.size()));
  EXPECT_EQ(f.descriptors.type(), CV_32F);
  for (const auto& p : f.points) {
    EXPECT_GE(p.x, -0.5f);
    EXPECT_LT(p.x, static_cast<float>(gray.cols));
  }
}

// Banded detection (a memory cap on the scale space) finds the same keypoints as the whole image (measured: 97 % at the
// same position), and most with the same descriptor (80 %; those whose window reaches past the band's overlap differ).
TEST(SiftTest, BandedDetectionAgreesWithTheWholeImage) {
  const cv::Mat gray = WorkingGray(static_cast<int>(1000 * test::EmulationImageScale()));
  FeatureOptions whole;
  FeatureOptions banded;
  // A cap that splits detection into 3 bands (80 MiB at 1000 px).
  const int cap =
      static_cast<int>(std::ceil(SiftScaleSpaceMiB(gray.cols, (gray.rows + 2) / 3 + 2 * banded.band_margin, banded)));
  banded.max_scale_space_mib = cap;
  ASSERT_EQ(SiftBands(gray.cols, gray.rows, whole), 1);
  const int bands = SiftBands(gray.cols, gray.rows, banded);
  EXPECT_GE(bands, 2);
  const int band_rows = (gray.rows + bands - 1) / bands + 2 * banded.band_margin;
  EXPECT_LE(SiftScaleSpaceMiB(gray.cols, band_rows, banded), cap);
  EXPECT_GT(SiftScaleSpaceMiB(gray.cols, gray.rows, banded), cap);

  const Features a = SiftExtractor(whole).Extract(gray);
  const Features b = SiftExtractor(banded).Extract(gray);
  ASSERT_GT(a.size(), 1000u);
  EXPECT_NEAR(static_cast<double>(b.size()), static_cast<double>(a.size()), 0.05 * static_cast<double>(a.size()));
  // For each banded keypoint, the same location in the whole-image set (within 0.05 px), and a near-equal descriptor.
  int same = 0;
  int located = 0;
  for (size_t i = 0; i < b.size(); ++i) {
    for (size_t j = 0; j < a.size(); ++j) {
      if (std::abs(a.points[j].x - b.points[i].x) > 0.05f || std::abs(a.points[j].y - b.points[i].y) > 0.05f) continue;
      ++located;
      if (cv::norm(a.descriptors.row(static_cast<int>(j)), b.descriptors.row(static_cast<int>(i)), cv::NORM_L2) < 0.2)
        ++same;
      break;
    }
  }
  std::cerr << "banded (" << bands << " bands under " << cap << " MiB): " << located << " located, " << same << " of "
            << b.size() << " keypoints as in the whole image\n";
  EXPECT_GT(located, static_cast<int>(0.95 * static_cast<double>(b.size())));
  EXPECT_GT(same, static_cast<int>(0.8 * static_cast<double>(b.size())));
}

// Half-size detection maps its keypoints back to the working copy's pixel-centre convention: keypoints it shares with a
// full-resolution detection (nearest within 1 px) sit at the same place, without an offset (a wrong centre mapping,
// 2p instead of 2p + 0.5, shows as a 0.5 px median, and so does taking an odd side's ratio as 2); it still finds
// plenty.
TEST(SiftTest, HalfSizePositionsAgreeWithFullResolution) {
  // An odd number of rows (1000 x 751, or 500 x 375 under emulation): the half-size copy is not exactly half.
  cv::Mat gray = WorkingGray(static_cast<int>(1000 * test::EmulationImageScale()));
  if (gray.rows % 2 == 0) cv::copyMakeBorder(gray, gray, 0, 1, 0, 0, cv::BORDER_REFLECT);
  FeatureOptions half;
  half.half_size = true;
  const Features h = SiftExtractor(half).Extract(gray);
  const Features f = SiftExtractor(FeatureOptions{}).Extract(gray);
  EXPECT_GE(h.size(), static_cast<size_t>(1000 * test::EmulationImageScale()));
  std::vector<float> dx, dy;
  for (const auto& p : h.points) {
    float best = 1.0f;
    cv::Point2f d;
    for (const auto& q : f.points) {
      const float dist = std::hypot(q.x - p.x, q.y - p.y);
      if (dist < best) {
        best = dist;
        d = q - p;
      }
    }
    if (best < 1.0f) {
      dx.push_back(d.x);
      dy.push_back(d.y);
    }
  }
  ASSERT_GE(dx.size(), 200u);
  std::nth_element(dx.begin(), dx.begin() + static_cast<long>(dx.size() / 2), dx.end());
  std::nth_element(dy.begin(), dy.begin() + static_cast<long>(dy.size() / 2), dy.end());
  EXPECT_LT(std::abs(dx[dx.size() / 2]), 0.15f);
  EXPECT_LT(std::abs(dy[dy.size() / 2]), 0.15f);
}

// features.double_first_octave: false starts the scale space at the input's size. Its figure (and so the memory plan
// and the bands under a cap) is a quarter of the doubled one's; it still finds plenty, most of them where the doubled
// scale space has one too (the doubled octave adds the finer ones; bench/results/sift-first-octave-*.md
// measures what they buy).
TEST(SiftTest, AnUndoubledFirstOctaveCostsAQuarterAndFindsTheCoarserKeypoints) {
  const cv::Mat gray = WorkingGray(static_cast<int>(1000 * test::EmulationImageScale()));
  FeatureOptions doubled;
  FeatureOptions input;
  input.double_first_octave = false;
  // A quarter up to the rows' alignment (0.002 % at 500 px wide under emulation).
  const double quarter = SiftScaleSpaceMiB(gray.cols, gray.rows, doubled) / 4;
  EXPECT_NEAR(SiftScaleSpaceMiB(gray.cols, gray.rows, input), quarter, 1e-3 * quarter);
  const int cap = static_cast<int>(std::ceil(SiftScaleSpaceMiB(gray.cols, gray.rows, input)));
  doubled.max_scale_space_mib = cap;
  input.max_scale_space_mib = cap;
  EXPECT_EQ(SiftBands(gray.cols, gray.rows, input), 1);
  EXPECT_GE(SiftBands(gray.cols, gray.rows, doubled), 2);
  doubled.max_scale_space_mib = 0;
  input.max_scale_space_mib = 0;
  doubled.max_features = 1 << 20;  // every keypoint, not only the strongest (mostly fine ones)

  const Features a = SiftExtractor(doubled).Extract(gray);
  const Features b = SiftExtractor(input).Extract(gray);
  ASSERT_GE(b.size(), static_cast<size_t>(1000 * test::EmulationImageScale()));
  int shared = 0;
  for (const auto& p : b.points) {
    for (const auto& q : a.points) {
      if (std::abs(p.x - q.x) <= 0.25f && std::abs(p.y - q.y) <= 0.25f) {
        ++shared;
        break;
      }
    }
  }
  std::cerr << "undoubled: " << b.size() << " keypoints (doubled " << a.size() << "), " << shared
            << " within 0.25 px of a doubled one\n";
  // 81 % measured at 1000 px, 70 % at 500 px (under emulation: fewer, coarser keypoints).
  EXPECT_GT(shared, static_cast<int>(0.6 * static_cast<double>(b.size())));
}

// The extractor keeps the scale space's block from one frame to the next (the memory plan's detector figure, one band
// of it under a cap) and gives it back on request (the end of the flight): the same features as a fresh extractor.
TEST(SiftTest, TheExtractorHoldsItsScaleSpaceUntilReleased) {
  const cv::Mat gray = WorkingGray(static_cast<int>(640 * test::EmulationImageScale()));
  FeatureOptions o;
  const SiftExtractor sift(o);
  EXPECT_EQ(sift.HeldBytes(), 0u);
  const Features first = sift.Extract(gray);
  const double figure = SiftScaleSpaceMiB(gray.cols, gray.rows, o) * 1024.0 * 1024.0;
  EXPECT_NEAR(static_cast<double>(sift.HeldBytes()), figure, 64.0);
  const Features second = sift.Extract(gray);
  EXPECT_EQ(second.points, first.points);
  EXPECT_EQ(cv::norm(second.descriptors, SiftExtractor(o).Extract(gray).descriptors, cv::NORM_INF), 0.0);
  sift.ReleaseBuffers();
  EXPECT_EQ(sift.HeldBytes(), 0u);
  // Under a cap, bands of the frame: the block is one band's, within the cap.
  o.max_scale_space_mib = static_cast<int>(std::ceil(figure / (1024.0 * 1024.0) / 2));
  ASSERT_GE(SiftBands(gray.cols, gray.rows, o), 2);
  const SiftExtractor banded(o);
  EXPECT_GT(banded.Extract(gray).size(), 100u);
  EXPECT_GT(banded.HeldBytes(), 0u);
  EXPECT_LE(static_cast<double>(banded.HeldBytes()), o.max_scale_space_mib * 1024.0 * 1024.0);
}

// The detection on the extractor's awake workers or on OpenCV's pool: the same features, frame after frame (the
// workers and the held first-octave level carry over), and again after the release.
TEST(SiftTest, AwakeWorkersGiveTheSameFeatures) {
  const cv::Mat gray = WorkingGray(static_cast<int>(640 * test::EmulationImageScale()));
  cv::Mat soft;
  gray.convertTo(soft, CV_8U, 0.25, 96);
  FeatureOptions o;
  const SiftExtractor awake(o);
  o.awake_workers = false;
  const SiftExtractor pooled(o);
  for (int round = 0; round < 2; ++round) {
    for (const cv::Mat* frame : std::initializer_list<const cv::Mat*>{&gray, &soft, &gray}) {
      const Features a = awake.Extract(*frame);
      const Features b = pooled.Extract(*frame);
      ASSERT_GT(a.size(), 100u);
      EXPECT_EQ(a.points, b.points);
      EXPECT_EQ(cv::norm(a.descriptors, b.descriptors, cv::NORM_INF), 0.0);
    }
    awake.ReleaseBuffers();
  }
}

TEST(SiftTest, OptionsAreChecked) {
  FeatureOptions o;
  std::string why;
  EXPECT_TRUE(o.Check(&why));
  o.max_scale_space_mib = -1;
  EXPECT_FALSE(o.Check(&why));
  EXPECT_NE(why.find("max_scale_space_mib"), std::string::npos);
  EXPECT_TRUE(SiftExtractor(FeatureOptions{}).Extract(cv::Mat()).points.empty());
}

}  // namespace
}  // namespace uavm
