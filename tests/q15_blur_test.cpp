#include "core/features/q15_blur.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <random>
#include <vector>

namespace uavm {
namespace {

// Q15 weights of a Gaussian (w0 + 2 sum w_i = 32768), as the scale space's kernels.
std::vector<int16_t> Weights(double sigma, int radius) {
  std::vector<double> w(static_cast<size_t>(radius) + 1);
  double sum = 0.0;
  for (int i = 0; i <= radius; ++i) {
    w[static_cast<size_t>(i)] = std::exp(-0.5 * i * i / (sigma * sigma));
    sum += (i == 0 ? 1.0 : 2.0) * w[static_cast<size_t>(i)];
  }
  std::vector<int16_t> q;
  int total = 0;
  for (double v : w) {
    q.push_back(static_cast<int16_t>(std::lround(v / sum * 32768.0)));
    total += (q.size() == 1 ? 1 : 2) * q.back();
  }
  q[0] = static_cast<int16_t>(q[0] + 32768 - total);
  return q;
}

// The reference: the exact sum in 64 bits, rounded half up (the real-valued one is checked against it below).
int16_t Exact(const std::vector<int16_t>& c, int x, const std::vector<int16_t>& w) {
  int64_t sum = int64_t{w[0]} * c[static_cast<size_t>(x)];
  for (size_t i = 1; i < w.size(); ++i)
    sum += int64_t{w[i]} * (c[static_cast<size_t>(x) - i] + c[static_cast<size_t>(x) + i]);
  return static_cast<int16_t>((sum + 16384) >> 15);
}

std::vector<int16_t> Random(size_t n, std::mt19937* rng) {
  std::uniform_int_distribution<int> value(-32768, 32767);
  std::vector<int16_t> v(n);
  for (auto& x : v) x = static_cast<int16_t>(value(*rng));
  return v;
}

// Every width (the vector blocks and the scalar tails) and radius: the exact sum rounded once, within half a unit of
// the real-valued convolution, on the instruction set the CPU has and on the generic code alike.
TEST(Q15BlurTest, RowPassIsTheExactSumRoundedOnce) {
  std::mt19937 rng(5);
  for (int radius = 1; radius <= 9; ++radius) {
    const std::vector<int16_t> w = Weights(radius / 3.0, radius);
    for (int n : {1, 7, 15, 16, 17, 31, 32, 33, 63, 64, 65, 100, 333}) {
      const std::vector<int16_t> padded = Random(static_cast<size_t>(n + 2 * radius), &rng);
      std::vector<int16_t> out(static_cast<size_t>(n)), generic(static_cast<size_t>(n));
      q15::ConvolveRow(padded.data(), n, w.data(), radius, out.data());
      q15::generic::ConvolveRow(padded.data(), n, w.data(), radius, generic.data());
      for (int x = 0; x < n; ++x) {
        const int16_t exact = Exact(padded, x + radius, w);
        ASSERT_EQ(out[static_cast<size_t>(x)], exact) << "radius " << radius << " n " << n << " x " << x;
        ASSERT_EQ(generic[static_cast<size_t>(x)], exact);
        double real = w[0] * double{padded[static_cast<size_t>(x + radius)]};
        for (int i = 1; i <= radius; ++i)
          real += w[static_cast<size_t>(i)] * double{padded[static_cast<size_t>(x + radius - i)]} +
                  w[static_cast<size_t>(i)] * double{padded[static_cast<size_t>(x + radius + i)]};
        EXPECT_LE(std::abs(exact - real / 32768.0), 0.5 + 1e-9);
      }
    }
  }
}

TEST(Q15BlurTest, ColumnPairIsTheExactSumRoundedOnce) {
  std::mt19937 rng(9);
  for (int radius = 1; radius <= 9; ++radius) {
    const std::vector<int16_t> w = Weights(radius / 3.0, radius);
    for (int n : {1, 8, 15, 16, 17, 32, 33, 100, 257}) {
      std::vector<std::vector<int16_t>> rows;
      std::vector<const int16_t*> pointers;
      for (int r = 0; r < 2 * radius + 2; ++r) rows.push_back(Random(static_cast<size_t>(n), &rng));
      for (const auto& r : rows) pointers.push_back(r.data());
      std::vector<int16_t> out0(static_cast<size_t>(n)), out1(static_cast<size_t>(n));
      std::vector<int16_t> g0(static_cast<size_t>(n)), g1(static_cast<size_t>(n));
      q15::ConvolveColumnPair(pointers.data(), n, w.data(), radius, out0.data(), out1.data());
      q15::generic::ConvolveColumnPair(pointers.data(), n, w.data(), radius, g0.data(), g1.data());
      for (int x = 0; x < n; ++x) {
        for (int k = 0; k < 2; ++k) {
          std::vector<int16_t> column;
          for (const auto& r : rows) column.push_back(r[static_cast<size_t>(x)]);
          const int16_t exact = Exact(column, radius + k, w);
          ASSERT_EQ((k == 0 ? out0 : out1)[static_cast<size_t>(x)], exact) << "radius " << radius << " n " << n;
          ASSERT_EQ((k == 0 ? g0 : g1)[static_cast<size_t>(x)], exact);
        }
      }
    }
  }
}

// A flat image stays flat at any value, the extremes included: no overflow, no drift over the octaves' blurs.
TEST(Q15BlurTest, FlatStaysFlatAndTheMaximumHolds) {
  for (int radius = 1; radius <= 9; ++radius) {
    const std::vector<int16_t> w = Weights(radius / 3.0, radius);
    for (int16_t v : {int16_t{-32768}, int16_t{-1}, int16_t{0}, int16_t{12345}, int16_t{32767}}) {
      const std::vector<int16_t> padded(static_cast<size_t>(100 + 2 * radius), v);
      std::vector<int16_t> out(100);
      q15::ConvolveRow(padded.data(), 100, w.data(), radius, out.data());
      for (int16_t o : out) ASSERT_EQ(o, v);
    }
  }
}

}  // namespace
}  // namespace uavm
