#pragma once
// The fixed-point blur's loops (core/features/q15_blur.h), written once over the widest integer register a
// translation unit has: included by q15_blur.cpp (NEON on aarch64, 8-lane scalar loops elsewhere) and, on x86-64, by
// q15_blur_avx2.cpp (compiled with -mavx2). Everything here has internal linkage, and no standard header is included:
// an inline function compiled with -mavx2 could otherwise be the copy the linker keeps for the whole program.
//
// Every path computes the same integers: the taps' products summed exactly in 32 bits, then rounded once,
// (sum + 2^14) >> 15 (an arithmetic shift). The weights are positive and sum to 32768, so no sum leaves
// +-2^30 and a blurred value stays within the range of those it was blurred from.
#include <stdint.h>

#if defined(__AVX2__)
#include <immintrin.h>
#elif defined(__aarch64__)
#include <arm_neon.h>
#endif

namespace uavm::q15_kernels {
namespace {

#define UAVM_Q15_INLINE inline __attribute__((always_inline))

inline int16_t NarrowScalar(int32_t sum) {
  return static_cast<int16_t>((sum + 16384) >> 15);
}

// Lanes: a register of int16 values; Sums: their 32-bit sums (two registers). Pair(s, a, b, w) adds w (a + b) to s,
// One(s, c, w) adds w c.
#if defined(__AVX2__)
// vpmaddwd multiplies pairs of int16 and adds each pair: a and b interleaved, times (w, w), give w a + w b per lane in
// the interleaving's order (within each 128-bit half), which vpackssdw undoes.
using Lanes = __m256i;
struct Sums {
  __m256i low, high;
};
constexpr int kLanes = 16;
constexpr int kRowVectors = 2;
constexpr int kColumnVectors = 1;
UAVM_Q15_INLINE Lanes Load(const int16_t* p) {
  return _mm256_loadu_si256(reinterpret_cast<const __m256i*>(p));
}
UAVM_Q15_INLINE void Store(int16_t* p, Lanes v) {
  _mm256_storeu_si256(reinterpret_cast<__m256i*>(p), v);
}
UAVM_Q15_INLINE Lanes Weight(int16_t w) {
  return _mm256_set1_epi16(w);
}
UAVM_Q15_INLINE Sums Zero() {
  return {_mm256_setzero_si256(), _mm256_setzero_si256()};
}
UAVM_Q15_INLINE Sums Pair(Sums s, Lanes a, Lanes b, Lanes w) {
  return {_mm256_add_epi32(s.low, _mm256_madd_epi16(_mm256_unpacklo_epi16(a, b), w)),
          _mm256_add_epi32(s.high, _mm256_madd_epi16(_mm256_unpackhi_epi16(a, b), w))};
}
UAVM_Q15_INLINE Sums One(Sums s, Lanes c, Lanes w) {
  return Pair(s, c, _mm256_setzero_si256(), w);
}
UAVM_Q15_INLINE Lanes Narrow(Sums s) {
  const __m256i half = _mm256_set1_epi32(16384);
  return _mm256_packs_epi32(_mm256_srai_epi32(_mm256_add_epi32(s.low, half), 15),
                            _mm256_srai_epi32(_mm256_add_epi32(s.high, half), 15));
}
#elif defined(__aarch64__)
// smlal widens and accumulates in one (a pair's sum would not fit 16 bits: the values use all of them).
using Lanes = int16x8_t;
struct Sums {
  int32x4_t low, high;
};
constexpr int kLanes = 8;
constexpr int kRowVectors = 4;
constexpr int kColumnVectors = 2;
UAVM_Q15_INLINE Lanes Load(const int16_t* p) {
  return vld1q_s16(p);
}
UAVM_Q15_INLINE void Store(int16_t* p, Lanes v) {
  vst1q_s16(p, v);
}
UAVM_Q15_INLINE Lanes Weight(int16_t w) {
  return vdupq_n_s16(w);
}
UAVM_Q15_INLINE Sums Zero() {
  return {vdupq_n_s32(0), vdupq_n_s32(0)};
}
UAVM_Q15_INLINE Sums One(Sums s, Lanes c, Lanes w) {
  return {vmlal_s16(s.low, vget_low_s16(c), vget_low_s16(w)), vmlal_high_s16(s.high, c, w)};
}
UAVM_Q15_INLINE Sums Pair(Sums s, Lanes a, Lanes b, Lanes w) {
  return One(One(s, a, w), b, w);
}
UAVM_Q15_INLINE Lanes Narrow(Sums s) {
  return vcombine_s16(vrshrn_n_s32(s.low, 15), vrshrn_n_s32(s.high, 15));
}
#else
struct Lanes {
  int16_t v[8];
};
struct Sums {
  int32_t v[8];
};
constexpr int kLanes = 8;
constexpr int kRowVectors = 4;
constexpr int kColumnVectors = 2;
UAVM_Q15_INLINE Lanes Load(const int16_t* p) {
  Lanes l;
  for (int k = 0; k < kLanes; ++k) l.v[k] = p[k];
  return l;
}
UAVM_Q15_INLINE void Store(int16_t* p, Lanes l) {
  for (int k = 0; k < kLanes; ++k) p[k] = l.v[k];
}
UAVM_Q15_INLINE Lanes Weight(int16_t w) {
  Lanes l;
  for (int k = 0; k < kLanes; ++k) l.v[k] = w;
  return l;
}
UAVM_Q15_INLINE Sums Zero() {
  return Sums{};
}
UAVM_Q15_INLINE Sums Pair(Sums s, Lanes a, Lanes b, Lanes w) {
  for (int k = 0; k < kLanes; ++k) s.v[k] += w.v[k] * a.v[k] + w.v[k] * b.v[k];
  return s;
}
UAVM_Q15_INLINE Sums One(Sums s, Lanes c, Lanes w) {
  for (int k = 0; k < kLanes; ++k) s.v[k] += w.v[k] * c.v[k];
  return s;
}
UAVM_Q15_INLINE Lanes Narrow(Sums s) {
  Lanes l;
  for (int k = 0; k < kLanes; ++k) l.v[k] = NarrowScalar(s.v[k]);
  return l;
}
#endif

// out[x] = w0 c[x] + sum_i w_i (c[x-i] + c[x+i]) for x in [0, n), c = padded + radius; kRowVectors registers of
// columns over every tap before they are stored.
UAVM_Q15_INLINE void ConvolveRowLanes(const int16_t* __restrict padded, int n, const int16_t* __restrict w, int radius,
                                      int16_t* __restrict out) {
  constexpr int kBlock = kRowVectors * kLanes;
  const int16_t* c = padded + radius;
  int x0 = 0;
  for (; x0 + kBlock <= n; x0 += kBlock) {
    const int16_t* p = c + x0;
    const Lanes w0 = Weight(w[0]);
    Sums a[kRowVectors];
#pragma GCC unroll 8
    for (int k = 0; k < kRowVectors; ++k) a[k] = One(Zero(), Load(p + k * kLanes), w0);
    for (int i = 1; i <= radius; ++i) {
      const Lanes wi = Weight(w[i]);
      const int16_t* left = p - i;
      const int16_t* right = p + i;
#pragma GCC unroll 8
      for (int k = 0; k < kRowVectors; ++k) a[k] = Pair(a[k], Load(left + k * kLanes), Load(right + k * kLanes), wi);
    }
#pragma GCC unroll 8
    for (int k = 0; k < kRowVectors; ++k) Store(out + x0 + k * kLanes, Narrow(a[k]));
  }
  for (int x = x0; x < n; ++x) {
    int32_t sum = w[0] * c[x];
    for (int i = 1; i <= radius; ++i) sum += w[i] * c[x - i] + w[i] * c[x + i];
    out[x] = NarrowScalar(sum);
  }
}

// Two rows of the vertical pass (out0 from rows[0 .. 2 radius], out1 from rows[1 .. 2 radius + 1]); each row loaded
// serves both.
UAVM_Q15_INLINE void ConvolveColumnPairLanes(const int16_t* const* __restrict rows, int n, const int16_t* __restrict w,
                                             int radius, int16_t* __restrict out0, int16_t* __restrict out1) {
  constexpr int kBlock = kColumnVectors * kLanes;
  int x0 = 0;
  for (; x0 + kBlock <= n; x0 += kBlock) {
    const int16_t* c0 = rows[radius] + x0;
    const int16_t* c1 = rows[radius + 1] + x0;
    const Lanes w0 = Weight(w[0]);
    Lanes low[kColumnVectors], high[kColumnVectors];
    Sums a[kColumnVectors], b[kColumnVectors];
#pragma GCC unroll 8
    for (int k = 0; k < kColumnVectors; ++k) {
      low[k] = Load(c0 + k * kLanes);   // row radius + 1 - i at step i
      high[k] = Load(c1 + k * kLanes);  // row radius + i
      a[k] = One(Zero(), low[k], w0);
      b[k] = One(Zero(), high[k], w0);
    }
    // Two taps a step, so that the rows loaded change roles without register copies (GCC moved low and high into
    // fresh registers at every tap: a quarter of this loop's instructions on aarch64).
    int i = 1;
    for (; i + 1 <= radius; i += 2) {
      const Lanes wi = Weight(w[i]);
      const Lanes wj = Weight(w[i + 1]);
      const int16_t* lo_i = rows[radius - i] + x0;
      const int16_t* hi_i = rows[radius + 1 + i] + x0;
      const int16_t* lo_j = rows[radius - i - 1] + x0;
      const int16_t* hi_j = rows[radius + 2 + i] + x0;
#pragma GCC unroll 8
      for (int k = 0; k < kColumnVectors; ++k) {
        const Lanes li = Load(lo_i + k * kLanes);
        const Lanes hi = Load(hi_i + k * kLanes);
        a[k] = Pair(a[k], li, high[k], wi);
        b[k] = Pair(b[k], low[k], hi, wi);
        const Lanes lj = Load(lo_j + k * kLanes);
        const Lanes hj = Load(hi_j + k * kLanes);
        a[k] = Pair(a[k], lj, hi, wj);
        b[k] = Pair(b[k], li, hj, wj);
        low[k] = lj;
        high[k] = hj;
      }
    }
    if (i == radius) {
      const Lanes wi = Weight(w[i]);
      const int16_t* lo = rows[radius - i] + x0;
      const int16_t* hi = rows[radius + 1 + i] + x0;
#pragma GCC unroll 8
      for (int k = 0; k < kColumnVectors; ++k) {
        a[k] = Pair(a[k], Load(lo + k * kLanes), high[k], wi);
        b[k] = Pair(b[k], low[k], Load(hi + k * kLanes), wi);
      }
    }
#pragma GCC unroll 8
    for (int k = 0; k < kColumnVectors; ++k) {
      Store(out0 + x0 + k * kLanes, Narrow(a[k]));
      Store(out1 + x0 + k * kLanes, Narrow(b[k]));
    }
  }
  for (int x = x0; x < n; ++x) {
    int32_t sum0 = w[0] * rows[radius][x];
    int32_t sum1 = w[0] * rows[radius + 1][x];
    for (int i = 1; i <= radius; ++i) {
      sum0 += w[i] * rows[radius - i][x] + w[i] * rows[radius + i][x];
      sum1 += w[i] * rows[radius + 1 - i][x] + w[i] * rows[radius + 1 + i][x];
    }
    out0[x] = NarrowScalar(sum0);
    out1[x] = NarrowScalar(sum1);
  }
}

#undef UAVM_Q15_INLINE

}  // namespace
}  // namespace uavm::q15_kernels
