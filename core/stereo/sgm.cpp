#include "core/stereo/sgm.h"

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <memory>
#if defined(__x86_64__)
#include <immintrin.h>
#endif

#include <opencv2/calib3d.hpp>
#include <opencv2/core/utility.hpp>
#include <opencv2/imgproc.hpp>
#include <vector>

#include "core/util/fail.h"
#include "core/util/memory.h"

// The hot loops are plain C++ that the compiler vectorises; on x86-64 an AVX2 clone is chosen at run time (the
// baseline build targets SSE2 only, and the census cost needs a hardware popcount to be cheap).
#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__)) && !defined(UAVM_FUZZ_BUILD)
#define UAVM_HOT __attribute__((target_clones("avx2", "default")))
#else
#define UAVM_HOT
#endif

namespace uavm::stereo {
namespace {

constexpr int16_t kBig = std::numeric_limits<int16_t>::max() / 4;  // "no path": + P2 stays far below overflow

cv::Mat ToGray(const cv::Mat& image) {
  cv::Mat gray;
  if (image.channels() == 3) {
    cv::cvtColor(image, gray, cv::COLOR_BGR2GRAY);
  } else if (image.channels() == 4) {
    cv::cvtColor(image, gray, cv::COLOR_BGRA2GRAY);
  } else {
    gray = image;
  }
  return gray;
}

// Census bit string: bit set where the neighbour is darker than the centre (window w x h, centre excluded).
cv::Mat Census(const cv::Mat& gray, int w, int h) {
  const int rx = w / 2;
  const int ry = h / 2;
  cv::Mat padded;
  cv::copyMakeBorder(gray, padded, ry, ry, rx, rx, cv::BORDER_REPLICATE);
  cv::Mat census(gray.size(), CV_64FC1);  // 64-bit storage; the bits are reinterpreted as uint64_t
  cv::parallel_for_(cv::Range(0, gray.rows), [&](const cv::Range& rows) {
    for (int y = rows.start; y < rows.end; ++y) {
      auto* out = census.ptr<uint64_t>(y);
      for (int x = 0; x < gray.cols; ++x) out[x] = 0;
      const uint8_t* centre = padded.ptr<uint8_t>(y + ry) + rx;
      for (int dy = -ry; dy <= ry; ++dy) {
        const uint8_t* row = padded.ptr<uint8_t>(y + ry + dy) + rx;
        for (int dx = -rx; dx <= rx; ++dx) {
          if (dx == 0 && dy == 0) continue;
          for (int x = 0; x < gray.cols; ++x) out[x] = (out[x] << 1) | static_cast<uint64_t>(row[x + dx] < centre[x]);
        }
      }
    }
  });
  return census;
}

struct CostParams {
  int width = 0;
  int height = 0;
  int min_disp = 0;
  int num_disp = 0;
  int stride = 0;  // disparities per pixel in the volume (num_disp rounded up to 16)
  int gradient_weight = 0;
};

// Matching cost of one row, disparity-major (t[k * width + x]): Hamming distance of census strings plus the clipped
// difference of horizontal gradients. Disparities that fall outside the right image get a neutral cost, so that the
// paths carry their neighbours' value. The row is transposed into the pixel-major volume afterwards.
inline uint8_t NeutralCost(const CostParams& p) {
  return static_cast<uint8_t>(24 + 4 * p.gradient_weight);
}

// Valid x for disparity index k: 0 <= x - min_disp - k < width.
inline void ValidRange(const CostParams& p, int k, int* x_lo, int* x_hi) {
  *x_lo = std::clamp(p.min_disp + k, 0, p.width);
  *x_hi = std::clamp(p.width + p.min_disp + k, *x_lo, p.width);
}

void CostRowScalar(const uint64_t* __restrict cl, const uint64_t* __restrict cr, const int16_t* __restrict gl,
                   const int16_t* __restrict gr, const CostParams& p, uint8_t* __restrict t) {
  const uint8_t neutral = NeutralCost(p);
  for (int k = 0; k < p.num_disp; ++k) {
    uint8_t* row = t + static_cast<size_t>(k) * p.width;
    int x_lo, x_hi;
    ValidRange(p, k, &x_lo, &x_hi);
    const int shift = p.min_disp + k;
    for (int x = 0; x < x_lo; ++x) row[x] = neutral;
    for (int x = x_lo; x < x_hi; ++x) {
      const int ham = std::popcount(cl[x] ^ cr[x - shift]);
      const int grad = std::min(std::abs(gl[x] - gr[x - shift]), 15) * p.gradient_weight;
      row[x] = static_cast<uint8_t>(std::min(ham + grad, 255));
    }
    for (int x = x_hi; x < p.width; ++x) row[x] = neutral;
  }
}

#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
#define UAVM_HAVE_AVX2_COST 1
// Four 64-bit census XORs counted at once with the nibble-table popcount (AVX2 has no 64-bit popcount).
__attribute__((target("avx2"))) void CostRowAvx2(const uint64_t* __restrict cl, const uint64_t* __restrict cr,
                                                 const int16_t* __restrict gl, const int16_t* __restrict gr,
                                                 const CostParams& p, uint8_t* __restrict t) {
  const uint8_t neutral = NeutralCost(p);
  const __m256i table =
      _mm256_setr_epi8(0, 1, 1, 2, 1, 2, 2, 3, 1, 2, 2, 3, 2, 3, 3, 4, 0, 1, 1, 2, 1, 2, 2, 3, 1, 2, 2, 3, 2, 3, 3, 4);
  const __m256i low4 = _mm256_set1_epi8(0x0f);
  const __m256i zero = _mm256_setzero_si256();
  const __m256i cap = _mm256_set1_epi32(15);
  const __m256i weight = _mm256_set1_epi32(p.gradient_weight);
  const __m256i max255 = _mm256_set1_epi32(255);
  // Low byte of each 64-bit lane -> bytes 0, 1 (lower 128-bit half) and 2, 3 (upper half), then OR of the halves.
  const __m256i gather = _mm256_setr_epi8(0, 8, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, 0, 8,
                                          -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1);
  for (int k = 0; k < p.num_disp; ++k) {
    uint8_t* row = t + static_cast<size_t>(k) * p.width;
    int x_lo, x_hi;
    ValidRange(p, k, &x_lo, &x_hi);
    const int shift = p.min_disp + k;
    for (int x = 0; x < x_lo; ++x) row[x] = neutral;
    int x = x_lo;
    for (; x + 4 <= x_hi; x += 4) {
      const __m256i a = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(cl + x));
      const __m256i b = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(cr + x - shift));
      const __m256i v = _mm256_xor_si256(a, b);
      const __m256i lo = _mm256_shuffle_epi8(table, _mm256_and_si256(v, low4));
      const __m256i hi = _mm256_shuffle_epi8(table, _mm256_and_si256(_mm256_srli_epi16(v, 4), low4));
      const __m256i ham = _mm256_sad_epu8(_mm256_add_epi8(lo, hi), zero);  // 4 x u64
      const __m256i ga = _mm256_cvtepi16_epi64(_mm_loadl_epi64(reinterpret_cast<const __m128i*>(gl + x)));
      const __m256i gb = _mm256_cvtepi16_epi64(_mm_loadl_epi64(reinterpret_cast<const __m128i*>(gr + x - shift)));
      // Only the low 32 bits of each 64-bit lane matter below.
      const __m256i grad =
          _mm256_mullo_epi32(_mm256_min_epi32(_mm256_abs_epi32(_mm256_sub_epi32(ga, gb)), cap), weight);
      const __m256i sum = _mm256_min_epi32(_mm256_add_epi32(ham, grad), max255);
      const __m256i bytes = _mm256_shuffle_epi8(sum, gather);
      const int four =
          _mm_cvtsi128_si32(_mm_or_si128(_mm256_castsi256_si128(bytes), _mm256_extracti128_si256(bytes, 1)));
      std::memcpy(row + x, &four, 4);
    }
    for (; x < x_hi; ++x) {
      const int ham = std::popcount(cl[x] ^ cr[x - shift]);
      const int grad = std::min(std::abs(gl[x] - gr[x - shift]), 15) * p.gradient_weight;
      row[x] = static_cast<uint8_t>(std::min(ham + grad, 255));
    }
    for (x = x_hi; x < p.width; ++x) row[x] = neutral;
  }
}
#endif

