// The integer (AVX2) descriptor distance against cvflann's own L2<unsigned char>: the same values, and kd-trees built
// and searched with either return the same neighbours at the same distances.
#include "core/matching/descriptor_distance.h"

#include <gtest/gtest.h>

#include <random>
#include <vector>

namespace uavm {
namespace {

TEST(DescriptorDistanceTest, EqualsCvflannL2OnRandomAndExtremeVectors) {
  std::mt19937 rng(7);
  std::uniform_int_distribution<int> byte(0, 255);
  const cvflann::L2<unsigned char> reference;
  const ByteL2 ours;
  for (size_t n : {size_t{128}, size_t{7}, size_t{33}, size_t{130}}) {
    for (int trial = 0; trial < 200; ++trial) {
      std::vector<unsigned char> a(n), b(n);
      for (size_t i = 0; i < n; ++i) {
        // Every fourth trial at the extremes: the largest sums (128 x 255^2) must stay exact.
        a[i] = static_cast<unsigned char>(trial % 4 == 0 ? 255 : byte(rng));
        b[i] = static_cast<unsigned char>(trial % 4 == 0 ? 0 : byte(rng));
      }
      const float want = reference(a.data(), b.data(), n);
      EXPECT_EQ(ours(a.data(), b.data(), n), want) << n << " " << trial;
      EXPECT_EQ(static_cast<float>(SquaredL2Bytes(a.data(), b.data(), n)), want);
    }
  }
  const std::vector<unsigned char> hi(128, 255), lo(128, 0);
  EXPECT_EQ(SquaredL2Bytes(hi.data(), lo.data(), 128), 128u * 255u * 255u);
}

TEST(DescriptorDistanceTest, KdTreesFindTheSameNeighboursAsWithCvflannL2) {
  std::mt19937 rng(11);
  std::uniform_int_distribution<int> byte(0, 120);
  const int rows = 3000, queries = 500, cols = 128;
  std::vector<unsigned char> data(static_cast<size_t>(rows * cols)), query(static_cast<size_t>(queries * cols));
  for (auto& v : data) v = static_cast<unsigned char>(byte(rng));
  for (auto& v : query) v = static_cast<unsigned char>(byte(rng));
  const cvflann::Matrix<unsigned char> data_m(data.data(), rows, cols), query_m(query.data(), queries, cols);
  auto search = [&](auto* index, std::vector<int>* idx, std::vector<float>* dist) {
    index->buildIndex();
    idx->assign(static_cast<size_t>(queries * 2), -1);
    dist->assign(static_cast<size_t>(queries * 2), 0.f);
    cvflann::Matrix<int> idx_m(idx->data(), queries, 2);
    cvflann::Matrix<float> dist_m(dist->data(), queries, 2);
    index->knnSearch(query_m, idx_m, dist_m, 2, cvflann::SearchParams(32));
  };
  std::vector<int> idx_ref, idx_ours;
  std::vector<float> dist_ref, dist_ours;
  cvflann::seed_random(42);  // the trees' random split dimensions: the same for both
  cvflann::Index<cvflann::L2<unsigned char>> reference(data_m, cvflann::KDTreeIndexParams(4));
  search(&reference, &idx_ref, &dist_ref);
  cvflann::seed_random(42);
  cvflann::Index<ByteL2> ours(data_m, cvflann::KDTreeIndexParams(4));
  search(&ours, &idx_ours, &dist_ours);
  EXPECT_EQ(idx_ours, idx_ref);
  EXPECT_EQ(dist_ours, dist_ref);
}

}  // namespace
}  // namespace uavm
