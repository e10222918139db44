#pragma once
// Squared L2 distance between 8-bit descriptors for cvflann's kd-trees, computed in integers (AVX2 where the CPU has
// it). cvflann::L2<unsigned char> sums in float, one element at a time, and its searches spent most of their time
// there. Every partial sum of 8-bit differences squared is an integer below 2^24 (128 x 255^2 = 8.3 M), so the float
// result is the same exact integer either way: the same neighbours, on x86-64 and aarch64 alike.
#include <cstddef>
#include <cstdint>
#include <opencv2/flann.hpp>
#include <type_traits>

namespace uavm {

// Sum over i < n of (a[i] - b[i])^2.
[[nodiscard]] uint32_t SquaredL2Bytes(const uint8_t* a, const uint8_t* b, size_t n);

struct ByteL2 {
  using is_kdtree_distance = cvflann::True;
  using is_vector_space_distance = cvflann::True;
  using ElementType = unsigned char;
  using ResultType = float;
  using CentersType = float;

  // The whole distance: the kd-tree search compares it with the worst kept, an early exit would save little here.
  // Other operands (cluster centres of the index types cvflann instantiates but this project does not use) are summed
  // as cvflann::L2 does.
  template <typename Iterator1, typename Iterator2>
  ResultType operator()(Iterator1 a, Iterator2 b, size_t size, ResultType /*worst_dist*/ = -1) const {
    using A = std::remove_cv_t<std::remove_pointer_t<Iterator1>>;
    using B = std::remove_cv_t<std::remove_pointer_t<Iterator2>>;
    if constexpr (std::is_pointer_v<Iterator1> && std::is_pointer_v<Iterator2> && std::is_same_v<A, unsigned char> &&
                  std::is_same_v<B, unsigned char>) {
      return static_cast<ResultType>(SquaredL2Bytes(a, b, size));
    } else {
      ResultType sum = 0;
      for (size_t i = 0; i < size; ++i, ++a, ++b) {
        const auto d = static_cast<ResultType>(*a - *b);
        sum += d * d;
      }
      return sum;
    }
  }
  // Distance along one dimension to a splitting value, as cvflann::L2 computes it.
  template <typename U, typename V>
  ResultType accum_dist(const U& a, const V& b, int /*dim*/) const {
    return static_cast<ResultType>((a - b) * (a - b));
  }
};

}  // namespace uavm