// A disparity-major cost row (scratch) into the pixel-major volume (stride disparities per pixel, padding = 255).
void StoreRow(const std::vector<uint8_t>& scratch, const CostParams& p, uint8_t* out) {
  const cv::Mat t(p.num_disp, p.width, CV_8UC1, const_cast<uint8_t*>(scratch.data()));
  cv::Mat dst(p.width, p.num_disp, CV_8UC1, out, static_cast<size_t>(p.stride));
  cv::transpose(t, dst);
  if (p.stride > p.num_disp) {
    for (int x = 0; x < p.width; ++x)
      std::memset(out + static_cast<size_t>(x) * p.stride + p.num_disp, 255,
                  static_cast<size_t>(p.stride - p.num_disp));
  }
}

// DAISY cost of one row, disparity-major: L1 distance of the byte descriptors / divisor, neutral outside the image.
void DaisyCostRow(const uint8_t* dl, const uint8_t* dr, int desc_stride, int divisor, const CostParams& p,
                  std::vector<uint8_t>* scratch, uint8_t* out) {
  scratch->resize(static_cast<size_t>(p.num_disp) * p.width);
  const uint8_t neutral = 32;
  const auto stride = static_cast<size_t>(desc_stride);
  for (int k = 0; k < p.num_disp; ++k) {
    uint8_t* row = scratch->data() + static_cast<size_t>(k) * p.width;
    int x_lo, x_hi;
    ValidRange(p, k, &x_lo, &x_hi);
    const int shift = p.min_disp + k;
    for (int x = 0; x < x_lo; ++x) row[x] = neutral;
    for (int x = x_lo; x < x_hi; ++x) {
      const int d = DaisyDistance(dl + static_cast<size_t>(x) * stride, dr + static_cast<size_t>(x - shift) * stride,
                                  desc_stride);
      row[x] = static_cast<uint8_t>(std::min(d / divisor, 255));
    }
    for (int x = x_hi; x < p.width; ++x) row[x] = neutral;
  }
  StoreRow(*scratch, p, out);
}

