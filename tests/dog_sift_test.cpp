#include "core/features/dog_sift.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <iostream>
#include <opencv2/calib3d.hpp>
#include <opencv2/features2d.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <vector>

#include "core/buffers/mat_pool.h"
#include "core/util/burst_workers.h"
#include "tests/test_env.h"
#include "tests/test_frames.h"

namespace uavm {
namespace {

const std::string kData = UAVM_TEST_DATA;

using test::WorkingGray;

// Synthetic truth: a dark Gaussian blob at a known sub-pixel centre is one keypoint there, of its scale.
TEST(DogSiftTest, FindsABlobAtItsSubPixelCentre) {
  const cv::Point2d centre(61.37, 47.81);
  const double sigma = 4.0;
  cv::Mat img(96, 128, CV_8U);
  for (int y = 0; y < img.rows; ++y)
    for (int x = 0; x < img.cols; ++x) {
      const double r2 = (x - centre.x) * (x - centre.x) + (y - centre.y) * (y - centre.y);
      img.at<uchar>(y, x) = cv::saturate_cast<uchar>(200.0 - 150.0 * std::exp(-r2 / (2 * sigma * sigma)));
    }
  std::vector<SiftKeypoint> kps;
  cv::Mat desc;
  DetectAndDescribeSift(img, DogSiftOptions{}, &kps, &desc);
  ASSERT_FALSE(kps.empty());
  const SiftKeypoint& best = kps.front();  // strongest first
  EXPECT_NEAR(best.point.x, centre.x, 0.05);
  EXPECT_NEAR(best.point.y, centre.y, 0.05);
  // A blob of sigma s answers the scale-normalised Laplacian most at scale s; OpenCV's size is twice the scale.
  EXPECT_NEAR(best.size, 2.0 * sigma, 0.2 * 2.0 * sigma);
  EXPECT_EQ(desc.rows, static_cast<int>(kps.size()));
  EXPECT_EQ(desc.cols, 128);
}

// The same keypoints as OpenCV 4.6's SIFT with the same settings: nearly all at the same place (OpenCV's positions
// moved to pixel centres by -0.25 px), of the same size within 2 % (our fixed-point scale space, 1/256 grey, moves the
// scale fit of weak keypoints by 1-2 %: 89 % within 1 %, 93 % within 2 %; float images gave 95 % and 97 %), and no
// offset between the two.
TEST(DogSiftTest, KeypointsAgreeWithOpenCvSift) {
  const cv::Mat gray = WorkingGray(static_cast<int>(800 * test::EmulationImageScale()));
  DogSiftOptions o;
  std::vector<SiftKeypoint> ours;
  cv::Mat ours_desc;
  DetectAndDescribeSift(gray, o, &ours, &ours_desc);
  std::vector<cv::KeyPoint> theirs;
  cv::Mat theirs_desc;
  cv::SIFT::create(o.max_features, o.octave_layers, o.contrast_threshold, o.edge_threshold, o.sigma)
      ->detectAndCompute(gray, cv::noArray(), theirs, theirs_desc);
  ASSERT_GT(theirs.size(), 1000u);
  EXPECT_NEAR(static_cast<double>(ours.size()), static_cast<double>(theirs.size()),
              0.03 * static_cast<double>(theirs.size()));
  int same = 0;
  double sum_dx = 0.0;
  double sum_dy = 0.0;
  for (const auto& k : ours) {
    for (const auto& t : theirs) {
      const cv::Point2f d = k.point - (t.pt - cv::Point2f(0.25f, 0.25f));
      if (std::abs(d.x) > 0.05f || std::abs(d.y) > 0.05f) continue;
      if (std::abs(k.size / t.size - 1.f) > 0.02f) continue;
      ++same;
      sum_dx += d.x;
      sum_dy += d.y;
      break;
    }
  }
  std::cerr << same << " of " << ours.size() << " keypoints as OpenCV's (" << theirs.size() << ")\n";
  EXPECT_GT(same, static_cast<int>(0.9 * static_cast<double>(ours.size())));
  EXPECT_LT(std::abs(sum_dx / same), 0.002);
  EXPECT_LT(std::abs(sum_dy / same), 0.002);
}

struct PairScore {
  int matches = 0;
  int correct = 0;
};

// Mutual ratio-test matches between two images, scored against the homography b_from_a (correct within 2 px).
PairScore ScorePair(const std::vector<cv::Point2f>& a, const cv::Mat& da, const std::vector<cv::Point2f>& b,
                    const cv::Mat& db, const cv::Mat& b_from_a) {
  cv::BFMatcher matcher(cv::NORM_L2);
  std::vector<std::vector<cv::DMatch>> ab, ba;
  matcher.knnMatch(da, db, ab, 2);
  matcher.knnMatch(db, da, ba, 1);
  PairScore s;
  for (const auto& m : ab) {
    if (m.size() < 2 || m[0].distance > 0.8f * m[1].distance) continue;
    if (ba[static_cast<size_t>(m[0].trainIdx)].empty() ||
        ba[static_cast<size_t>(m[0].trainIdx)][0].trainIdx != m[0].queryIdx)
      continue;
    ++s.matches;
    std::vector<cv::Point2f> in{a[static_cast<size_t>(m[0].queryIdx)]}, out;
    cv::perspectiveTransform(in, out, b_from_a);
    if (cv::norm(out[0] - b[static_cast<size_t>(m[0].trainIdx)]) < 2.0) ++s.correct;
  }
  return s;
}

// OpenCV's graf pair (a 40-degree change of viewpoint, its exact homography): at least as many correct matches as
// OpenCV's SIFT (within 5 %), and as large a share of them correct.
TEST(DogSiftTest, MatchesTheGrafPairAsWellAsOpenCvSift) {
  const cv::Mat a = cv::imread(kData + "/opencv_samples/graf1.png", cv::IMREAD_GRAYSCALE);
  const cv::Mat b = cv::imread(kData + "/opencv_samples/graf3.png", cv::IMREAD_GRAYSCALE);
  ASSERT_FALSE(a.empty());
  ASSERT_FALSE(b.empty());
  cv::Mat h;
  cv::FileStorage fs(kData + "/opencv_samples/H1to3p.xml", cv::FileStorage::READ);
  fs.getFirstTopLevelNode() >> h;
  ASSERT_EQ(h.rows, 3);
  h.convertTo(h, CV_64F);
  DogSiftOptions o;
  auto ours = [&](const cv::Mat& img, std::vector<cv::Point2f>* pts, cv::Mat* desc) {
    std::vector<SiftKeypoint> kps;
    DetectAndDescribeSift(img, o, &kps, desc);
    for (const auto& k : kps) pts->push_back(k.point);
  };
  auto theirs = [&](const cv::Mat& img, std::vector<cv::Point2f>* pts, cv::Mat* desc) {
    std::vector<cv::KeyPoint> kps;
    cv::SIFT::create(o.max_features, o.octave_layers, o.contrast_threshold, o.edge_threshold, o.sigma)
        ->detectAndCompute(img, cv::noArray(), kps, *desc);
    for (const auto& k : kps) pts->push_back(k.pt - cv::Point2f(0.25f, 0.25f));
  };
  std::vector<cv::Point2f> pa, pb, qa, qb;
  cv::Mat da, db, ea, eb;
  ours(a, &pa, &da);
  ours(b, &pb, &db);
  theirs(a, &qa, &ea);
  theirs(b, &qb, &eb);
  // Pixel centres: the homography maps pixel indices, as do both sets of points.
  const PairScore s_ours = ScorePair(pa, da, pb, db, h);
  const PairScore s_theirs = ScorePair(qa, ea, qb, eb, h);
  std::cerr << "graf1-3: ours " << s_ours.correct << " / " << s_ours.matches << ", OpenCV " << s_theirs.correct << " / "
            << s_theirs.matches << "\n";
  ASSERT_GT(s_theirs.correct, 50);
  EXPECT_GE(s_ours.correct, static_cast<int>(0.95 * s_theirs.correct));
  EXPECT_GE(static_cast<double>(s_ours.correct) / s_ours.matches,
            0.97 * static_cast<double>(s_theirs.correct) / s_theirs.matches);
}

// The descriptor from 4 x 4 bilinear samples a cell on its rotated grid (the default) against OpenCV's way, every
// pixel of its window, on a frame and its copy turned by 30 degrees and shrunk to 0.7 (the exact homography): as many
// correct matches (within 3 %), as large a share of them correct.
TEST(DogSiftTest, SampledDescriptorMatchesAsWellAsEveryPixel) {
  const cv::Mat a = WorkingGray(static_cast<int>(640 * test::EmulationImageScale()));
  const cv::Mat affine = cv::getRotationMatrix2D(
      cv::Point2f(0.5f * static_cast<float>(a.cols), 0.5f * static_cast<float>(a.rows)), 30.0, 0.7);
  cv::Mat b;
  cv::warpAffine(a, b, affine, a.size(), cv::INTER_LINEAR, cv::BORDER_REFLECT101);
  cv::Mat h = cv::Mat::eye(3, 3, CV_64F);
  affine.copyTo(h.rowRange(0, 2));
  auto score = [&](int samples_per_cell) {
    DogSiftOptions o;
    o.descriptor_samples_per_cell = samples_per_cell;
    auto detect = [&](const cv::Mat& img, std::vector<cv::Point2f>* pts, cv::Mat* desc) {
      std::vector<SiftKeypoint> kps;
      DetectAndDescribeSift(img, o, &kps, desc);
      for (const auto& k : kps) pts->push_back(k.point);
    };
    std::vector<cv::Point2f> pa, pb;
    cv::Mat da, db;
    detect(a, &pa, &da);
    detect(b, &pb, &db);
    return ScorePair(pa, da, pb, db, h);
  };
  const PairScore sampled = score(4);
  const PairScore every_pixel = score(0);
  std::cerr << "turned 30 degrees, 0.7: sampled " << sampled.correct << " / " << sampled.matches << ", every pixel "
            << every_pixel.correct << " / " << every_pixel.matches << "\n";
  ASSERT_GT(every_pixel.correct, 100);
  EXPECT_GE(sampled.correct, static_cast<int>(0.97 * every_pixel.correct));
  EXPECT_GE(static_cast<double>(sampled.correct) / sampled.matches,
            0.97 * static_cast<double>(every_pixel.correct) / every_pixel.matches);
}

// The result does not depend on the number of threads (each task computes whole rows or whole keypoints), nor on
// whose threads.
TEST(DogSiftTest, SameBitsWithOneThreadOrMany) {
  const cv::Mat gray = WorkingGray(static_cast<int>(500 * test::EmulationImageScale()));
  std::vector<SiftKeypoint> many, one;
  cv::Mat dm, d1;
  DetectAndDescribeSift(gray, DogSiftOptions{}, &many, &dm);
  const int threads = cv::getNumThreads();
  cv::setNumThreads(1);
  DetectAndDescribeSift(gray, DogSiftOptions{}, &one, &d1);
  cv::setNumThreads(threads);
  ASSERT_EQ(many.size(), one.size());
  for (size_t i = 0; i < many.size(); ++i) {
    EXPECT_EQ(many[i].point, one[i].point);
    EXPECT_EQ(many[i].angle, one[i].angle);
  }
  EXPECT_EQ(cv::norm(dm, d1, cv::NORM_INF), 0.0);
  // On workers of our own (SiftExtractor's), 1 and 3 beside the caller.
  for (const int threads : {1, 3}) {
    BurstWorkers workers(threads);
    std::vector<SiftKeypoint> on_workers;
    cv::Mat dw;
    DetectAndDescribeSift(gray, DogSiftOptions{}, &on_workers, &dw, nullptr, nullptr, &workers);
    ASSERT_EQ(on_workers.size(), one.size());
    for (size_t i = 0; i < one.size(); ++i) EXPECT_EQ(on_workers[i].point, one[i].point);
    EXPECT_EQ(cv::norm(dw, d1, cv::NORM_INF), 0.0);
  }
}

// The threshold lowered on one scale space gives what detecting again at a third of it gives, on a frame too soft
// for the first threshold.
TEST(DogSiftTest, LoweredThresholdIsASecondDetection) {
  cv::Mat gray = WorkingGray(static_cast<int>(480 * test::EmulationImageScale()));
  gray.convertTo(gray, CV_8U, 0.25, 96);  // a quarter of the contrast
  DogSiftOptions ladder;
  ladder.target_min_features = 1500;
  ladder.min_contrast_threshold = 0.001;
  std::vector<SiftKeypoint> once;
  cv::Mat d_once;
  double used = 0.0;
  DetectAndDescribeSift(gray, ladder, &once, &d_once, &used);
  // The loop SiftExtractor ran before: detect, and again at a third while too few.
  DogSiftOptions plain;
  std::vector<SiftKeypoint> again;
  cv::Mat d_again;
  for (;;) {
    DetectAndDescribeSift(gray, plain, &again, &d_again);
    if (static_cast<int>(again.size()) >= ladder.target_min_features) break;
    if (plain.contrast_threshold / 3.0 < ladder.min_contrast_threshold) break;
    plain.contrast_threshold /= 3.0;
  }
  EXPECT_LT(used, ladder.contrast_threshold) << "the frame should need a lower threshold";
  EXPECT_DOUBLE_EQ(used, plain.contrast_threshold);
  ASSERT_NEAR(static_cast<double>(once.size()), static_cast<double>(again.size()),
              0.01 * static_cast<double>(again.size()));
  size_t same = 0;
  for (size_t i = 0; i < std::min(once.size(), again.size()); ++i) same += once[i].point == again[i].point ? 1 : 0;
  EXPECT_GT(same, static_cast<size_t>(0.97 * static_cast<double>(again.size())));
}

// The first octave searched once at a lower level of the ladder gives the keypoints of searching each level in turn,
// bit for bit, whichever level the frame needs: a textured frame (the top), softer ones (one and two steps down). So
// does the level the last frame needed (held buffers), from the softest frame to the textured one.
TEST(DogSiftTest, FirstOctaveSearchedOnceGivesWhatEachLevelGives) {
  const double scale = test::EmulationImageScale();
  const cv::Mat textured = WorkingGray(static_cast<int>(480 * scale));
  const int target = static_cast<int>(1500 * scale * scale);  // the same keypoints a pixel on a smaller frame
  std::vector<double> needed;
  std::vector<std::vector<SiftKeypoint>> each_of;
  std::vector<cv::Mat> grays;
  for (const double contrast : {1.0, 0.25, 0.08}) {
    cv::Mat gray;
    textured.convertTo(gray, CV_8U, contrast, 128.0 * (1.0 - contrast));
    DogSiftOptions o;
    o.target_min_features = target;
    o.min_contrast_threshold = 0.0005;
    std::vector<SiftKeypoint> each, once;
    cv::Mat d_each, d_once;
    double used_each = 0.0;
    double used_once = 0.0;
    o.first_octave_search_level = 0;
    DetectAndDescribeSift(gray, o, &each, &d_each, &used_each);
    for (const int level : {1, 2}) {
      o.first_octave_search_level = level;
      DetectAndDescribeSift(gray, o, &once, &d_once, &used_once);
      EXPECT_EQ(used_once, used_each);
      ASSERT_EQ(once.size(), each.size()) << "contrast " << contrast << ", searched once at level " << level;
      for (size_t i = 0; i < each.size(); ++i) {
        EXPECT_EQ(once[i].point, each[i].point);
        EXPECT_EQ(once[i].angle, each[i].angle);
        EXPECT_EQ(once[i].response, each[i].response);
      }
      EXPECT_EQ(cv::norm(d_once, d_each, cv::NORM_INF), 0.0);
    }
    needed.push_back(used_each);
    each_of.push_back(each);
    grays.push_back(gray);
  }
  // The three frames needed three different levels (else the test shows less than it says).
  EXPECT_DOUBLE_EQ(needed[0], DogSiftOptions{}.contrast_threshold);
  EXPECT_LT(needed[1], needed[0]);
  EXPECT_LT(needed[2], needed[1]);
  DogSiftBuffers held;
  DogSiftOptions o;
  o.target_min_features = target;
  o.min_contrast_threshold = 0.0005;
  for (const size_t frame : {2, 0, 1, 1, 2}) {
    std::vector<SiftKeypoint> found;
    cv::Mat d;
    DetectAndDescribeSift(grays[frame], o, &found, &d, nullptr, &held);
    ASSERT_EQ(found.size(), each_of[frame].size()) << "frame " << frame;
    for (size_t i = 0; i < found.size(); ++i) EXPECT_EQ(found[i].point, each_of[frame][i].point);
  }
  // The softest frame's first octave needed a lower level, which the buffers hold.
  EXPECT_GT(held.first_octave_threshold(), 0.0);
  EXPECT_LT(held.first_octave_threshold(), DogSiftOptions{}.contrast_threshold);
}

TEST(DogSiftTest, TinyAndFlatImagesGiveNothing) {
  std::vector<SiftKeypoint> kps;
  cv::Mat desc;
  DetectAndDescribeSift(cv::Mat(5, 5, CV_8U, cv::Scalar(7)), DogSiftOptions{}, &kps, &desc);
  EXPECT_TRUE(kps.empty());
  DetectAndDescribeSift(cv::Mat(300, 400, CV_8U, cv::Scalar(128)), DogSiftOptions{}, &kps, &desc);
  EXPECT_TRUE(kps.empty());
  EXPECT_EQ(desc.rows, 0);
}

// The scale space's figure is what the memory plan reserves: L + 3 int16 images of the doubled first octave (its
// Gaussian layers; the later octaves' fit in the room of the first's three searched ones).
TEST(DogSiftTest, ScaleSpaceFigure) {
  EXPECT_NEAR(DogSiftScaleSpaceMiB(1000, 750), 6.0 * 2000 * 1500 * 2 / (1024.0 * 1024.0), 1e-9);
  EXPECT_NEAR(DogSiftScaleSpaceMiB(1000, 750, 3, false), 6.0 * 1000 * 750 * 2 / (1024.0 * 1024.0),
              1e-3);  // images rounded to cache lines
  EXPECT_NEAR(DogSiftScaleSpaceMiB(1000, 750, 4), 7.0 * 2000 * 1500 * 2 / (1024.0 * 1024.0), 1e-9);
  // From 9 layers on (a tie at 9) the later octaves' kept layers outgrow that room: the figure counts them.
  EXPECT_NEAR(DogSiftScaleSpaceMiB(1000, 750, 8), 11.0 * 2000 * 1500 * 2 / (1024.0 * 1024.0), 1e-9);
  EXPECT_GT(DogSiftScaleSpaceMiB(1000, 750, 12), 15.5 * 2000 * 1500 * 2 / (1024.0 * 1024.0));
}

// The detector's large buffers are its figure and the descriptors, and a second frame takes them all back from the
// image pool: one block for every octave (images of each octave's own size missed the pool and were faulted in anew).
TEST(DogSiftTest, ScaleSpaceIsOneBlockThePoolHandsBack) {
  MatPool* pool = InstallMatPool();
  const cv::Mat gray = WorkingGray(static_cast<int>(640 * test::EmulationImageScale()));
  std::vector<SiftKeypoint> kps;
  cv::Mat desc;
  DetectAndDescribeSift(gray, DogSiftOptions{}, &kps, &desc);
  ASSERT_GT(kps.size(), 100u);
  const MatPoolStats first = pool->Stats();
  DetectAndDescribeSift(gray, DogSiftOptions{}, &kps, &desc);
  const MatPoolStats second = pool->Stats();
  EXPECT_EQ(second.misses, first.misses);
  EXPECT_GT(second.hits, first.hits);
  const double figure = DogSiftScaleSpaceMiB(gray.cols, gray.rows) * 1024.0 * 1024.0;
  EXPECT_GE(static_cast<double>(second.peak_in_use_bytes), figure);
  EXPECT_LE(static_cast<double>(second.peak_in_use_bytes),
            figure + 2.0 * static_cast<double>(desc.total() * desc.elemSize()));
}

// A caller that detects frame after frame keeps the scale space's block (DogSiftBuffers): when the image pool has given
// its free blocks back between two frames (as it did to make room for the matching's buffers), the second frame maps
// nothing new, and it finds exactly what a call with a block of its own finds.
TEST(DogSiftTest, HeldBuffersKeepTheScaleSpaceBetweenFrames) {
  MatPool* pool = InstallMatPool();
  const cv::Mat gray = WorkingGray(static_cast<int>(640 * test::EmulationImageScale()));
  DogSiftBuffers held;
  std::vector<SiftKeypoint> kps;
  cv::Mat desc;
  DetectAndDescribeSift(gray, DogSiftOptions{}, &kps, &desc, nullptr, &held);
  ASSERT_GT(kps.size(), 100u);
  EXPECT_NEAR(static_cast<double>(held.bytes()), DogSiftScaleSpaceMiB(gray.cols, gray.rows) * 1024.0 * 1024.0, 64.0);
  pool->Flush();
  const MatPoolStats before = pool->Stats();
  DetectAndDescribeSift(gray, DogSiftOptions{}, &kps, &desc, nullptr, &held);
  EXPECT_EQ(pool->Stats().misses, before.misses);
  std::vector<SiftKeypoint> own;
  cv::Mat own_desc;
  DetectAndDescribeSift(gray, DogSiftOptions{}, &own, &own_desc);
  EXPECT_GT(pool->Stats().misses, before.misses);  // its own block: flushed away, mapped again
  ASSERT_EQ(own.size(), kps.size());
  for (size_t i = 0; i < kps.size(); ++i) {
    EXPECT_EQ(own[i].point, kps[i].point);
    EXPECT_EQ(own[i].angle, kps[i].angle);
  }
  EXPECT_EQ(cv::norm(own_desc, desc, cv::NORM_INF), 0.0);
  held.Release();
  EXPECT_EQ(held.bytes(), 0u);
}

}  // namespace
}  // namespace uavm
