#pragma once
// Approximate nearest neighbours of 8-bit SIFT descriptors: a forest of randomized kd-trees searched best-bin-first,
// as FLANN's KDTreeIndex, with leaves of up to `leaf_size` points instead of one. A search that may check `checks`
// points then descends about checks / leaf_size times instead of `checks` times: with cvflann's one-point leaves the
// descents and their heap traffic, not the distances, were most of the matching time.
#include <cstdint>
#include <opencv2/core.hpp>
#include <vector>

namespace uavm {

class KdForest {
 public:
  struct Options {
    int trees = 4;
    int leaf_size = 8;
    uint32_t seed = 0x5eed;  // the trees' random split choices: the same forest for the same descriptors
  };

  KdForest() = default;
  // `descriptors`: CV_8U, continuous, one descriptor per row; borrowed (must outlive the forest).
  KdForest(const cv::Mat& descriptors, const Options& options);

  // The two nearest rows to `query` (descriptors.cols bytes) among those checked: every leaf each tree descends to,
  // then the nearest branches not taken until `checks` points have been compared. Squared L2 distances in integers
  // (the same answer on every CPU); index -1 when fewer than two rows were seen.
  void Nearest2(const uint8_t* query, int checks, int index[2], uint32_t dist[2]) const;

  [[nodiscard]] int rows() const { return rows_; }
  // Bytes the forest holds (its trees; the descriptors are borrowed).
  [[nodiscard]] size_t bytes() const {
    return order_.capacity() * sizeof(int32_t) + nodes_.capacity() * sizeof(Node) + roots_.capacity() * sizeof(int32_t);
  }

 private:
  // Inner node: children `first` and `second` (indices into nodes_), split on `dim` at `value` (below: first).
  // Leaf (dim < 0): rows order_[first .. second).
  struct Node {
    float value = 0;
    int32_t first = 0, second = 0;
    int16_t dim = -1;
  };
  struct Search;

  int32_t BuildNode(int32_t begin, int32_t end, uint32_t* rng);
  void Descend(int32_t node, float mindist, Search* s) const;

  const uint8_t* data_ = nullptr;
  int rows_ = 0;
  int cols_ = 0;
  int leaf_size_ = 8;
  std::vector<int32_t> order_;  // each tree's permutation of the rows, leaves contiguous
  std::vector<Node> nodes_;
  std::vector<int32_t> roots_;
};

}  // namespace uavm