// Cost of row y into the pixel-major volume.
void CostRow(const uint64_t* cl, const uint64_t* cr, const int16_t* gl, const int16_t* gr, const CostParams& p,
             std::vector<uint8_t>* scratch, uint8_t* out) {
  scratch->resize(static_cast<size_t>(p.num_disp) * p.width);
#ifdef UAVM_HAVE_AVX2_COST
  static const bool avx2 = __builtin_cpu_supports("avx2");
  if (avx2) {
    CostRowAvx2(cl, cr, gl, gr, p, scratch->data());
  } else {
    CostRowScalar(cl, cr, gl, gr, p, scratch->data());
  }
#else
  CostRowScalar(cl, cr, gl, gr, p, scratch->data());
#endif
  StoreRow(*scratch, p, out);
}

// The whole cost volume: census + gradient, or DAISY.
void BuildCostVolume(const cv::Mat& gl, const cv::Mat& gr, const CostParams& p, const SgmOptions& options,
                     uint8_t* cost) {
  if (options.cost == SgmOptions::Cost::kDaisy) {
    DenseDaisy daisy_l(options.daisy), daisy_r(options.daisy);
    daisy_l.Prepare(gl);
    daisy_r.Prepare(gr);
    const int ds = options.daisy.stride();
    cv::parallel_for_(cv::Range(0, p.height), [&](const cv::Range& rows) {
      std::vector<uint8_t> scratch, dl(static_cast<size_t>(p.width) * static_cast<size_t>(ds)), dr(dl.size());
      for (int y = rows.start; y < rows.end; ++y) {
        daisy_l.Row(y, dl.data());
        daisy_r.Row(y, dr.data());
        DaisyCostRow(dl.data(), dr.data(), ds, options.daisy_divisor, p, &scratch,
                     cost + static_cast<size_t>(y) * p.width * p.stride);
      }
    });
    return;
  }
  const cv::Mat cl = Census(gl, options.census_width, options.census_height);
  const cv::Mat cr = Census(gr, options.census_width, options.census_height);
  cv::Mat sl, sr;
  // Horizontal gradient /8 (Sobel sums 4 differences of 2 pixels): a few grey levels per unit.
  cv::Sobel(gl, sl, CV_16S, 1, 0, 3, 0.125);
  cv::Sobel(gr, sr, CV_16S, 1, 0, 3, 0.125);
  cv::parallel_for_(cv::Range(0, p.height), [&](const cv::Range& rows) {
    std::vector<uint8_t> scratch;
    for (int y = rows.start; y < rows.end; ++y) {
      CostRow(cl.ptr<uint64_t>(y), cr.ptr<uint64_t>(y), sl.ptr<int16_t>(y), sr.ptr<int16_t>(y), p, &scratch,
              cost + static_cast<size_t>(y) * p.width * p.stride);
    }
  });
}

