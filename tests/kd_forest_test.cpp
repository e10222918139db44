// The bucketed kd-forest (core/matching/kd_forest.h) against an independent exact search (OpenCV's brute-force
// matcher) and against cvflann's KDTreeIndex at the settings each is used with: on real SIFT descriptors of two
// overlapping frames it finds the true nearest neighbour at least as often, and with every point checked it is exact.
#include "core/matching/kd_forest.h"

#include <gtest/gtest.h>

#include <opencv2/features2d.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <random>
#include <vector>

#include "core/matching/descriptor_distance.h"
#include "core/matching/pair_matcher.h"

namespace uavm {
namespace {

const std::string kData = UAVM_TEST_DATA;

// RootSIFT descriptors of a bundled frame, quantized as the product stores them (8-bit rows).
cv::Mat FrameDescriptors(const std::string& name) {
  cv::Mat image = cv::imread(kData + "/caliterra_small/images/" + name, cv::IMREAD_GRAYSCALE);
  EXPECT_FALSE(image.empty()) << name;
  // The same size natively and under emulation (a few seconds of SIFT under qemu): the same kind of point sets.
  const double scale = 800.0 / image.cols;
  cv::resize(image, image, cv::Size(), scale, scale, cv::INTER_AREA);
  std::vector<cv::KeyPoint> keypoints;
  cv::Mat d;
  cv::SIFT::create(1500)->detectAndCompute(image, cv::noArray(), keypoints, d);
  for (int r = 0; r < d.rows; ++r) {  // RootSIFT: L1-normalise, square root
    cv::Mat row = d.row(r);
    row /= std::max(1e-7, cv::norm(row, cv::NORM_L1));
    cv::sqrt(row, row);
  }
  return QuantizeDescriptors(d);
}

// The exact two nearest neighbours of every query (OpenCV's brute force, float squared L2: exact on 8-bit values).
std::vector<std::vector<cv::DMatch>> Exact(const cv::Mat& query, const cv::Mat& train) {
  cv::Mat qf, tf;
  query.convertTo(qf, CV_32F);
  train.convertTo(tf, CV_32F);
  std::vector<std::vector<cv::DMatch>> knn;
  cv::BFMatcher(cv::NORM_L2SQR).knnMatch(qf, tf, knn, 2);
  return knn;
}

TEST(KdForestTest, CheckingEveryPointIsExact) {
  const cv::Mat train = FrameDescriptors("IMG_9360.jpg");
  const cv::Mat query = FrameDescriptors("IMG_9361.jpg");
  ASSERT_GT(train.rows, 500);
  const KdForest forest(train, {4, 4, 0x5eed});
  const auto exact = Exact(query, train);
  for (int q = 0; q < query.rows; ++q) {
    int idx[2];
    uint32_t dist[2];
    forest.Nearest2(query.ptr<uint8_t>(q), train.rows, idx, dist);
    ASSERT_EQ(dist[0], static_cast<uint32_t>(exact[q][0].distance)) << q;
    ASSERT_EQ(dist[1], static_cast<uint32_t>(exact[q][1].distance)) << q;
    EXPECT_EQ(dist[0], SquaredL2Bytes(query.ptr<uint8_t>(q), train.ptr<uint8_t>(idx[0]), 128));
  }
}

// Recall of the true nearest neighbour, ours at the measured settings (4 trees, 4 points a leaf, 64 checks) against
// cvflann's KDTreeIndex at the settings it was used with (4 trees, 32 checks): on the queries whose nearest neighbour
// passes the ratio test (the ones that become matches), and on all. Two overlapping caliterra frames (brighton_beach's
// sand and water give too few matchable points).
TEST(KdForestTest, FindsTheTrueNeighbourAtLeastAsOftenAsCvflann) {
  const cv::Mat train = FrameDescriptors("IMG_9360.jpg");
  const cv::Mat query = FrameDescriptors("IMG_9361.jpg");
  const auto exact = Exact(query, train);
  const KdForest forest(train, {4, 4, 0x5eed});
  cvflann::seed_random(42);
  cvflann::Index<ByteL2> flann(cvflann::Matrix<unsigned char>(train.data, static_cast<size_t>(train.rows), 128),
                               cvflann::KDTreeIndexParams(4));
  flann.buildIndex();
  int matches = 0, ours = 0, theirs = 0, all_ours = 0, all_theirs = 0;
  for (int q = 0; q < query.rows; ++q) {
    const bool matchable = exact[q][0].distance < 0.64f * exact[q][1].distance;
    matches += matchable ? 1 : 0;
    int idx[2];
    uint32_t dist[2];
    forest.Nearest2(query.ptr<uint8_t>(q), 64, idx, dist);
    all_ours += idx[0] == exact[q][0].trainIdx ? 1 : 0;
    ours += matchable && idx[0] == exact[q][0].trainIdx ? 1 : 0;
    int fidx[2];
    float fdist[2];
    cvflann::Matrix<unsigned char> qm(const_cast<uint8_t*>(query.ptr<uint8_t>(q)), 1, 128);
    cvflann::Matrix<int> im(fidx, 1, 2);
    cvflann::Matrix<float> dm(fdist, 1, 2);
    flann.knnSearch(qm, im, dm, 2, cvflann::SearchParams(32));
    all_theirs += fidx[0] == exact[q][0].trainIdx ? 1 : 0;
    theirs += matchable && fidx[0] == exact[q][0].trainIdx ? 1 : 0;
  }
  std::printf("all %d queries: nearest found by the kd-forest %d (%.1f %%), by cvflann %d (%.1f %%)\n", query.rows,
              all_ours, 100.0 * all_ours / query.rows, all_theirs, 100.0 * all_theirs / query.rows);
  std::printf("%d matchable queries: nearest found by the kd-forest %d (%.1f %%), by cvflann %d (%.1f %%)\n", matches,
              ours, 100.0 * ours / matches, theirs, 100.0 * theirs / matches);
  ASSERT_GT(matches, 100);
  // Both find nearly all (99.3 % each here); one query either way is noise.
  EXPECT_GE(ours + 1, theirs);
  EXPECT_GT(ours, 0.95 * matches);
  EXPECT_GE(all_ours, all_theirs);  // measured 83 % against 78 %
}

TEST(KdForestTest, SameForestSameAnswersAndSmallOrUniformSets) {
  const cv::Mat train = FrameDescriptors("IMG_9360.jpg");
  const KdForest a(train, {4, 4, 7}), b(train, {4, 4, 7});
  for (int q = 0; q < 200; ++q) {
    int ia[2], ib[2];
    uint32_t da[2], db[2];
    a.Nearest2(train.ptr<uint8_t>(q), 64, ia, da);
    b.Nearest2(train.ptr<uint8_t>(q), 64, ib, db);
    EXPECT_EQ(ia[0], ib[0]);
    EXPECT_EQ(ia[1], ib[1]);
    EXPECT_EQ(da[0], 0u);  // a row of the set finds itself
  }
  // One row: its only neighbour, and none second.
  const KdForest one(train.rowRange(0, 1), {4, 4, 1});
  int idx[2];
  uint32_t dist[2];
  one.Nearest2(train.ptr<uint8_t>(5), 64, idx, dist);
  EXPECT_EQ(idx[0], 0);
  EXPECT_EQ(idx[1], -1);
  // 100 identical rows (every split value alike): still a tree, still the nearest.
  cv::Mat same(100, 128, CV_8U, cv::Scalar(9));
  same.row(37).setTo(cv::Scalar(10));
  const KdForest uniform(same, {2, 4, 1});
  const std::vector<uint8_t> probe(128, 10);
  uniform.Nearest2(probe.data(), 200, idx, dist);
  EXPECT_EQ(idx[0], 37);
  EXPECT_EQ(dist[0], 0u);
  EXPECT_EQ(dist[1], 128u);
}

}  // namespace
}  // namespace uavm
