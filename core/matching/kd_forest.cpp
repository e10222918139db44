#include "core/matching/kd_forest.h"

#include <algorithm>
#include <array>
#include <limits>

#include "core/matching/descriptor_distance.h"

namespace uavm {

namespace {

constexpr int kSampleForSplit = 100;  // rows whose mean and variance choose a split (FLANN's choice)
constexpr int kTopDims = 5;           // the split dimension is drawn among the most varied ones

// xorshift32: a portable, seeded sequence (the same trees on every standard library and CPU).
uint32_t Next(uint32_t* s) {
  uint32_t x = *s;
  x ^= x << 13;
  x ^= x >> 17;
  x ^= x << 5;
  return *s = x;
}

}  // namespace

// What one query carries through the trees.
struct KdForest::Search {
  const uint8_t* query = nullptr;
  int checked = 0;
  std::array<int, 2> index{-1, -1};
  std::array<uint32_t, 2> dist{std::numeric_limits<uint32_t>::max(), std::numeric_limits<uint32_t>::max()};
  std::vector<std::pair<float, int32_t>>* heap = nullptr;  // branches not taken: (mindist, node), a min-heap
  std::vector<uint64_t>* seen = nullptr;                   // rows already compared (trees share rows)
};

KdForest::KdForest(const cv::Mat& descriptors, const Options& options)
    : data_(descriptors.ptr<uint8_t>()),
      rows_(descriptors.rows),
      cols_(descriptors.cols),
      leaf_size_(std::max(1, options.leaf_size)) {
  CV_Assert(descriptors.type() == CV_8UC1 && descriptors.isContinuous());
  if (rows_ < 1) return;
  const int trees = std::max(1, options.trees);
  order_.resize(static_cast<size_t>(trees) * static_cast<size_t>(rows_));
  // Splits at the sampled mean leave leaves of 1..leaf_size rows: ~0.67 nodes a row with leaves of 4 (8-bit SIFT).
  // One a row is reserved, so that the vector does not double (and copy) while the trees grow.
  nodes_.reserve(static_cast<size_t>(trees) * static_cast<size_t>(rows_));
  uint32_t rng = options.seed == 0 ? 1 : options.seed;
  for (int t = 0; t < trees; ++t) {
    const int32_t begin = t * rows_;
    for (int32_t i = 0; i < rows_; ++i) order_[static_cast<size_t>(begin + i)] = i;
    roots_.push_back(BuildNode(begin, begin + rows_, &rng));
  }
}

int32_t KdForest::BuildNode(int32_t begin, int32_t end, uint32_t* rng) {
  const auto id = static_cast<int32_t>(nodes_.size());
  nodes_.emplace_back();
  if (end - begin <= leaf_size_) {
    nodes_[static_cast<size_t>(id)] = {0.f, begin, end, -1};
    return id;
  }
  // Mean and variance per dimension over the first rows of the range (integer sums: exact).
  const int n = std::min(end - begin, kSampleForSplit);
  std::vector<int64_t> sum(static_cast<size_t>(cols_), 0), sum_sq(static_cast<size_t>(cols_), 0);
  for (int i = 0; i < n; ++i) {
    const uint8_t* row = data_ + static_cast<size_t>(order_[static_cast<size_t>(begin + i)]) * cols_;
    for (int d = 0; d < cols_; ++d) {
      sum[static_cast<size_t>(d)] += row[d];
      sum_sq[static_cast<size_t>(d)] += row[d] * row[d];
    }
  }
  // n^2 x variance = n sum_sq - sum^2, compared as integers.
  std::vector<std::pair<int64_t, int>> spread(static_cast<size_t>(cols_));
  for (int d = 0; d < cols_; ++d) {
    const auto k = static_cast<size_t>(d);
    spread[k] = {n * sum_sq[k] - sum[k] * sum[k], d};
  }
  const int top = std::min(kTopDims, cols_);
  std::partial_sort(spread.begin(), spread.begin() + top, spread.end(), [](const auto& a, const auto& b) {
    return a.first != b.first ? a.first > b.first : a.second < b.second;
  });
  const int dim = spread[Next(rng) % static_cast<uint32_t>(top)].second;
  const float value = static_cast<float>(sum[static_cast<size_t>(dim)]) / static_cast<float>(n);
  auto* first = order_.data() + begin;
  auto* last = order_.data() + end;
  auto* mid =
      std::partition(first, last, [&](int32_t r) { return data_[static_cast<size_t>(r) * cols_ + dim] < value; });
  float split = value;
  if (mid == first || mid == last) {  // every sampled value alike: split the range in halves along dim
    mid = first + (end - begin) / 2;
    std::nth_element(first, mid, last, [&](int32_t a, int32_t b) {
      return data_[static_cast<size_t>(a) * cols_ + dim] < data_[static_cast<size_t>(b) * cols_ + dim];
    });
    split = static_cast<float>(data_[static_cast<size_t>(*mid) * cols_ + dim]) - 0.5f;
  }
  const auto cut = static_cast<int32_t>(mid - order_.data());
  const int32_t left = BuildNode(begin, cut, rng);
  const int32_t right = BuildNode(cut, end, rng);
  nodes_[static_cast<size_t>(id)] = {split, left, right, static_cast<int16_t>(dim)};
  return id;
}

void KdForest::Descend(int32_t node_id, float mindist, Search* s) const {
  const Node* node = &nodes_[static_cast<size_t>(node_id)];
  while (node->dim >= 0) {
    const float diff = static_cast<float>(s->query[node->dim]) - node->value;
    const int32_t near = diff < 0 ? node->first : node->second;
    const int32_t far = diff < 0 ? node->second : node->first;
    const float far_dist = mindist + diff * diff;
    // A branch that cannot hold anything nearer than the second best is never worth a visit.
    if (static_cast<double>(far_dist) < static_cast<double>(s->dist[1])) {
      s->heap->emplace_back(far_dist, far);
      std::push_heap(s->heap->begin(), s->heap->end(), std::greater<>());
    }
    node = &nodes_[static_cast<size_t>(near)];
  }
  for (int32_t i = node->first; i < node->second; ++i) {
    const int32_t row = order_[static_cast<size_t>(i)];
    uint64_t& word = (*s->seen)[static_cast<size_t>(row) >> 6];
    const uint64_t bit = uint64_t{1} << (row & 63);
    if ((word & bit) != 0) continue;
    word |= bit;
    ++s->checked;
    const uint32_t d = SquaredL2Bytes(s->query, data_ + static_cast<size_t>(row) * cols_, static_cast<size_t>(cols_));
    if (d < s->dist[0]) {
      s->dist[1] = s->dist[0];
      s->index[1] = s->index[0];
      s->dist[0] = d;
      s->index[0] = row;
    } else if (d < s->dist[1]) {
      s->dist[1] = d;
      s->index[1] = row;
    }
  }
}

void KdForest::Nearest2(const uint8_t* query, int checks, int index[2], uint32_t dist[2]) const {
  // Scratch reused by every query of the thread: no allocation per query once warm.
  thread_local std::vector<std::pair<float, int32_t>> heap;
  thread_local std::vector<uint64_t> seen;
  heap.clear();
  seen.assign(static_cast<size_t>(rows_ / 64 + 1), 0);
  Search s;
  s.query = query;
  s.heap = &heap;
  s.seen = &seen;
  for (const int32_t root : roots_) Descend(root, 0.f, &s);
  while (!heap.empty() && (s.checked < checks || s.index[1] < 0)) {
    std::pop_heap(heap.begin(), heap.end(), std::greater<>());
    const auto [mindist, node] = heap.back();
    heap.pop_back();
    if (static_cast<double>(mindist) >= static_cast<double>(s.dist[1])) break;  // the heap's best cannot do better
    Descend(node, mindist, &s);
  }
  for (int k = 0; k < 2; ++k) {
    index[k] = s.index[static_cast<size_t>(k)];
    dist[k] = s.dist[static_cast<size_t>(k)];
  }
}

}  // namespace uavm