// One step along a path: L(p, d) = C(p, d) + min(L(p-r, d), L(p-r, d+-1) + P1, min L(p-r) + P2) - min L(p-r).
// `prev` has one guard value (kBig) on each side. Returns min_d L(p, d).
UAVM_HOT int16_t PathStep(const uint8_t* __restrict cost, const int16_t* __restrict prev, int16_t prev_min, int16_t p1,
                          int16_t p2, int stride, int16_t* __restrict out) {
  const int16_t jump = static_cast<int16_t>(prev_min + p2);
  int16_t mn = kBig;
  for (int d = 0; d < stride; ++d) {
    int16_t best = std::min(prev[d], jump);
    best = std::min(best, static_cast<int16_t>(std::min(prev[d - 1], prev[d + 1]) + p1));
    const int16_t v = static_cast<int16_t>(cost[d] + best - prev_min);
    out[d] = v;
    mn = std::min(mn, v);
  }
  return mn;
}

UAVM_HOT int16_t PathStart(const uint8_t* __restrict cost, int stride, int16_t* __restrict out) {
  int16_t mn = kBig;
  for (int d = 0; d < stride; ++d) {
    out[d] = cost[d];
    mn = std::min(mn, out[d]);
  }
  return mn;
}

UAVM_HOT void AddPaths(const int16_t* __restrict a, const int16_t* __restrict b, const int16_t* __restrict c,
                       const int16_t* __restrict e, int stride, uint16_t* __restrict sum) {
  for (int d = 0; d < stride; ++d) sum[d] = static_cast<uint16_t>(a[d] + b[d] + c[d] + e[d]);
}

UAVM_HOT void AddPaths2(const int16_t* __restrict a, const int16_t* __restrict b, int stride,
                        uint16_t* __restrict sum) {
  for (int d = 0; d < stride; ++d) sum[d] = static_cast<uint16_t>(a[d] + b[d]);
}

struct PathBuffers {
  // Per direction (horizontal, vertical, diagonal, anti-diagonal) and per row parity: (width + 2) guarded vectors.
  std::vector<int16_t> storage;
  std::vector<int16_t> mins;
  int vec = 0;  // int16 per guarded vector: stride + 2 guards, rounded up
  int width = 0;

  void Init(int w, int stride) {
    width = w;
    vec = stride + 16;
    storage.assign(static_cast<size_t>(4) * 2 * (w + 2) * vec, kBig);
    mins.assign(static_cast<size_t>(4) * 2 * (w + 2), 0);
  }
  // Vector of direction `dir`, row parity `par`, column x (x = -1 and x = width are guard columns).
  int16_t* Vec(int dir, int par, int x) {
    return storage.data() + ((static_cast<size_t>(dir) * 2 + par) * (width + 2) + (x + 1)) * vec + 8;
  }
  int16_t& Min(int dir, int par, int x) { return mins[(static_cast<size_t>(dir) * 2 + par) * (width + 2) + (x + 1)]; }
};

// P2 for a step between two pixels of intensities a and b: smaller across image edges, where depth jumps are likely.
inline int16_t AdaptiveP2(const SgmOptions& o, int a, int b) {
  if (o.p2_gradient_scale <= 0.0) return static_cast<int16_t>(o.p2);
  const double p2 = o.p2 / (1.0 + std::abs(a - b) / o.p2_gradient_scale);
  return static_cast<int16_t>(std::max<double>(std::max(o.p2_min, o.p1 + 1), p2));
}

// One sweep over the image (forward: top-down, left-to-right; backward: the reverse) aggregating 4 paths (or 2 when
// only 4 paths are used in total) into `sum`.
void Sweep(const uint8_t* cost, const cv::Mat& gray, const CostParams& p, const SgmOptions& o, bool forward,
           uint16_t* sum) {
  const int w = p.width;
  const int h = p.height;
  const int s = p.stride;
  const bool diagonals = o.num_paths == 8;
  const int step = forward ? 1 : -1;
  const int16_t p1 = static_cast<int16_t>(o.p1);
  PathBuffers buf;
  buf.Init(w, s);
  for (int i = 0; i < h; ++i) {
    const int y = forward ? i : h - 1 - i;
    const int cur = i & 1;
    const int prv = cur ^ 1;
    const uint8_t* g = gray.ptr<uint8_t>(y);
    const uint8_t* gp = i > 0 ? gray.ptr<uint8_t>(y - step) : nullptr;
    for (int j = 0; j < w; ++j) {
      const int x = forward ? j : w - 1 - j;
      const size_t pix = static_cast<size_t>(y) * w + x;
      const uint8_t* c = cost + pix * s;
      // Horizontal path: previous pixel of this row.
      int16_t* lh = buf.Vec(0, cur, x);
      buf.Min(0, cur, x) = j == 0 ? PathStart(c, s, lh)
                                  : PathStep(c, buf.Vec(0, cur, x - step), buf.Min(0, cur, x - step), p1,
                                             AdaptiveP2(o, g[x], g[x - step]), s, lh);
      // Vertical path: same column of the previous row.
      int16_t* lv = buf.Vec(1, cur, x);
      buf.Min(1, cur, x) =
          i == 0 ? PathStart(c, s, lv)
                 : PathStep(c, buf.Vec(1, prv, x), buf.Min(1, prv, x), p1, AdaptiveP2(o, g[x], gp[x]), s, lv);
      uint16_t* out = sum + pix * s;
      if (!diagonals) {
        AddPaths2(lh, lv, s, out);
        continue;
      }
      int16_t* ld = buf.Vec(2, cur, x);
      const int xd = x - step;
      buf.Min(2, cur, x) = (i == 0 || xd < 0 || xd >= w) ? PathStart(c, s, ld)
                                                         : PathStep(c, buf.Vec(2, prv, xd), buf.Min(2, prv, xd), p1,
                                                                    AdaptiveP2(o, g[x], gp[xd]), s, ld);
      int16_t* la = buf.Vec(3, cur, x);
      const int xa = x + step;
      buf.Min(3, cur, x) = (i == 0 || xa < 0 || xa >= w) ? PathStart(c, s, la)
                                                         : PathStep(c, buf.Vec(3, prv, xa), buf.Min(3, prv, xa), p1,
                                                                    AdaptiveP2(o, g[x], gp[xa]), s, la);
      AddPaths(lh, lv, ld, la, s, out);
    }
  }
}

// Winner-take-all over one row with uniqueness check and sub-pixel refinement; also the right image's
// integer disparity from the same volume (best k over S(x_r + k, k)) for the left-right check. Costs and indices are
// packed as (cost << 16 | k) so that every search is a plain (vectorised) minimum.
UAVM_HOT void SelectRow(const uint16_t* __restrict row_a, const uint16_t* __restrict row_b, const CostParams& p,
                        int uniqueness, float* __restrict dl, int* __restrict il, uint32_t* __restrict right,
                        uint16_t* __restrict sp, uint32_t* __restrict pk) {
  const int w = p.width;
  const int s = p.stride;
  const int n = p.num_disp;
  for (int x = 0; x < w; ++x) right[x] = 0xFFFFFFFFu;
  for (int x = 0; x < w; ++x) {
    // The two sweeps' sums are added here rather than in a separate pass over the volume.
    const uint16_t* a = row_a + static_cast<size_t>(x) * s;
    const uint16_t* b = row_b + static_cast<size_t>(x) * s;
    for (int k = 0; k < s; ++k) sp[k] = static_cast<uint16_t>(a[k] + b[k]);
    uint32_t packed = 0xFFFFFFFFu;
    for (int k = 0; k < n; ++k) {
      pk[k] = (static_cast<uint32_t>(sp[k]) << 16) | static_cast<uint32_t>(k);
      packed = std::min(packed, pk[k]);
    }
    const int best = static_cast<int>(packed & 0xFFFFu);
    const int best_cost = static_cast<int>(packed >> 16);
    // Right view: pixel x_r = x - min_disp - k, for k in range and x_r inside the image.
    const int k_lo = std::max(0, x - p.min_disp - (w - 1));
    const int k_hi = std::min(n - 1, x - p.min_disp);
    // Written with ascending x_r (descending k) so that the loop vectorises.
    const uint32_t* top = pk + k_hi;
    uint32_t* r = right + (x - p.min_disp - k_hi);
    const int count = k_hi - k_lo + 1;
    for (int j = 0; j < count; ++j) r[j] = std::min(r[j], top[-j]);
    uint16_t second = 0xFFFFu;
    for (int k = 0; k < best - 1; ++k) second = std::min(second, sp[k]);
    for (int k = best + 2; k < n; ++k) second = std::min(second, sp[k]);
    if (second * (100 - uniqueness) < best_cost * 100) {
      il[x] = -1;
      dl[x] = std::numeric_limits<float>::quiet_NaN();
      continue;
    }
    il[x] = best;
    double sub = best;
    if (best > 0 && best < n - 1) {
      const int c0 = sp[best - 1];
      const int c2 = sp[best + 1];
      // Equiangular (V-shaped) fit rather than a parabola: census costs grow linearly with the offset, and the
      // parabola pulls estimates towards whole pixels (mean error at quarter-pixel shifts 0.16 px vs 0.09 px).
      const int denom = 2 * (std::max(c0, c2) - best_cost);
      if (denom > 0) sub += static_cast<double>(c0 - c2) / denom;
    }
    dl[x] = static_cast<float>(sub + p.min_disp);
  }
}

void SelectDisparities(const uint16_t* sum_a, const uint16_t* sum_b, const CostParams& p, const SgmOptions& o,
                       cv::Mat* left, cv::Mat* left_int, cv::Mat* right_int) {
  const int w = p.width;
  *left = cv::Mat(p.height, w, CV_32FC1);
  *left_int = cv::Mat(p.height, w, CV_32SC1);
  *right_int = cv::Mat(p.height, w, CV_32SC1);
  cv::parallel_for_(cv::Range(0, p.height), [&](const cv::Range& rows) {
    std::vector<uint32_t> right(static_cast<size_t>(w));
    std::vector<uint16_t> sp(static_cast<size_t>(p.stride));
    std::vector<uint32_t> pk(static_cast<size_t>(p.stride));
    for (int y = rows.start; y < rows.end; ++y) {
      const size_t row = static_cast<size_t>(y) * w * p.stride;
      SelectRow(sum_a + row, sum_b + row, p, o.uniqueness_ratio, left->ptr<float>(y), left_int->ptr<int>(y),
                right.data(), sp.data(), pk.data());
      int* ir = right_int->ptr<int>(y);
      for (int x = 0; x < w; ++x) ir[x] = right[x] == 0xFFFFFFFFu ? -1 : static_cast<int>(right[x] & 0xFFFFu);
    }
  });
}

// Invalid pixels take the lower (farther) of the nearest valid disparities left and right on the same row: holes
// are mostly occlusions, which belong to the background.
void FillHoles(cv::Mat* disp) {
  const int w = disp->cols;
  std::vector<float> left_val(static_cast<size_t>(w));
  for (int y = 0; y < disp->rows; ++y) {
    float* d = disp->ptr<float>(y);
    float last = std::numeric_limits<float>::quiet_NaN();
    for (int x = 0; x < w; ++x) {
      if (std::isfinite(d[x])) last = d[x];
      left_val[x] = last;
    }
    last = std::numeric_limits<float>::quiet_NaN();
    for (int x = w - 1; x >= 0; --x) {
      if (std::isfinite(d[x])) {
        last = d[x];
        continue;
      }
      const float a = left_val[x];
      const float b = last;
      if (std::isfinite(a) && std::isfinite(b)) {
        d[x] = std::min(a, b);
      } else if (std::isfinite(a)) {
        d[x] = a;
      } else if (std::isfinite(b)) {
        d[x] = b;
      }
    }
  }
}

}  // namespace

bool SgmOptions::Check(std::string* why) const {
  auto bad = [&](const char* what) {
    if (why) *why = what;
    return false;
  };
  if (num_disparities < 1 || num_disparities > 1024) return bad("num_disparities must be in [1, 1024]");
  if (census_width < 1 || census_height < 1 || census_width % 2 == 0 || census_height % 2 == 0 ||
      census_width * census_height - 1 > 64)
    return bad("census window must be odd-sized with at most 65 pixels");
  if (gradient_weight < 0 || gradient_weight > 8) return bad("gradient_weight must be in [0, 8]");
  if (p1 < 0 || p2 < p1 || p2 > 2000 || p2_min < 0) return bad("need 0 <= p1 <= p2 <= 2000, p2_min >= 0");
  if (num_paths != 4 && num_paths != 8) return bad("num_paths must be 4 or 8");
  if (uniqueness_ratio < 0 || uniqueness_ratio >= 100) return bad("uniqueness_ratio must be in [0, 100)");
  if (speckle_size < 0 || speckle_range < 0) return bad("speckle settings must be >= 0");
  if (median_size != 0 && median_size != 3 && median_size != 5) return bad("median_size must be 0, 3 or 5");
  if (threads < 0) return bad("threads must be >= 0");
  if (max_memory_mib < 1) return bad("max_memory_mib must be >= 1");
  if (daisy_divisor < 1) return bad("daisy_divisor must be >= 1");
  if (cost == Cost::kDaisy && !daisy.Check(why)) return false;
  return true;
}

bool ComputeDisparity(const cv::Mat& left, const cv::Mat& right, const SgmOptions& options, cv::Mat* disparity,
                      std::string* error, cv::Mat* measured) {
  SgmMatcher matcher(options);
  return matcher.Compute(left, right, disparity, error, measured);
}

void SgmMatcher::ReleaseBuffers() {
  cost_ = std::vector<uint8_t>();
  sum_[0] = std::vector<uint16_t>();
  sum_[1] = std::vector<uint16_t>();
}

bool SgmMatcher::Compute(const cv::Mat& left, const cv::Mat& right, cv::Mat* disparity, std::string* error,
                         cv::Mat* measured) {
  const SgmOptions& options = options_;
  std::string why;
  if (!options.Check(&why)) return Fail(error, "bad stereo options: " + why);
  if (left.empty() || right.empty()) return Fail(error, "empty input image");
  if (left.size() != right.size()) return Fail(error, "left and right images differ in size");
  if (left.depth() != CV_8U || right.depth() != CV_8U) return Fail(error, "images must be 8-bit");
  if (disparity == nullptr) return Fail(error, "no output");
  const int saved_threads = cv::getNumThreads();
  if (options.threads > 0) cv::setNumThreads(options.threads);

  const cv::Mat gl = ToGray(left);
  const cv::Mat gr = ToGray(right);
  CostParams p;
  p.width = left.cols;
  p.height = left.rows;
  p.min_disp = options.min_disparity;
  p.num_disp = options.num_disparities;
  p.stride = (options.num_disparities + 15) / 16 * 16;
  p.gradient_weight = options.gradient_weight;

  const size_t volume = static_cast<size_t>(p.width) * p.height * p.stride;
  double need_mib = 5.0 * static_cast<double>(volume) / kMiB;
  if (options.cost == SgmOptions::Cost::kDaisy) {
    need_mib += 2.0 * static_cast<double>(DenseDaisy::LayerBytes(options.daisy, p.width, p.height)) / kMiB;
  }
  if (need_mib > options.max_memory_mib) {
    if (options.threads > 0) cv::setNumThreads(saved_threads);
    return Fail(error, "matching " + std::to_string(p.width) + "x" + std::to_string(p.height) + " pixels over " +
                           std::to_string(p.num_disp) + " disparities needs " +
                           std::to_string(static_cast<int>(need_mib)) + " MiB, more than the limit of " +
                           std::to_string(options.max_memory_mib) +
                           " MiB: reduce the disparity range or the image size");
  }
  if (cost_.size() < volume) cost_.resize(volume);
  uint8_t* cost = cost_.data();
  BuildCostVolume(gl, gr, p, options, cost);

  // The two sweeps are independent: one per core, each into its own sum (added during the selection).
  for (auto& sum : sum_)
    if (sum.size() < volume) sum.resize(volume);
  uint16_t* sum_forward = sum_[0].data();
  uint16_t* sum_backward = sum_[1].data();
  cv::parallel_for_(cv::Range(0, 2), [&](const cv::Range& r) {
    for (int k = r.start; k < r.end; ++k) Sweep(cost, gl, p, options, k == 0, k == 0 ? sum_forward : sum_backward);
  });

  cv::Mat disp, left_int, right_int;
  SelectDisparities(sum_forward, sum_backward, p, options, &disp, &left_int, &right_int);

  const float nan = std::numeric_limits<float>::quiet_NaN();
  if (options.lr_tolerance >= 0.0) {
    for (int y = 0; y < p.height; ++y) {
      float* d = disp.ptr<float>(y);
      const int* il = left_int.ptr<int>(y);
      const int* ir = right_int.ptr<int>(y);
      for (int x = 0; x < p.width; ++x) {
        if (il[x] < 0) continue;
        const int xr = x - p.min_disp - il[x];
        if (xr < 0 || xr >= p.width || ir[xr] < 0 || std::abs(ir[xr] - il[x]) > options.lr_tolerance) d[x] = nan;
      }
    }
  }
  if (options.speckle_size > 0) {
    // filterSpeckles works on 16-bit fixed point (1/16 px); invalid pixels are marked with a value below the range.
    cv::Mat fixed(disp.size(), CV_16SC1);
    const int16_t invalid = static_cast<int16_t>((p.min_disp - 1) * 16);
    for (int y = 0; y < p.height; ++y) {
      const float* d = disp.ptr<float>(y);
      int16_t* f = fixed.ptr<int16_t>(y);
      for (int x = 0; x < p.width; ++x)
        f[x] = std::isfinite(d[x]) ? static_cast<int16_t>(std::lround(d[x] * 16.0f)) : invalid;
    }
    cv::filterSpeckles(fixed, invalid, options.speckle_size, options.speckle_range * 16.0);
    for (int y = 0; y < p.height; ++y) {
      float* d = disp.ptr<float>(y);
      const int16_t* f = fixed.ptr<int16_t>(y);
      for (int x = 0; x < p.width; ++x)
        if (f[x] == invalid) d[x] = nan;
    }
  }
  if (measured) {
    *measured = cv::Mat(disp.size(), CV_8UC1);
    for (int y = 0; y < p.height; ++y) {
      const float* d = disp.ptr<float>(y);
      uint8_t* m = measured->ptr<uint8_t>(y);
      for (int x = 0; x < p.width; ++x) m[x] = std::isfinite(d[x]) ? 255 : 0;
    }
  }
  if (options.fill_holes) {
    FillHoles(&disp);
    if (options.median_size > 0) {
      // medianBlur on float supports 3 and 5; NaN cannot remain after filling unless a whole row was empty.
      cv::Mat finite_mask(disp.size(), CV_8UC1);
      for (int y = 0; y < disp.rows; ++y) {
        const float* d = disp.ptr<float>(y);
        uint8_t* m = finite_mask.ptr<uint8_t>(y);
        for (int x = 0; x < disp.cols; ++x) m[x] = std::isfinite(d[x]) ? 255 : 0;
      }
      cv::Mat filtered;
      cv::Mat tmp = disp.clone();
      tmp.setTo(0.0f, ~finite_mask);
      cv::medianBlur(tmp, filtered, options.median_size);
      filtered.setTo(nan, ~finite_mask);
      disp = filtered;
    }
  }
  *disparity = disp;
  if (options.threads > 0) cv::setNumThreads(saved_threads);
  return true;
}

}  // namespace uavm::stereo
