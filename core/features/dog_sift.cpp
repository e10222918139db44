#include "core/features/dog_sift.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <numeric>
#include <optional>
#include <tuple>
#include <type_traits>
#include <utility>

#if defined(__aarch64__)
#include <arm_neon.h>
#endif

#include "core/features/portable_math.h"
#include "core/features/q15_blur.h"
#include "core/util/burst_workers.h"

// The vector loops (convolution, subtraction, doubling, gradients, descriptor votes, extremum mask) are compiled twice
// on x86-64 (AVX2 and the SSE2 baseline, chosen at load time); each lane does the same float operations in the same
// order as the scalar code, so both give the same bits.
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
#define UAVM_SIMD_CLONES __attribute__((target_clones("avx2", "default")))
#else
#define UAVM_SIMD_CLONES
#endif

namespace uavm {
namespace {

constexpr int kImageBorder = 5;  // no extremum closer to the edge (OpenCV's SIFT_IMG_BORDER)
constexpr int kMaxInterpolationSteps = 5;
constexpr float kInputSigma = 0.5f;  // blur assumed in the input
constexpr int kOrientationBins = 36;
constexpr float kOrientationSigmaFactor = 1.5f;
constexpr float kOrientationRadiusFactor = 3.f * kOrientationSigmaFactor;
constexpr float kOrientationPeakRatio = 0.8f;
constexpr int kDescriptorWidth = 4;  // 4 x 4 cells
constexpr int kDescriptorBins = 8;   // of 8 directions
constexpr int kDescriptorSize = kDescriptorWidth * kDescriptorWidth * kDescriptorBins;
constexpr float kDescriptorCellFactor = 3.f;  // a cell is 3 sigma wide
constexpr float kDescriptorClip = 0.2f;
constexpr float kDescriptorScale = 512.f;
constexpr int kRowsPerTask = 64;
// The scale space's images are int16: grey levels x 256 - 32768 (core/features/q15_blur.h), all 16 bits for 0 .. 255.
// A unit is 1/256 grey, and a blur pass rounds once, by at most half a unit (the same scale space at 1/128 grey cost
// the simulated flights ~10 % of their accuracy against the truth). Differences (DoG, gradients) drop the offset.
constexpr double kFixedScale = 256.0;
constexpr int kFixedOffset = -32768;
// Kernels reach 3 sigma (OpenCV: 4 for float images): measured the same matches and precision, 1/4 fewer taps.
constexpr double kKernelRadiusSigmas = 3.0;

// ---- Separable Gaussian --------------------------------------------------------------------------------------------

struct Kernel {
  int radius = 0;
  std::vector<int16_t> weights;  // weights[i] for offsets +-i, Q15 (x 32768): w0 + 2 sum w_i = 32768 exactly
};

// Radius kKernelRadiusSigmas sigma, weights normalised in double, then rounded to Q15 with the centre's taking the
// rounding's remainder, so that a flat image stays flat but for the taps' rounding.
Kernel GaussianKernel(double sigma) {
  Kernel k;
  const int size = static_cast<int>(std::floor(sigma * kKernelRadiusSigmas * 2.0 + 1.0 + 0.5)) | 1;
  k.radius = size / 2;
  std::vector<double> w(static_cast<size_t>(k.radius) + 1);
  double sum = 0.0;
  for (int i = 0; i <= k.radius; ++i) {
    w[static_cast<size_t>(i)] = portable::Exp(-0.5 * i * i / (sigma * sigma));
    sum += (i == 0 ? 1.0 : 2.0) * w[static_cast<size_t>(i)];
  }
  int total = 0;
  for (double v : w) {
    k.weights.push_back(static_cast<int16_t>(std::lround(v / sum * 32768.0)));
    total += (k.weights.size() == 1 ? 1 : 2) * k.weights.back();
  }
  // (a kernel of under ~0.15 sigma is all centre: 32767, a flat image loses 1/32768 of its value)
  k.weights[0] = static_cast<int16_t>(std::min(k.weights[0] + 32768 - total, 32767));
  return k;
}

int Reflect101(int i, int n) {
  if (n == 1) return 0;
  while (i < 0 || i >= n) i = i < 0 ? -i : 2 * n - 2 - i;
  return i;
}

// Eight floats as one value (GCC's vector extension): one AVX register in the AVX2 clone, two SSE registers in the
// baseline one. Each lane does exactly the scalar code's operations, so every path gives the same bits.
#pragma GCC diagnostic ignored "-Wpsabi"  // vectors by value: only between always-inlined helpers (below)
#define UAVM_INLINE inline __attribute__((always_inline))
using Float8 = float __attribute__((vector_size(32)));
using Int8 = int __attribute__((vector_size(32)));  // lane masks (-1 true) and bin indices
// Lane helpers of the code written for either vector, V = Float8 or a 4-float vector. Functions, not lambdas, so
// that they are always inlined: a vector passed by value between an AVX2 clone and a default-target function would
// not agree on how it is passed (unoptimised builds call lambdas).
// (On aarch64 NEON's own unaligned load and store: GCC copied a 4-float vector's memcpy through two general
// registers and the stack.)
template <typename V>
UAVM_INLINE V LoadLanes(const float* p) {
#if defined(__aarch64__)
  if constexpr (sizeof(V) == 16) return reinterpret_cast<V>(vld1q_f32(p));
#endif
  V v;
  std::memcpy(&v, p, sizeof v);
  return v;
}
template <typename V>
UAVM_INLINE void StoreLanes(float* p, V v) {
#if defined(__aarch64__)
  if constexpr (sizeof(V) == 16) {
    vst1q_f32(p, reinterpret_cast<float32x4_t>(v));
    return;
  }
#endif
  std::memcpy(p, &v, sizeof v);
}
// floor as integers for |v| < 2^31: truncation, minus one where it rounded up (negative non-integers).
template <typename V, typename I>
UAVM_INLINE I FloorLanes(V v) {
  const I t = __builtin_convertvector(v, I);
  return t + (__builtin_convertvector(t, V) > v);
}
// a and b interleaved (a0 b0 a1 b1 ...) at p[0 .. 2 lanes).
template <typename V>
UAVM_INLINE void StorePairLanes(float* p, V a, V b) {
  if constexpr (sizeof(V) == sizeof(Float8)) {  // (__builtin_shufflevector: GCC 12 and clang)
    StoreLanes(p, V{__builtin_shufflevector(a, b, 0, 8, 1, 9, 2, 10, 3, 11)});
    StoreLanes(p + 8, V{__builtin_shufflevector(a, b, 4, 12, 5, 13, 6, 14, 7, 15)});
  } else {
    StoreLanes(p, V{__builtin_shufflevector(a, b, 0, 4, 1, 5)});
    StoreLanes(p + 4, V{__builtin_shufflevector(a, b, 2, 6, 3, 7)});
  }
}

// One register's floats and ints: an AVX register on x86-64, a NEON register on aarch64. GCC keeps 8-float vectors
// in memory on aarch64 (no 256-bit registers): it stored and reloaded the blur's accumulators at every tap, splatted a
// weight by eight scalar stores, and compared and selected lane by lane in scalar code. The filters below are written
// once for either width (templates over V), with the same operations per lane in the same order, so the same bits.
#if defined(__aarch64__)
using RegisterFloats = float __attribute__((vector_size(16)));
using RegisterInts = int __attribute__((vector_size(16)));
#else
using RegisterFloats = Float8;
using RegisterInts = Int8;
#endif

// Saturating: a DoG of 128 grey levels is beyond any image (a step edge's is ~14). On aarch64 NEON's sqsub (GCC 12
// widened, clamped and narrowed: 8 instructions for 8 lanes), the same values.
UAVM_SIMD_CLONES void SubtractRow(const int16_t* a, const int16_t* b, int n, int16_t* out) {
  int x = 0;
#if defined(__aarch64__)
  for (; x + 8 <= n; x += 8) vst1q_s16(out + x, vqsubq_s16(vld1q_s16(a + x), vld1q_s16(b + x)));
#endif
  for (; x < n; ++x) out[x] = static_cast<int16_t>(std::clamp(a[x] - b[x], -32768, 32767));
}

// The workers the loops of the detection running on this thread use (DetectAndDescribeSift's `workers`), or none:
// cv::parallel_for_. No loop body starts a loop of its own.
thread_local BurstWorkers* tls_workers = nullptr;

// tls_workers for a scope (then back to what it was).
class WorkersScope {
 public:
  explicit WorkersScope(BurstWorkers* workers) : outer_(tls_workers) { tls_workers = workers; }
  ~WorkersScope() { tls_workers = outer_; }
  WorkersScope(const WorkersScope&) = delete;
  WorkersScope& operator=(const WorkersScope&) = delete;

 private:
  BurstWorkers* outer_;
};

// fn(begin, end) over [0, n) in parallel, for ranges of items that may share scratch: on the held workers `pieces`
// equal ranges (claimed in turn: the caller takes those a late worker has not), else the ranges OpenCV's pool
// chooses.
template <typename Fn>
void ForRanges(int n, int pieces, Fn&& fn) {
  if (n <= 0) return;
  if (tls_workers == nullptr) {
    cv::parallel_for_(cv::Range(0, n), [&](const cv::Range& range) { fn(range.start, range.end); });
    return;
  }
  pieces = std::clamp(pieces, 1, n);
  tls_workers->ForEach(pieces, [&](int p) {
    fn(static_cast<int>(static_cast<int64_t>(n) * p / pieces),
       static_cast<int>(static_cast<int64_t>(n) * (p + 1) / pieces));
  });
}

// Threads a loop of this detection runs on: the held workers and the caller, or OpenCV's pool.
int LoopThreads() {
  return tls_workers != nullptr ? tls_workers->threads() + 1 : cv::getNumThreads();
}

// Pieces of a loop over many small items (keypoints) on the held workers: each a few hundred microseconds. (OpenCV's
// pool chooses its own ranges: ForRanges ignores this without workers.)
int ItemPieces() {
  return 8 * LoopThreads();
}

// fn(y0, y1) for each task's rows [y0, y1) of [0, rows), in parallel: two tasks a thread, each of at least min_rows
// rows.
template <typename Fn>
void ForRowBlocks(int rows, int min_rows, Fn&& fn) {
  const int tasks = std::max(1, std::min(2 * LoopThreads(), rows / std::max(1, min_rows)));
  ForRanges(tasks, tasks, [&](int begin, int end) {
    for (int t = begin; t < end; ++t)
      fn(static_cast<int>(static_cast<int64_t>(rows) * t / tasks),
         static_cast<int>(static_cast<int64_t>(rows) * (t + 1) / tasks));
  });
}

// out[x] for x in [0, cols): row `s` convolved by `kernel`, borders reflected (BORDER_REFLECT_101). The inside straight
// from the row; each border (r columns) from a reflected copy of its 3 r neighbours in `padded` (cols + 2 r values).
void ConvolveRowReflected(const int16_t* s, int cols, const Kernel& kernel, int16_t* padded, int16_t* out) {
  using q15::ConvolveRow;
  const int r = kernel.radius;
  const int16_t* w = kernel.weights.data();
  if (cols < 4 * r) {
    for (int i = 0; i < cols + 2 * r; ++i) padded[i] = s[Reflect101(i - r, cols)];
    ConvolveRow(padded, cols, w, r, out);
    return;
  }
  for (int i = 0; i < 3 * r; ++i) padded[i] = s[Reflect101(i - r, cols)];
  ConvolveRow(padded, r, w, r, out);
  ConvolveRow(s, cols - 2 * r, w, r, out + r);
  for (int i = 0; i < 3 * r; ++i) padded[i] = s[Reflect101(cols - 2 * r + i, cols)];
  ConvolveRow(padded, r, w, r, out + cols - r);
}

// The blur of `src` by `kernel` (borders reflected as OpenCV's BORDER_REFLECT_101) into `blurred` (not src), row by
// row while the row is in cache. Each task keeps a ring of 2 radius + 2 horizontally blurred rows and writes two output
// rows a step (ConvolveColumnPair); an odd task's last step writes its second row to a spare row.
void Blur(const cv::Mat& src, const Kernel& kernel, cv::Mat& blurred) {
  const int rows = src.rows;
  const int cols = src.cols;
  const int r = kernel.radius;
  const int ring_rows = 2 * r + 2;
  const auto width = static_cast<size_t>(cols);
  ForRowBlocks(rows, kRowsPerTask, [&](int y0, int y1) {
    std::vector<int16_t> padded(static_cast<size_t>(cols + 2 * r));
    std::vector<int16_t> ring(static_cast<size_t>(ring_rows) * width);
    std::vector<const int16_t*> window(static_cast<size_t>(ring_rows));
    std::vector<int16_t> spare;
    auto ring_row = [&](int y) {
      return ring.data() + static_cast<size_t>(((y % ring_rows) + ring_rows) % ring_rows) * width;
    };
    auto horizontal = [&](int y) {
      ConvolveRowReflected(src.ptr<int16_t>(Reflect101(y, rows)), cols, kernel, padded.data(), ring_row(y));
    };
    for (int y = y0 - r; y < y0 + r; ++y) horizontal(y);
    for (int y = y0; y < y1; y += 2) {
      horizontal(y + r);
      horizontal(y + r + 1);
      for (int i = 0; i < ring_rows; ++i) window[static_cast<size_t>(i)] = ring_row(y - r + i);
      if (y + 1 == y1) spare.resize(width);
      q15::ConvolveColumnPair(window.data(), cols, kernel.weights.data(), r, blurred.ptr<int16_t>(y),
                              y + 1 < y1 ? blurred.ptr<int16_t>(y + 1) : spare.data());
    }
  });
}

// out[2 x], out[2 x + 1] = the row at input x - 0.25 and x + 0.25, in grey levels x 64: 48 s[x] + 16 s[x -+ 1] (0.75
// and 0.25 of the two pixels; edges clamped). Exact in integers.
UAVM_SIMD_CLONES void WidenRow(const uchar* __restrict s, int cols, int16_t* __restrict out) {
  auto one = [&](int i) {
    const int v = 48 * s[i];
    out[2 * i] = static_cast<int16_t>(v + 16 * s[std::max(i - 1, 0)]);
    out[2 * i + 1] = static_cast<int16_t>(v + 16 * s[std::min(i + 1, cols - 1)]);
  };
  if (cols < 3) {
    for (int x = 0; x < cols; ++x) one(x);
    return;
  }
  one(0);
  for (int x = 1; x + 1 < cols; ++x) {
    const int v = 48 * s[x];
    out[2 * x] = static_cast<int16_t>(v + 16 * s[x - 1]);
    out[2 * x + 1] = static_cast<int16_t>(v + 16 * s[x + 1]);
  }
  one(cols - 1);
}

// even[x], odd[x] = the rows at -0.25 and +0.25 of `here` (grey x 64) in the scale space's units: 3 here + above
// (below), plus the offset.
UAVM_SIMD_CLONES void BlendRows(const int16_t* __restrict above, const int16_t* __restrict here,
                                const int16_t* __restrict below, int n, int16_t* __restrict even,
                                int16_t* __restrict odd) {
  for (int x = 0; x < n; ++x) {
    const int v = 3 * here[x] + kFixedOffset;
    even[x] = static_cast<int16_t>(v + above[x]);
    odd[x] = static_cast<int16_t>(v + below[x]);
  }
}

// The input doubled by linear interpolation between pixel centres (output pixel X sits at input X / 2 - 0.25), in
// grey levels x kFixedScale: exact (the weights are sixteenths).
void Upsample2x(const cv::Mat& gray, cv::Mat& dst) {
  const int cols = gray.cols;
  const int rows = gray.rows;
  ForRowBlocks(rows, kRowsPerTask / 2, [&](int y0, int y1) {
    std::vector<int16_t> wide(static_cast<size_t>(3 * 2 * cols));
    auto widen = [&](int y, int16_t* out) { WidenRow(gray.ptr<uchar>(std::clamp(y, 0, rows - 1)), cols, out); };
    int16_t* above = wide.data();
    int16_t* here = above + 2 * cols;
    int16_t* below = here + 2 * cols;
    widen(y0 - 1, above);
    widen(y0, here);
    for (int y = y0; y < y1; ++y) {
      widen(y + 1, below);
      BlendRows(above, here, below, 2 * cols, dst.ptr<int16_t>(2 * y), dst.ptr<int16_t>(2 * y + 1));
      std::swap(above, here);
      std::swap(here, below);
    }
  });
}

// dst = every second pixel of src (rows and columns), dst's size.
void Decimate(const cv::Mat& src, cv::Mat& dst) {
  for (int y = 0; y < dst.rows; ++y) {
    const int16_t* s = src.ptr<int16_t>(2 * y);
    auto* d = dst.ptr<int16_t>(y);
    for (int x = 0; x < dst.cols; ++x) d[x] = s[2 * x];
  }
}

// ---- Extrema -------------------------------------------------------------------------------------------------------

struct Candidate {
  int octave = 0;
  int row = 0, col = 0, layer = 0;  // integer position after interpolation (octave pixels)
  float x = 0.f, y = 0.f;           // sub-pixel position (octave pixels)
  float layer_offset = 0.f;
  float response = 0.f;
  double contrast = 0.0;  // |DoG| * octave_layers: what the thresholds compare (exactly)
  int peak = 0;           // |DoG| of the sample the search found, before the fit: what the first rejection compares
};

// Lowe's first rejection for `contrast_threshold`: |DoG| above half of it, in whole units of the images.
int PeakThreshold(double contrast_threshold, int octave_layers) {
  return static_cast<int>(
      std::min(std::floor(0.5 * contrast_threshold / octave_layers * 255.0 * kFixedScale), 32767.0));
}

// An octave's difference-of-Gaussian images, computed where they are read: DoG l = Gaussian l + 1 - Gaussian l, the
// same float subtraction the stored images held. Storing them was L + 2 more images of the octave's size to write and
// read back (and their room in the memory plan); the extremum search reads their rows once, the tests below a few
// pixels around each candidate.
class DogLayers {
 public:
  explicit DogLayers(const std::vector<cv::Mat>& gauss) : gauss_(gauss) {}
  [[nodiscard]] int rows() const { return gauss_[0].rows; }
  [[nodiscard]] int cols() const { return gauss_[0].cols; }
  [[nodiscard]] int At(int layer, int r, int c) const {
    return std::clamp(Gauss(layer + 1).at<int16_t>(r, c) - Gauss(layer).at<int16_t>(r, c), -32768, 32767);
  }
  // Row r of DoG layer `layer`, every column, into out.
  void Row(int layer, int r, int16_t* out) const {
    SubtractRow(Gauss(layer + 1).ptr<int16_t>(r), Gauss(layer).ptr<int16_t>(r), cols(), out);
  }

 private:
  [[nodiscard]] const cv::Mat& Gauss(int layer) const { return gauss_[static_cast<size_t>(layer)]; }
  const std::vector<cv::Mat>& gauss_;
};

// Whether DoG (layer, r, c) is a maximum (or minimum) of its 26 neighbours. The values are integers, so neighbours tie
// (floats almost never did): a sample must beat those before it in (layer, row, column) order and match or beat those
// after it, so that a plateau gives one extremum, not several at one place.
bool IsExtremum26(const DogLayers& dog, int layer, int r, int c) {
  const int v = dog.At(layer, r, c);
  const int sign = v > 0 ? 1 : -1;
  bool before = true;
  for (int l = layer - 1; l <= layer + 1; ++l) {
    for (int dy = -1; dy <= 1; ++dy) {
      for (int dx = -1; dx <= 1; ++dx) {
        if (l == layer && dy == 0 && dx == 0) {
          before = false;
          continue;
        }
        const int margin = sign * (v - dog.At(l, r + dy, c + dx));
        if (before ? margin <= 0 : margin < 0) return false;
      }
    }
  }
  return true;
}

// mask[c] = 1 where row `cur` beats the contrast pre-threshold and is a maximum (or minimum) of its 8 neighbours in
// the layer and of the same pixel in the layers below and above (`below`, `above`: their row), for c in [first, last).
// Branch-free, so that it vectorises. The two cross-layer pixels leave a quarter of the candidates for the full
// 26-neighbour test (140k -> 33k on a 1000x750 frame), whose scalar loads and branches cost more than the two
// vector compares.
// Short lanes of the extremum mask (the same tests as the scalar loop below, on a register of int16 at a time; GCC
// widened the scalar loop's compares to int32 lanes). On aarch64 NEON's own load (see LoadLanes).
using RegisterShorts = short __attribute__((vector_size(sizeof(RegisterFloats))));
using RegisterBytes = char __attribute__((vector_size(sizeof(RegisterFloats) / 2)));
UAVM_INLINE RegisterShorts LoadShorts(const int16_t* p) {
#if defined(__aarch64__)
  return reinterpret_cast<RegisterShorts>(vld1q_s16(p));
#else
  RegisterShorts v;
  std::memcpy(&v, p, sizeof v);
  return v;
#endif
}
UAVM_INLINE RegisterShorts MaxShorts(RegisterShorts a, RegisterShorts b) {
  return a > b ? a : b;
}
UAVM_INLINE RegisterShorts MinShorts(RegisterShorts a, RegisterShorts b) {
  return a < b ? a : b;
}
// Whether any lane of a compare's result (0 or -1 lanes) is set.
UAVM_INLINE bool AnyLane(RegisterShorts m) {
#if defined(__aarch64__)
  return vmaxvq_u16(vreinterpretq_u16_s16(reinterpret_cast<int16x8_t>(m))) != 0;
#else
  uint64_t words[sizeof m / sizeof(uint64_t)];
  std::memcpy(words, &m, sizeof m);
  uint64_t any = 0;
  for (const uint64_t w : words) any |= w;
  return any != 0;
#endif
}

UAVM_SIMD_CLONES void ExtremumMaskRow(const int16_t* __restrict up, const int16_t* __restrict cur,
                                      const int16_t* __restrict dn, const int16_t* __restrict below,
                                      const int16_t* __restrict above, int first, int last, int threshold,
                                      uchar* __restrict mask) {
  using V = RegisterShorts;
  constexpr int kLanes = static_cast<int>(sizeof(V) / sizeof(int16_t));
  const auto t = static_cast<short>(threshold);  // within 0 .. 32767 (FindExtrema)
  const auto minus_t = static_cast<short>(-threshold);
  int c = first;
  for (; c + kLanes <= last; c += kLanes) {
    const V v = LoadShorts(cur + c);
    // Most of a smooth octave is below the pre-threshold: no lane can be set, and the neighbours need not be read.
    if (!AnyLane((v > t) | (v < minus_t))) {
      std::memset(mask + c, 0, kLanes);
      continue;
    }
    const V u0 = LoadShorts(up + c - 1), u1 = LoadShorts(up + c), u2 = LoadShorts(up + c + 1);
    const V d0 = LoadShorts(dn + c - 1), d1 = LoadShorts(dn + c), d2 = LoadShorts(dn + c + 1);
    const V left = LoadShorts(cur + c - 1), right = LoadShorts(cur + c + 1);
    const V b = LoadShorts(below + c), a = LoadShorts(above + c);
    const V hi_before = MaxShorts(MaxShorts(MaxShorts(u0, u1), MaxShorts(u2, left)), b);
    const V lo_before = MinShorts(MinShorts(MinShorts(u0, u1), MinShorts(u2, left)), b);
    const V hi_after = MaxShorts(MaxShorts(MaxShorts(d0, d1), MaxShorts(d2, right)), a);
    const V lo_after = MinShorts(MinShorts(MinShorts(d0, d1), MinShorts(d2, right)), a);
    const V set = ((v > t) & (v > hi_before) & (v >= hi_after)) | ((v < minus_t) & (v < lo_before) & (v <= lo_after));
    const RegisterBytes bytes = __builtin_convertvector(set, RegisterBytes) & 1;
    std::memcpy(mask + c, &bytes, sizeof bytes);
  }
  using std::max;
  using std::min;
  for (; c < last; ++c) {
    const int v = cur[c];
    // Before c in (layer, row, column) order (beaten strictly, IsExtremum26), and after it.
    const int hi_before = max(max(max(up[c - 1], up[c]), max(up[c + 1], cur[c - 1])), below[c]);
    const int lo_before = min(min(min(up[c - 1], up[c]), min(up[c + 1], cur[c - 1])), below[c]);
    const int hi_after = max(max(max(dn[c - 1], dn[c]), max(dn[c + 1], cur[c + 1])), above[c]);
    const int lo_after = min(min(min(dn[c - 1], dn[c]), min(dn[c + 1], cur[c + 1])), above[c]);
    mask[c] = static_cast<uchar>(((v > threshold) & (v > hi_before) & (v >= hi_after)) |
                                 ((v < -threshold) & (v < lo_before) & (v <= lo_after)));
  }
}

// Lowe's quadratic fit in (x, y, scale), moving to the neighbouring sample while the offset exceeds half a pixel;
// rejects low contrast and edges (OpenCV's adjustLocalExtrema, in double).
bool Interpolate(const DogLayers& dog, const DogSiftOptions& o, double threshold, int layer, int r, int c,
                 Candidate* out) {
  const double scale = 1.0 / (255.0 * kFixedScale);
  const int rows = dog.rows();
  const int cols = dog.cols();
  double xc = 0, xr = 0, xs = 0;
  double d[3] = {0, 0, 0};
  int step = 0;
  for (; step < kMaxInterpolationSteps; ++step) {
    const int img = layer;
    const int prev = layer - 1;
    const int next = layer + 1;
    auto at = [&dog](int l, int y, int x) { return static_cast<double>(dog.At(l, y, x)); };
    d[0] = (at(img, r, c + 1) - at(img, r, c - 1)) * 0.5 * scale;
    d[1] = (at(img, r + 1, c) - at(img, r - 1, c)) * 0.5 * scale;
    d[2] = (at(next, r, c) - at(prev, r, c)) * 0.5 * scale;
    const double v2 = at(img, r, c) * 2.0;
    const double dxx = (at(img, r, c + 1) + at(img, r, c - 1) - v2) * scale;
    const double dyy = (at(img, r + 1, c) + at(img, r - 1, c) - v2) * scale;
    const double dss = (at(next, r, c) + at(prev, r, c) - v2) * scale;
    const double dxy =
        (at(img, r + 1, c + 1) - at(img, r + 1, c - 1) - at(img, r - 1, c + 1) + at(img, r - 1, c - 1)) * 0.25 * scale;
    const double dxs =
        (at(next, r, c + 1) - at(next, r, c - 1) - at(prev, r, c + 1) + at(prev, r, c - 1)) * 0.25 * scale;
    const double dys =
        (at(next, r + 1, c) - at(next, r - 1, c) - at(prev, r + 1, c) + at(prev, r - 1, c)) * 0.25 * scale;
    // Solve H X = d by the adjugate.
    const double c00 = dyy * dss - dys * dys;
    const double c01 = dxs * dys - dxy * dss;
    const double c02 = dxy * dys - dxs * dyy;
    const double det = dxx * c00 + dxy * c01 + dxs * c02;
    if (!(std::abs(det) > 1e-30)) return false;
    const double c11 = dxx * dss - dxs * dxs;
    const double c12 = dxs * dxy - dxx * dys;
    const double c22 = dxx * dyy - dxy * dxy;
    xc = -(c00 * d[0] + c01 * d[1] + c02 * d[2]) / det;
    xr = -(c01 * d[0] + c11 * d[1] + c12 * d[2]) / det;
    xs = -(c02 * d[0] + c12 * d[1] + c22 * d[2]) / det;
    if (std::abs(xs) < 0.5 && std::abs(xr) < 0.5 && std::abs(xc) < 0.5) break;
    if (std::abs(xs) > 1e6 || std::abs(xr) > 1e6 || std::abs(xc) > 1e6) return false;
    c += static_cast<int>(std::lround(xc));
    r += static_cast<int>(std::lround(xr));
    layer += static_cast<int>(std::lround(xs));
    if (layer < 1 || layer > o.octave_layers || c < kImageBorder || c >= cols - kImageBorder || r < kImageBorder ||
        r >= rows - kImageBorder)
      return false;
  }
  if (step >= kMaxInterpolationSteps) return false;
  auto at = [&dog, layer](int y, int x) { return static_cast<double>(dog.At(layer, y, x)); };
  const double value = at(r, c);
  const double contrast = value * scale + 0.5 * (d[0] * xc + d[1] * xr + d[2] * xs);
  if (std::abs(contrast) * o.octave_layers < threshold) return false;
  const double v2 = value * 2.0;
  const double dxx = (at(r, c + 1) + static_cast<double>(at(r, c - 1)) - v2) * scale;
  const double dyy = (at(r + 1, c) + static_cast<double>(at(r - 1, c)) - v2) * scale;
  const double dxy =
      (static_cast<double>(at(r + 1, c + 1)) - at(r + 1, c - 1) - at(r - 1, c + 1) + at(r - 1, c - 1)) * 0.25 * scale;
  const double trace = dxx + dyy;
  const double det = dxx * dyy - dxy * dxy;
  const double e = o.edge_threshold;
  if (det <= 0 || trace * trace * e >= (e + 1) * (e + 1) * det) return false;
  out->row = r;
  out->col = c;
  out->layer = layer;
  out->x = static_cast<float>(c + xc);
  out->y = static_cast<float>(r + xr);
  out->layer_offset = static_cast<float>(xs);
  out->response = static_cast<float>(std::abs(contrast));
  out->contrast = std::abs(contrast) * o.octave_layers;
  return true;
}

// A search task's scratch: the DoG rows of every layer at rows r - 1, r and r + 1 (a ring by row) and the mask.
struct SearchRows {
  // DoG row y of layer l (0 .. L + 1) for y in a ring of 3.
  [[nodiscard]] int16_t* At(int l, int y) {
    return data.data() + (static_cast<size_t>(l) * 3 + static_cast<size_t>(y % 3)) * width;  // y >= 0
  }
  size_t width = 0;
  std::vector<int16_t> data;
  std::vector<uchar> mask;
};

// Candidates of layer `layer` at row r: the extremum mask over the ring's DoG rows, then the 26-neighbour test and the
// fit where it is set.
void SearchRow(const DogLayers& dog, const DogSiftOptions& o, double contrast_threshold, int threshold, int octave,
               int layer, int r, SearchRows* rows, std::vector<Candidate>* found) {
  const int cols = dog.cols();
  ExtremumMaskRow(rows->At(layer, r - 1), rows->At(layer, r), rows->At(layer, r + 1), rows->At(layer - 1, r),
                  rows->At(layer + 1, r), kImageBorder, cols - kImageBorder, threshold, rows->mask.data());
  const uchar* mask = rows->mask.data();
  for (int c = kImageBorder; c < cols - kImageBorder; ++c) {
    if (c + 8 <= cols - kImageBorder) {  // most of the mask is zero: skip it eight bytes at a time
      uint64_t word = 0;
      std::memcpy(&word, mask + c, sizeof word);
      if (word == 0) {
        c += 7;
        continue;
      }
    }
    if (mask[c] == 0) continue;
    if (!IsExtremum26(dog, layer, r, c)) continue;
    Candidate k;
    k.octave = octave;
    k.peak = std::abs(int{rows->At(layer, r)[c]});
    if (Interpolate(dog, o, contrast_threshold, layer, r, c, &k)) found->push_back(k);
  }
}

// Candidates of one octave, in row-major order per layer (deterministic for any number of threads). Each task sweeps
// its rows once for every layer, with the DoG rows of all layers in a ring of three: each Gaussian row is read once
// (searched layer by layer, each was read four or five times).
void FindExtrema(const DogLayers& dog, const DogSiftOptions& o, double contrast_threshold, int octave,
                 std::vector<Candidate>* all) {
  const int rows = dog.rows();
  const int cols = dog.cols();
  const int threshold = PeakThreshold(contrast_threshold, o.octave_layers);
  const int inner_rows = rows - 2 * kImageBorder;
  if (inner_rows <= 0 || cols <= 2 * kImageBorder) return;
  const int dog_layers = o.octave_layers + 2;
  const int tasks = std::max(1, std::min(16, inner_rows / 32));
  // found[layer - 1][task]
  std::vector<std::vector<std::vector<Candidate>>> found(
      static_cast<size_t>(o.octave_layers), std::vector<std::vector<Candidate>>(static_cast<size_t>(tasks)));
  ForRanges(tasks, tasks, [&](int begin, int end) {
    SearchRows ring;
    ring.width = static_cast<size_t>(cols);
    ring.data.resize(static_cast<size_t>(dog_layers) * 3 * ring.width);
    ring.mask.resize(ring.width);
    for (int t = begin; t < end; ++t) {
      const int y0 = kImageBorder + static_cast<int>(static_cast<int64_t>(inner_rows) * t / tasks);
      const int y1 = kImageBorder + static_cast<int>(static_cast<int64_t>(inner_rows) * (t + 1) / tasks);
      for (int l = 0; l < dog_layers; ++l) {
        dog.Row(l, y0 - 1, ring.At(l, y0 - 1));
        dog.Row(l, y0, ring.At(l, y0));
      }
      for (int r = y0; r < y1; ++r) {
        for (int l = 0; l < dog_layers; ++l) dog.Row(l, r + 1, ring.At(l, r + 1));
        for (int layer = 1; layer <= o.octave_layers; ++layer)
          SearchRow(dog, o, contrast_threshold, threshold, octave, layer, r, &ring,
                    &found[static_cast<size_t>(layer - 1)][static_cast<size_t>(t)]);
      }
    }
  });
  for (const auto& layer : found)
    for (const auto& f : layer) all->insert(all->end(), f.begin(), f.end());
}

// ---- Orientation and descriptor ------------------------------------------------------------------------------------

// Gaussian weights e^(-k^2 / (2 sigma^2)) for k in [-radius, radius], at k + radius.
void GaussianWeights(float sigma, int radius, std::vector<float>* w) {
  w->resize(2 * static_cast<size_t>(radius) + 1);
  for (int k = 0; k <= radius; ++k) {
    const auto v = static_cast<float>(portable::Exp(-0.5 * k * k / (double{sigma} * sigma)));
    (*w)[static_cast<size_t>(radius + k)] = v;
    (*w)[static_cast<size_t>(radius - k)] = v;
  }
}

// Per pixel of a row segment: gradient magnitude times weight[j] * row_weight and direction in degrees
// (portable::Atan2Degrees, a vector V of lanes at a time: the same operations in the same order as the scalar loop).
// V is Float8 (one AVX register) on x86-64 and a vector of 4 floats (one NEON register) on aarch64, where GCC compares
// and selects 8-float vectors lane by lane in scalar code (97 compares and selects in this function).
// a - b as floats (exact: taken in int32): gradients in grey levels x kFixedScale, a scale the directions and the
// normalised descriptor do not see. (In int16 a steep edge's difference could overflow.) On aarch64 NEON's widening
// subtraction: GCC 12 converted a vector of 4 int16 lane by lane through general registers.
template <typename V>
UAVM_INLINE V DifferenceLanes(const int16_t* __restrict a, const int16_t* __restrict b) {
#if defined(__aarch64__)
  if constexpr (sizeof(V) == 16) return reinterpret_cast<V>(vcvtq_f32_s32(vsubl_s16(vld1_s16(a), vld1_s16(b))));
#endif
  using Shorts8 = short __attribute__((vector_size(16)));
  using Shorts4 = short __attribute__((vector_size(8)));
  using Ints4 = int __attribute__((vector_size(16)));
  using Shorts = std::conditional_t<sizeof(V) == 32, Shorts8, Shorts4>;
  using Ints = std::conditional_t<sizeof(V) == 32, Int8, Ints4>;
  Shorts x;
  Shorts y;
  std::memcpy(&x, a, sizeof x);
  std::memcpy(&y, b, sizeof y);
  return __builtin_convertvector(__builtin_convertvector(x, Ints) - __builtin_convertvector(y, Ints), V);
}

// Length and direction in degrees (portable::Atan2Degrees' steps, lane by lane) of the vectors (dx, dy).
template <typename V>
UAVM_INLINE void PolarLanes(V dx, V dy, V* length, V* degrees) {
  constexpr int kLanes = static_cast<int>(sizeof(V) / sizeof(float));
  V norm = dx * dx + dy * dy;
  for (int k = 0; k < kLanes; ++k) norm[k] = std::sqrt(norm[k]);  // one vector square root (-fno-math-errno)
  *length = norm;
  V ax = dx;
  V ay = dy;
  for (int k = 0; k < kLanes; ++k) {
    ax[k] = std::fabs(ax[k]);
    ay[k] = std::fabs(ay[k]);
  }
  const auto steep = ax < ay;
  const V lo = steep ? ax : ay;
  const V hi = steep ? ay : ax;
  const V c = lo / (hi + portable::kAtanEpsilon);
  const V c2 = c * c;
  V a = (((portable::kAtanP7 * c2 + portable::kAtanP5) * c2 + portable::kAtanP3) * c2 + portable::kAtanP1) * c;
  a = steep ? 90.f - a : a;
  a = dx < 0.f ? 180.f - a : a;
  a = dy < 0.f ? 360.f - a : a;
  *degrees = a >= 360.f ? a - 360.f : a;
}

template <typename V>
UAVM_INLINE void GradientLanes(const int16_t* __restrict above, const int16_t* __restrict row,
                               const int16_t* __restrict below, int n, const float* __restrict weight, float row_weight,
                               float* __restrict magnitude, float* __restrict degrees) {
  constexpr int kLanes = static_cast<int>(sizeof(V) / sizeof(float));
  if (n < kLanes) {
    for (int j = 0; j < n; ++j) {
      const auto dx = static_cast<float>(row[j + 1] - row[j - 1]);
      const auto dy = static_cast<float>(above[j] - below[j]);
      magnitude[j] = std::sqrt(dx * dx + dy * dy) * (weight[j] * row_weight);
      degrees[j] = portable::Atan2Degrees(dy, dx);
    }
    return;
  }
  // The last block ends at n, overlapping the one before (its lanes give the same values again).
  for (int j = 0; j < n; j += kLanes) {
    j = std::min(j, n - kLanes);
    V norm;
    V a;
    PolarLanes(DifferenceLanes<V>(row + j + 1, row + j - 1), DifferenceLanes<V>(above + j, below + j), &norm, &a);
    StoreLanes(magnitude + j, norm * (LoadLanes<V>(weight + j) * row_weight));
    StoreLanes(degrees + j, a);
  }
}

UAVM_SIMD_CLONES void GradientRow(const int16_t* __restrict above, const int16_t* __restrict row,
                                  const int16_t* __restrict below, int n, const float* __restrict weight,
                                  float row_weight, float* __restrict magnitude, float* __restrict degrees) {
  GradientLanes<RegisterFloats>(above, row, below, n, weight, row_weight, magnitude, degrees);
}

// Length x weight and direction in degrees of n >= 1 vectors (dx, dy), a vector of lanes at a time.
UAVM_SIMD_CLONES void PolarRow(const float* __restrict dx, const float* __restrict dy, int n,
                               const float* __restrict weight, float* __restrict magnitude, float* __restrict degrees) {
  using V = RegisterFloats;
  constexpr int kLanes = static_cast<int>(sizeof(V) / sizeof(float));
  int j = 0;
  for (; j + kLanes <= n; j += kLanes) {
    V norm;
    V a;
    PolarLanes(LoadLanes<V>(dx + j), LoadLanes<V>(dy + j), &norm, &a);
    StoreLanes(magnitude + j, norm * LoadLanes<V>(weight + j));
    StoreLanes(degrees + j, a);
  }
  for (; j < n; ++j) {
    magnitude[j] = std::sqrt(dx[j] * dx[j] + dy[j] * dy[j]) * weight[j];
    degrees[j] = portable::Atan2Degrees(dy[j], dx[j]);
  }
}

// A window's rows lie 2 bytes x the image's width apart, so the hardware sees no stream to prefetch. Asks for row y's
// columns [x0, x0 + n) a few rows ahead of use (nothing outside the image; measured a few per cent, within noise).
constexpr int kPrefetchRowsAhead = 4;
inline void PrefetchRow(const cv::Mat& img, int y, int x0, int n) {
  if (y < 0 || y >= img.rows) return;
  const int16_t* p = img.ptr<int16_t>(y);
  const int end = std::min(x0 + n, img.cols);
  for (int x = std::max(x0, 0); x < end; x += 32) __builtin_prefetch(p + x);
  if (end > 0) __builtin_prefetch(p + end - 1);
}

// Scratch rows of one orientation or descriptor computation.
struct GradientScratch {
  std::vector<float> magnitude, degrees;
  // A descriptor row's 8 trilinear weights per pixel: four arrays of pairs (the two direction bins a cell gets),
  // pixel t's pair p at [p * 2 count + 2 t] (count: the row's pixels).
  std::vector<float> votes;
  std::vector<int> bins;       // and its first histogram bin (-1: outside the cells)
  std::vector<float> weights;  // the window's Gaussian (GaussianWeights), kept to save an allocation a keypoint
  void Fit(size_t n) {
    if (magnitude.size() < n) {
      magnitude.resize(n);
      degrees.resize(n);
      votes.resize(8 * n);
      bins.resize(n);
    }
  }
};

// The dominant directions of a 36-bin direction histogram (hist[-2 .. kOrientationBins + 2), its 4 margin bins free):
// the peaks within 80 % of the highest after a circular (1 4 6 4 1) / 16 smoothing, interpolated, in degrees
// (OpenCV's convention).
void OrientationPeaks(float* hist, std::vector<float>* angles) {
  hist[-1] = hist[kOrientationBins - 1];
  hist[-2] = hist[kOrientationBins - 2];
  hist[kOrientationBins] = hist[0];
  hist[kOrientationBins + 1] = hist[1];
  std::array<float, kOrientationBins> smooth{};
  float top = 0.f;
  for (int i = 0; i < kOrientationBins; ++i) {
    smooth[static_cast<size_t>(i)] = (hist[i - 2] + hist[i + 2]) * (1.f / 16.f) +
                                     (hist[i - 1] + hist[i + 1]) * (4.f / 16.f) + hist[i] * (6.f / 16.f);
    top = std::max(top, smooth[static_cast<size_t>(i)]);
  }
  const float threshold = top * kOrientationPeakRatio;
  for (int j = 0; j < kOrientationBins; ++j) {
    const float h = smooth[static_cast<size_t>(j)];
    const float left = smooth[static_cast<size_t>(j > 0 ? j - 1 : kOrientationBins - 1)];
    const float right = smooth[static_cast<size_t>(j < kOrientationBins - 1 ? j + 1 : 0)];
    if (!(h > left && h > right && h >= threshold)) continue;
    float bin = static_cast<float>(j) + 0.5f * (left - right) / (left - 2 * h + right);
    bin = bin < 0 ? kOrientationBins + bin : bin >= kOrientationBins ? bin - kOrientationBins : bin;
    float angle = 360.f - (360.f / kOrientationBins) * bin;
    if (std::abs(angle - 360.f) < 1.1920929e-07f) angle = 0.f;
    angles->push_back(angle);
  }
}

// Dominant directions (degrees, OpenCV's convention) at (c, r) of a Gaussian image: the peaks of a 36-bin histogram of
// gradient directions weighted by magnitude and a Gaussian of 1.5 scales, within 80 % of the highest.
void Orientations(const cv::Mat& img, int c, int r, float scale, GradientScratch* s, std::vector<float>* angles) {
  const int radius = static_cast<int>(std::lround(kOrientationRadiusFactor * scale));
  std::vector<float>& w = s->weights;
  GaussianWeights(kOrientationSigmaFactor * scale, radius, &w);
  std::array<float, kOrientationBins + 4> raw{};
  float* hist = raw.data() + 2;
  const int y_lo = std::max(r - radius, 1);
  const int y_hi = std::min(r + radius, img.rows - 2);
  const int x_lo = std::max(c - radius, 1);
  const int x_hi = std::min(c + radius, img.cols - 2);
  const int n = x_hi - x_lo + 1;
  if (n <= 0) return;
  s->Fit(static_cast<size_t>(n));
  for (int y = y_lo - 1; y <= y_lo - 1 + kPrefetchRowsAhead; ++y) PrefetchRow(img, y, x_lo - 1, n + 2);
  for (int y = y_lo; y <= y_hi; ++y) {
    PrefetchRow(img, y + kPrefetchRowsAhead, x_lo - 1, n + 2);
    GradientRow(img.ptr<int16_t>(y - 1) + x_lo, img.ptr<int16_t>(y) + x_lo, img.ptr<int16_t>(y + 1) + x_lo, n,
                w.data() + (x_lo - c + radius), w[static_cast<size_t>(y - r + radius)], s->magnitude.data(),
                s->degrees.data());
    for (int j = 0; j < n; ++j) {
      int bin = static_cast<int>(s->degrees[static_cast<size_t>(j)] * (kOrientationBins / 360.f) + 0.5f);
      if (bin >= kOrientationBins) bin -= kOrientationBins;
      hist[bin] += s->magnitude[static_cast<size_t>(j)];
    }
  }
  OrientationPeaks(hist, angles);
}

// One descriptor's geometry: its centre pixel, the rotation (scaled to cells) and the window's Gaussian.
struct DescriptorWindow {
  int px = 0, py = 0, radius = 0;
  float cos_t = 0.f, sin_t = 0.f, ori = 0.f;
  const float* weight = nullptr;  // e^(-k^2 / (2 (d/2 cells)^2)) for offsets k in [-radius, radius], at k + radius
};

// The vector part of DescriptorVotes: pixels [0, returned count), a vector V of lanes at a time (all of them from one
// vector's width on); I is V's lane-mask and index type. Float8 / Int8 on x86-64, 4 lanes on aarch64 (see
// GradientLanes).
template <typename V, typename I>
UAVM_INLINE int DescriptorVoteLanes(const DescriptorWindow& win, float fi, int jb, int count,
                                    const float* __restrict degrees, const float* __restrict magnitude,
                                    int* __restrict bins, float* __restrict votes) {
  constexpr int kLanes = static_cast<int>(sizeof(V) / sizeof(float));
  if (count < kLanes) return 0;
  constexpr int d = kDescriptorWidth;
  constexpr int n = kDescriptorBins;
  const auto pairs = 2 * static_cast<size_t>(count);
  const float fi_sin = fi * win.sin_t;
  const float fi_cos = fi * win.cos_t;
  I lane{};
  for (int k = 0; k < kLanes; ++k) lane[k] = k;
  // The last block ends at count, overlapping the one before (its lanes give the same values again).
  for (int t = 0; t < count; t += kLanes) {
    t = std::min(t, count - kLanes);
    const V fj = __builtin_convertvector(jb + t + lane, V);
    V rbin = ((fj * win.sin_t + fi_cos) + static_cast<float>(d / 2)) - 0.5f;
    V cbin = ((fj * win.cos_t - fi_sin) + static_cast<float>(d / 2)) - 0.5f;
    const I inside = (rbin > -1.f) & (rbin < static_cast<float>(d)) & (cbin > -1.f) & (cbin < static_cast<float>(d));
    V obin = (LoadLanes<V>(degrees + t) - win.ori) * (n / 360.f);
    const I r0 = FloorLanes<V, I>(rbin);
    const I c0 = FloorLanes<V, I>(cbin);
    I o0 = FloorLanes<V, I>(obin);
    rbin = rbin - __builtin_convertvector(r0, V);
    cbin = cbin - __builtin_convertvector(c0, V);
    obin = obin - __builtin_convertvector(o0, V);
    o0 = o0 < 0 ? o0 + n : o0;
    o0 = o0 >= n ? o0 - n : o0;
    const I first = ((r0 + 1) * (d + 2) + c0 + 1) * (n + 2) + o0;
    const I bin = inside ? first : I{} - 1;
    std::memcpy(bins + t, &bin, sizeof bin);
    const V mag = inside ? LoadLanes<V>(magnitude + t) : V{};
    const V v_r1 = mag * rbin, v_r0 = mag - v_r1;
    const V v_rc11 = v_r1 * cbin, v_rc10 = v_r1 - v_rc11;
    const V v_rc01 = v_r0 * cbin, v_rc00 = v_r0 - v_rc01;
    const V v_rco111 = v_rc11 * obin, v_rco101 = v_rc10 * obin;
    const V v_rco011 = v_rc01 * obin, v_rco001 = v_rc00 * obin;
    StorePairLanes(votes + 2 * t, v_rc00 - v_rco001, v_rco001);
    StorePairLanes(votes + pairs + 2 * t, v_rc01 - v_rco011, v_rco011);
    StorePairLanes(votes + 2 * pairs + 2 * t, v_rc10 - v_rco101, v_rco101);
    StorePairLanes(votes + 3 * pairs + 2 * t, v_rc11 - v_rco111, v_rco111);
  }
  return count;
}

UAVM_SIMD_CLONES int DescriptorVotesVector(const DescriptorWindow& win, float fi, int jb, int count,
                                           const float* __restrict degrees, const float* __restrict magnitude,
                                           int* __restrict bins, float* __restrict votes) {
  return DescriptorVoteLanes<RegisterFloats, RegisterInts>(win, fi, jb, count, degrees, magnitude, bins, votes);
}

// For the pixels j = jb .. jb + count - 1 of window row i (gradients in s->magnitude, s->degrees): the first histogram
// bin of each pixel's votes (-1 outside the cells) and its 8 trilinear weights (two cells in each direction, two of
// the 8 direction bins), a vector's width of pixels at a time (DescriptorVotesVector) from that width on; the same
// operations, in the same order, in the scalar loop for shorter rows.
void DescriptorVotes(const DescriptorWindow& win, float fi, int jb, int count, GradientScratch* s) {
  constexpr int d = kDescriptorWidth;
  constexpr int n = kDescriptorBins;
  const float bins_per_degree = n / 360.f;
  const float fi_sin = fi * win.sin_t;
  const float fi_cos = fi * win.cos_t;
  const auto pairs = 2 * static_cast<size_t>(count);
  float* votes = s->votes.data();
  int t = DescriptorVotesVector(win, fi, jb, count, s->degrees.data(), s->magnitude.data(), s->bins.data(), votes);
  for (; t < count; ++t) {
    const auto fj = static_cast<float>(jb + t);
    float rbin = ((fj * win.sin_t + fi_cos) + static_cast<float>(d / 2)) - 0.5f;
    float cbin = ((fj * win.cos_t - fi_sin) + static_cast<float>(d / 2)) - 0.5f;
    if (!(rbin > -1 && rbin < d && cbin > -1 && cbin < d)) {
      s->bins[static_cast<size_t>(t)] = -1;
      continue;
    }
    float obin = (s->degrees[static_cast<size_t>(t)] - win.ori) * bins_per_degree;
    const auto r0 = static_cast<int>(std::floor(rbin));
    const auto c0 = static_cast<int>(std::floor(cbin));
    auto o0 = static_cast<int>(std::floor(obin));
    rbin -= static_cast<float>(r0);
    cbin -= static_cast<float>(c0);
    obin -= static_cast<float>(o0);
    if (o0 < 0) o0 += n;
    if (o0 >= n) o0 -= n;
    s->bins[static_cast<size_t>(t)] = ((r0 + 1) * (d + 2) + c0 + 1) * (n + 2) + o0;
    const float mag = s->magnitude[static_cast<size_t>(t)];
    const float v_r1 = mag * rbin, v_r0 = mag - v_r1;
    const float v_rc11 = v_r1 * cbin, v_rc10 = v_r1 - v_rc11;
    const float v_rc01 = v_r0 * cbin, v_rc00 = v_r0 - v_rc01;
    const float v_rco111 = v_rc11 * obin, v_rco101 = v_rc10 * obin;
    const float v_rco011 = v_rc01 * obin, v_rco001 = v_rc00 * obin;
    float* pair = votes + 2 * static_cast<size_t>(t);
    pair[0] = v_rc00 - v_rco001;
    pair[1] = v_rco001;
    pair[pairs] = v_rc01 - v_rco011;
    pair[pairs + 1] = v_rco011;
    pair[2 * pairs] = v_rc10 - v_rco101;
    pair[2 * pairs + 1] = v_rco101;
    pair[3 * pairs] = v_rc11 - v_rco111;
    pair[3 * pairs + 1] = v_rco111;
  }
}

// Trilinear votes of row py + i of the window: each gradient's magnitude (times the window) into the two nearest
// cells in each direction and the two nearest of the 8 direction bins.
void VoteDescriptorRow(const cv::Mat& img, const DescriptorWindow& win, int i, GradientScratch* s, float* hist) {
  constexpr int d = kDescriptorWidth;
  constexpr int n = kDescriptorBins;
  constexpr float kHalf = d / 2.f + 0.5f;  // |c_rot|, |r_rot| below this fall in the 4 x 4 cells or their margin
  const int yy = win.py + i;
  if (yy <= 0 || yy >= img.rows - 1) return;
  // The columns whose rotated offsets can fall in the cells (a conservative range; the exact test follows).
  auto j_lo = static_cast<float>(-win.radius);
  auto j_hi = static_cast<float>(win.radius);
  auto bound = [&](float a, float b) {  // |j a - b| < kHalf
    if (std::abs(a) < 1e-6f) return;
    const float lo = (b - kHalf) / a;
    const float hi = (b + kHalf) / a;
    j_lo = std::max(j_lo, std::min(lo, hi) - 1.f);
    j_hi = std::min(j_hi, std::max(lo, hi) + 1.f);
  };
  const auto fi = static_cast<float>(i);
  bound(win.cos_t, fi * win.sin_t);
  bound(win.sin_t, -fi * win.cos_t);
  const int jb = std::max(static_cast<int>(std::ceil(j_lo)), 1 - win.px);
  const int je = std::min(static_cast<int>(std::floor(j_hi)), img.cols - 2 - win.px);
  const int count = je - jb + 1;
  if (count <= 0) return;
  const int x0 = win.px + jb;
  PrefetchRow(img, yy + kPrefetchRowsAhead, x0 - 1, count + 2);
  GradientRow(img.ptr<int16_t>(yy - 1) + x0, img.ptr<int16_t>(yy) + x0, img.ptr<int16_t>(yy + 1) + x0, count,
              win.weight + (jb + win.radius), win.weight[i + win.radius], s->magnitude.data(), s->degrees.data());
  DescriptorVotes(win, fi, jb, count, s);
  const auto pairs = 2 * static_cast<size_t>(count);
  const float* v = s->votes.data();
  for (int t = 0; t < count; ++t, v += 2) {
    const int bin = s->bins[static_cast<size_t>(t)];
    if (bin < 0) continue;
    float* h = hist + bin;
    h[0] += v[0];
    h[1] += v[1];
    h[n + 2] += v[pairs];
    h[n + 3] += v[pairs + 1];
    h[(d + 2) * (n + 2)] += v[2 * pairs];
    h[(d + 2) * (n + 2) + 1] += v[2 * pairs + 1];
    h[(d + 3) * (n + 2)] += v[3 * pairs];
    h[(d + 3) * (n + 2) + 1] += v[3 * pairs + 1];
  }
}

// The histogram's 4 x 4 inner cells with their circular direction bins folded, clipped at 0.2 of the norm, scaled
// to 512 and rounded to 0..255.
void FinishDescriptor(float* hist, float* out) {
  constexpr int d = kDescriptorWidth;
  constexpr int n = kDescriptorBins;
  for (int i = 0; i < d; ++i) {
    for (int j = 0; j < d; ++j) {
      float* h = hist + ((i + 1) * (d + 2) + (j + 1)) * (n + 2);
      h[0] += h[n];
      h[1] += h[n + 1];
      for (int k = 0; k < n; ++k) out[(i * d + j) * n + k] = h[k];
    }
  }
  float sq = 0.f;
  for (int k = 0; k < kDescriptorSize; ++k) sq += out[k] * out[k];
  const float clip = std::sqrt(sq) * kDescriptorClip;
  sq = 0.f;
  for (int k = 0; k < kDescriptorSize; ++k) {
    out[k] = std::min(out[k], clip);
    sq += out[k] * out[k];
  }
  const float norm = kDescriptorScale / std::max(std::sqrt(sq), 1.1920929e-07f);
  for (int k = 0; k < kDescriptorSize; ++k) out[k] = static_cast<float>(cv::saturate_cast<uchar>(out[k] * norm));
}

// The direction a descriptor's window turns by (OpenCV's 360 - angle, 360 itself as 0) and its sine and cosine.
float DescriptorDirection(float angle, double* sin_d, double* cos_d) {
  float ori = 360.f - angle;
  if (std::abs(ori - 360.f) < 1.1920929e-07f) ori = 0.f;
  portable::SinCosDegrees(ori, sin_d, cos_d);
  return ori;
}

// The 4x4x8 descriptor at sub-pixel (x, y) of a Gaussian image, direction `angle` (OpenCV's convention), as OpenCV's
// calcSIFTDescriptor: trilinear votes of rotated gradients, Gaussian window of half the descriptor's width.
void Describe(const cv::Mat& img, float x, float y, float angle, float scale, GradientScratch* s, float* out) {
  constexpr int d = kDescriptorWidth;
  DescriptorWindow win;
  win.px = static_cast<int>(std::lround(x));
  win.py = static_cast<int>(std::lround(y));
  double sin_d = 0, cos_d = 0;
  win.ori = DescriptorDirection(angle, &sin_d, &cos_d);
  const float hist_width = kDescriptorCellFactor * scale;
  win.radius = static_cast<int>(std::lround(hist_width * 1.4142135623730951f * (d + 1) * 0.5f));
  win.radius = std::min(win.radius, static_cast<int>(std::sqrt(static_cast<double>(img.cols) * img.cols +
                                                               static_cast<double>(img.rows) * img.rows)));
  win.cos_t = static_cast<float>(cos_d) / hist_width;
  win.sin_t = static_cast<float>(sin_d) / hist_width;
  // The window e^(-(c_rot^2 + r_rot^2) / (2 (d/2)^2)) in cells is separable in the unrotated offsets.
  GaussianWeights(0.5f * d * hist_width, win.radius, &s->weights);
  win.weight = s->weights.data();
  std::array<float, (d + 2) * (d + 2) * (kDescriptorBins + 2)> hist{};
  s->Fit(static_cast<size_t>(2 * win.radius + 1));
  for (int i = -win.radius; i <= win.radius; ++i) VoteDescriptorRow(img, win, i, s, hist.data());
  FinishDescriptor(hist.data(), out);
}

// ---- Descriptor on a sampled grid ---------------------------------------------------------------------------------

// The descriptor's window sampled on its own rotated grid instead of at every pixel: S x S samples a cell (bilinear
// in the Gaussian image), gradients as differences of the neighbouring samples along the grid's axes (directions come
// out relative to the keypoint's), each sample's votes into the 2 x 2 cells around it at weights fixed by its place in
// the grid. The grid covers the 4 x 4 cells and the half-cell margin OpenCV's window reads (its samples vote partly
// into the edge cells). A cell is 3 sigma wide, so the work is (5 S + 2)^2 samples whatever the scale (OpenCV's way
// reads ~(15 sigma)^2 pixels: 900 at sigma 2, 2300 at 3.2), and the image, blurred by sigma, holds no detail finer
// than the samples' 0.75 sigma (at S = 4).

// Bilinear samples of an int16 image (rows x cols, step int16s a row) at (bx + c cos, by - c sin) for the n offsets c
// (clamped into the image), a vector of lanes at a time: positions and weights in lanes, the four pixels gathered.
// n >= the vector's lanes.
UAVM_SIMD_CLONES void SampleRow(const int16_t* __restrict image, int step, int cols, int rows, float bx, float by,
                                float cos_t, float sin_t, const float* __restrict offsets, int n,
                                float* __restrict out) {
  using V = RegisterFloats;
  using I = RegisterInts;
  constexpr int kLanes = static_cast<int>(sizeof(V) / sizeof(float));
  const auto max_x = static_cast<float>(cols - 1);
  const auto max_y = static_cast<float>(rows - 1);
  // The last block ends at n, overlapping the one before (its lanes give the same values again).
  for (int a = 0; a < n; a += kLanes) {
    a = std::min(a, n - kLanes);
    const V c = LoadLanes<V>(offsets + a);
    V px = bx + c * cos_t;
    V py = by - c * sin_t;
    px = px < 0.f ? V{} : px;
    px = px > max_x ? max_x - V{} : px;
    py = py < 0.f ? V{} : py;
    py = py > max_y ? max_y - V{} : py;
    I x0 = __builtin_convertvector(px, I);  // truncation: px >= 0
    I y0 = __builtin_convertvector(py, I);
    x0 = x0 > cols - 2 ? (cols - 2) - I{} : x0;
    y0 = y0 > rows - 2 ? (rows - 2) - I{} : y0;
    const V fx = px - __builtin_convertvector(x0, V);
    const V fy = py - __builtin_convertvector(y0, V);
    const I at = y0 * step + x0;
    V p00, p01, p10, p11;
    for (int k = 0; k < kLanes; ++k) {
      const int16_t* p = image + at[k];
      p00[k] = p[0];
      p01[k] = p[1];
      p10[k] = p[step];
      p11[k] = p[step + 1];
    }
    const V top = p00 + fx * (p01 - p00);
    const V bottom = p10 + fx * (p11 - p10);
    StoreLanes(out + a, top + fy * (bottom - top));
  }
}

// Each sample's votes into the descriptor's histogram (cells of kDescriptorBins + 2 floats, the last two unused):
// its magnitude split between the two direction bins around its direction (the second wrapping to bin 0), as one
// vector of the cell's 8 bins, added at four weights to the 2 x 2 cells from first_bin[k] on.
UAVM_SIMD_CLONES void VoteSamples(const float* __restrict degrees, const float* __restrict magnitude,
                                  const int* __restrict first_bin, const float* __restrict spatial, int count,
                                  float* __restrict hist) {
  using V = RegisterFloats;
  using I = RegisterInts;
  constexpr int kLanes = static_cast<int>(sizeof(V) / sizeof(float));
  constexpr int n = kDescriptorBins;
  constexpr int kCell = n + 2;
  static_assert(n % kLanes == 0);
  constexpr std::array<int, 4> kCorner = {0, kCell, (kDescriptorWidth + 2) * kCell, (kDescriptorWidth + 3) * kCell};
  I lane{};
  for (int k = 0; k < kLanes; ++k) lane[k] = k;
  for (int k = 0; k < count; ++k) {
    const float obin = degrees[k] * (n / 360.f);
    auto o0 = static_cast<int>(obin);  // degrees >= 0
    const float fo = obin - static_cast<float>(o0);
    if (o0 >= n) o0 -= n;
    const int o1 = o0 + 1 < n ? o0 + 1 : 0;
    const float m1 = magnitude[k] * fo;
    const float m0 = magnitude[k] - m1;
    const float* w = spatial + 4 * static_cast<size_t>(k);
    for (int part = 0; part < n; part += kLanes) {
      const I bin = lane + part;
      const V vote = bin == o0 ? m0 - V{} : (bin == o1 ? m1 - V{} : V{});
      for (int q = 0; q < 4; ++q) {
        float* h = hist + first_bin[k] + kCorner[static_cast<size_t>(q)] + part;
        StoreLanes(h, LoadLanes<V>(h) + vote * w[q]);
      }
    }
  }
}

// The sampled grid's fixed part, the same for every keypoint: where the samples lie in cells, their window and votes.
struct SampleGrid {
  explicit SampleGrid(int samples_per_cell) : side((kDescriptorWidth + 1) * samples_per_cell) {
    constexpr float half = kDescriptorWidth / 2.f;
    constexpr float reach = (kDescriptorWidth + 1) / 2.f;  // the cells and half a cell around them, as OpenCV's
    const int m = side + 2;
    offsets.resize(static_cast<size_t>(m));
    for (int a = 0; a < m; ++a)
      offsets[static_cast<size_t>(a)] =
          (static_cast<float>(a - 1) + 0.5f) / static_cast<float>(samples_per_cell) - reach;
    const auto n = static_cast<size_t>(side) * static_cast<size_t>(side);
    window.resize(n);
    first_bin.resize(n);
    spatial.resize(4 * n);
    for (int b = 0; b < side; ++b) {
      for (int a = 0; a < side; ++a) {
        const float c = offsets[static_cast<size_t>(a + 1)];
        const float r = offsets[static_cast<size_t>(b + 1)];
        const size_t k = static_cast<size_t>(b) * static_cast<size_t>(side) + static_cast<size_t>(a);
        window[k] = static_cast<float>(portable::Exp(-(double{c} * c + double{r} * r) / (2.0 * half * half)));
        const float rbin = r + half - 0.5f;
        const float cbin = c + half - 0.5f;
        const auto r0 = static_cast<int>(std::floor(rbin));
        const auto c0 = static_cast<int>(std::floor(cbin));
        const float fr = rbin - static_cast<float>(r0);
        const float fc = cbin - static_cast<float>(c0);
        first_bin[k] = ((r0 + 1) * (kDescriptorWidth + 2) + c0 + 1) * (kDescriptorBins + 2);
        spatial[4 * k] = (1.f - fr) * (1.f - fc);
        spatial[4 * k + 1] = (1.f - fr) * fc;
        spatial[4 * k + 2] = fr * (1.f - fc);
        spatial[4 * k + 3] = fr * fc;
      }
    }
  }

  int side;                    // samples along each side of the cells and their margin
  std::vector<float> offsets;  // sample a - 1's centre in cells from the keypoint, a in [0, side + 2)
  std::vector<float> window;   // the descriptor's Gaussian at each inner sample (row-major, side x side)
  std::vector<int> first_bin;  // its first histogram cell (before the direction)
  std::vector<float> spatial;  // its 4 bilinear cell weights
};

// Describes keypoints on a SampleGrid (borrowed: it outlives the describer), with scratch rows of its own (one
// describer a thread).
class SampledDescriber {
 public:
  explicit SampledDescriber(const SampleGrid& grid) : grid_(grid) {
    const auto m = static_cast<size_t>(grid.side) + 2;
    const size_t n = grid.window.size();
    values_.resize(m * m);
    dx_.resize(n);
    dy_.resize(n);
    magnitude_.resize(n);
    degrees_.resize(n);
  }

  // As Describe: the descriptor at sub-pixel (x, y) of a Gaussian image, direction `angle` (OpenCV's convention).
  void Describe(const cv::Mat& img, float x, float y, float angle, float scale, float* out) {
    constexpr int d = kDescriptorWidth;
    constexpr int n = kDescriptorBins;
    double sin_d = 0, cos_d = 0;
    DescriptorDirection(angle, &sin_d, &cos_d);
    const float cell = kDescriptorCellFactor * scale;
    Sample(img, x, y, static_cast<float>(cos_d) * cell, static_cast<float>(sin_d) * cell);
    Differences();
    const int count = grid_.side * grid_.side;
    PolarRow(dx_.data(), dy_.data(), count, grid_.window.data(), magnitude_.data(), degrees_.data());
    std::array<float, (d + 2) * (d + 2) * (n + 2)> hist{};
    VoteSamples(degrees_.data(), magnitude_.data(), grid_.first_bin.data(), grid_.spatial.data(), count, hist.data());
    FinishDescriptor(hist.data(), out);
  }

 private:
  // Bilinear samples of img at the grid's (side + 2)^2 places (the edge's rows and columns clamped into the image).
  void Sample(const cv::Mat& img, float x, float y, float cell_cos, float cell_sin) {
    const int m = grid_.side + 2;
    for (int b = 0; b < m; ++b) {
      const float r = grid_.offsets[static_cast<size_t>(b)];
      SampleRow(img.ptr<int16_t>(), static_cast<int>(img.step1()), img.cols, img.rows, x + r * cell_sin,
                y + r * cell_cos, cell_cos, cell_sin, grid_.offsets.data(), m,
                values_.data() + static_cast<size_t>(b) * m);
    }
  }

  // Central differences of the inner side x side samples into dx_, dy_ (row-major).
  void Differences() {
    const int side = grid_.side;
    const int m = side + 2;
    for (int b = 0; b < side; ++b) {
      const float* above = values_.data() + static_cast<size_t>(b) * m + 1;
      const float* row = above + m;
      const float* below = row + m;
      float* dx = dx_.data() + static_cast<size_t>(b) * side;
      float* dy = dy_.data() + static_cast<size_t>(b) * side;
      for (int a = 0; a < side; ++a) {
        dx[a] = row[a + 1] - row[a - 1];
        dy[a] = above[a] - below[a];  // up, as the image's gradients
      }
    }
  }

  const SampleGrid& grid_;
  std::vector<float> values_, dx_, dy_, magnitude_, degrees_;
};

// ---- Pyramid -------------------------------------------------------------------------------------------------------

// Blurs an octave's Gaussian layers 1 .. L + 2 (gauss[1 ..]) from its first, gauss[0], each from the one before.
void BuildOctave(const std::vector<Kernel>& kernels, std::vector<cv::Mat>& gauss) {
  for (size_t i = 1; i < gauss.size(); ++i) Blur(gauss[i - 1], kernels[i], gauss[i]);
}

struct Oriented {
  size_t candidate = 0;
  float angle = 0.f;
};

// Bytes of one image (int16), rounded up to a cache line.
size_t ImageBytes(int rows, int cols) {
  return (static_cast<size_t>(rows) * static_cast<size_t>(cols) * sizeof(int16_t) + 63) / 64 * 64;
}

// The block ImageBlock needs for the octaves of a rows x cols first octave with L layers: each octave's L kept
// Gaussian layers after those of the octaves before it, its 3 searched ones at the end. L + 3 images of the first
// octave's size for L <= 8: at octave k the kept layers take L (1 + 1/4 + ... + 1/4^k) images and the searched ones
// 3 / 4^k, within L + 3 below 9 layers (a tie at 9, which the 64-byte rounding tips over).
size_t ScaleSpaceBlockBytes(int rows, int cols, int layers) {
  size_t kept = 0;
  size_t block = 0;
  for (; std::min(rows, cols) >= 2 * kImageBorder + 3; rows /= 2, cols /= 2) {
    const size_t image = ImageBytes(rows, cols);
    kept += static_cast<size_t>(layers) * image;
    block = std::max(block, kept + 3 * image);
  }
  return block;
}

// Every image of the scale space in one block (ScaleSpaceBlockBytes), so that the image pool hands the same block back
// frame after frame (or the caller keeps it: DogSiftBuffers): with images of each octave's own size, a later octave's
// (a quarter of the first's) could not take a pooled first-octave block, the pool gave those back to stay within its
// peak, and the kernel zeroed ~50 MB of fresh pages a 1000x750 frame (6 % of the flight's CPU). Kept images (every
// octave's Gaussian layers 1 .. L, read by the orientations and descriptors) come from the front; the layers an
// octave's search alone reads from the back, free again when the next octave starts. The images are views: the block
// outlives them.
class ImageBlock {
 public:
  // The block from `held` (the caller's, kept between frames) or one of its own.
  void Reserve(size_t bytes, DogSiftBuffers* held) {
    data_ = (held != nullptr ? held : &own_)->Take(bytes);
    front_ = 0;
    back_ = end_ = bytes;
  }
  cv::Mat Kept(int rows, int cols) {
    cv::Mat image(rows, cols, CV_16S, data_ + front_);
    front_ += ImageBytes(rows, cols);
    CV_Assert(front_ <= back_);
    return image;
  }
  cv::Mat Searched(int rows, int cols) {
    const size_t bytes = ImageBytes(rows, cols);
    CV_Assert(front_ + bytes <= back_);
    back_ -= bytes;
    return {rows, cols, CV_16S, data_ + back_};
  }
  void NextOctave() { back_ = end_; }

 private:
  DogSiftBuffers own_;
  uchar* data_ = nullptr;
  size_t front_ = 0;
  size_t back_ = 0;
  size_t end_ = 0;
};

// The pyramid's outputs that outlive its search.
struct ScaleSpace {
  DogSiftOptions options;
  ImageBlock images;                        // holds every image below: declared before them
  std::vector<std::vector<cv::Mat>> gauss;  // per octave, Gaussian layers 1..L
  std::vector<Candidate> candidates;
  std::vector<double> ladder;  // the thresholds a repeated detection would try
  size_t searched = 0;         // the lowest of them searched

  [[nodiscard]] float ScaleOf(const Candidate& k) const {
    return static_cast<float>(options.sigma *
                              portable::Exp2((k.layer + double{k.layer_offset}) / options.octave_layers));
  }
  [[nodiscard]] const cv::Mat& ImageOf(const Candidate& k) const {
    return gauss[static_cast<size_t>(k.octave)][static_cast<size_t>(k.layer - 1)];
  }
};

// The first Gaussian image of `octave` into first: the doubled (or not) input blurred to sigma for the first octave,
// Gaussian layer L of the one before at every second pixel (sigma doubles) for the others.
void FirstImage(const cv::Mat& gray, const ScaleSpace& space, int octave, cv::Mat& scratch, cv::Mat& first) {
  const DogSiftOptions& o = space.options;
  if (octave == 0) {
    const double input = double{kInputSigma} * (o.double_first_octave ? 2 : 1);
    const Kernel blur = GaussianKernel(std::sqrt(std::max(o.sigma * o.sigma - input * input, 0.01)));
    if (o.double_first_octave)
      Upsample2x(gray, scratch);
    else
      gray.convertTo(scratch, CV_16S, kFixedScale, kFixedOffset);
    Blur(scratch, blur, first);
  } else {
    Decimate(space.gauss.back().back(), first);
  }
}

// The first octave's candidates at the highest level of the ladder at which they promise enough (the first octave gives
// about two thirds of a frame's), its level in space->searched. The octave is searched once, at
// first_octave_search_level, and each level above taken from that search: a candidate of a higher level is one whose
// sample passes that level's first rejection and whose fitted contrast its threshold (the fit does not depend on the
// threshold), so the same candidates in the same order as a search of its own. Levels below are searched in turn.
void SearchFirstOctave(const DogLayers& dog, const DogSiftOptions& o, int search_level, ScaleSpace* space) {
  const std::vector<double>& ladder = space->ladder;
  auto too_few = [&](size_t n) { return 1.5 * static_cast<double>(n) < o.target_min_features; };
  const size_t once = std::min(static_cast<size_t>(std::max(search_level, 0)), ladder.size() - 1);
  std::vector<Candidate> found;
  FindExtrema(dog, o, ladder[once], 0, &found);
  for (size_t level = 0; level < once; ++level) {
    const int peak = PeakThreshold(ladder[level], o.octave_layers);
    std::vector<Candidate> kept;
    for (const Candidate& k : found)
      if (k.peak > peak && k.contrast >= ladder[level]) kept.push_back(k);
    if (!too_few(kept.size())) {
      space->searched = level;
      space->candidates = std::move(kept);
      return;
    }
  }
  space->searched = once;
  space->candidates = std::move(found);
  while (space->searched + 1 < ladder.size() && too_few(space->candidates.size())) {
    space->candidates.clear();
    FindExtrema(dog, o, ladder[++space->searched], 0, &space->candidates);
  }
}

// Builds the octaves one at a time and searches each for candidates. Every octave's Gaussian layers 1 .. L stay (for
// the orientations and descriptors); its three others only while it is searched.
void SearchOctaves(const cv::Mat& gray, const DogSiftOptions& o, DogSiftBuffers* buffers, ScaleSpace* space) {
  space->options = o;
  space->ladder = {o.contrast_threshold};
  while (o.target_min_features > 0 && o.min_contrast_threshold > 0.0 &&
         space->ladder.back() / 3.0 >= o.min_contrast_threshold)
    space->ladder.push_back(space->ladder.back() / 3.0);
  const int layers = o.octave_layers;
  // Blur from layer i-1 to i: sigma_i^2 - sigma_{i-1}^2, sigma_i = sigma 2^(i / L).
  std::vector<Kernel> kernels(static_cast<size_t>(layers) + 3);
  for (int i = 1; i < layers + 3; ++i) {
    const double prev = o.sigma * portable::Exp2((i - 1) / static_cast<double>(layers));
    const double total = o.sigma * portable::Exp2(i / static_cast<double>(layers));
    kernels[static_cast<size_t>(i)] = GaussianKernel(std::sqrt(total * total - prev * prev));
  }
  int first_level = o.first_octave_search_level;
  if (first_level < 0) {  // the level of the last frame's threshold (the ladders are the same chain of divisions)
    first_level = 0;
    const double last = buffers != nullptr ? buffers->first_octave_threshold() : 0.0;
    while (last > 0.0 && static_cast<size_t>(first_level) + 1 < space->ladder.size() &&
           space->ladder[static_cast<size_t>(first_level)] > last)
      ++first_level;
  }
  const int f = o.double_first_octave ? 2 : 1;
  int width = gray.cols * f;
  int height = gray.rows * f;
  space->images.Reserve(ScaleSpaceBlockBytes(height, width, layers), buffers);
  for (int octave = 0; std::min(width, height) >= 2 * kImageBorder + 3; ++octave) {
    space->images.NextOctave();
    // Gaussian layers 0 .. L + 2: 1 .. L stay (orientations, descriptors, the next octave's first image), the others
    // only while the octave is searched.
    std::vector<cv::Mat> gauss(static_cast<size_t>(layers) + 3);
    for (int i = 0; i < layers + 3; ++i)
      gauss[static_cast<size_t>(i)] =
          i >= 1 && i <= layers ? space->images.Kept(height, width) : space->images.Searched(height, width);
    FirstImage(gray, *space, octave, gauss[1], gauss[0]);
    BuildOctave(kernels, gauss);
    const DogLayers dog(gauss);
    if (octave == 0) {
      SearchFirstOctave(dog, o, first_level, space);
      if (buffers != nullptr) buffers->set_first_octave_threshold(space->ladder[space->searched]);
    } else {
      FindExtrema(dog, o, space->ladder[space->searched], octave, &space->candidates);
    }
    space->gauss.emplace_back(gauss.begin() + 1, gauss.begin() + 1 + layers);
    width /= 2;
    height /= 2;
  }
}

// The highest threshold of the ladder that gives target_min_features keypoints (counting each direction), where the
// repeated detection would have stopped; candidates are sorted by contrast, so each level keeps a prefix (*prefix).
// searched + 1 when even the lowest searched level gives too few and the ladder goes lower.
size_t ChooseLevel(const ScaleSpace& space, const std::vector<std::vector<float>>& angles, int target, size_t* prefix) {
  for (size_t level = 0; level <= space.searched; ++level) {
    size_t count = 0;
    *prefix = 0;
    while (*prefix < space.candidates.size() && space.candidates[*prefix].contrast >= space.ladder[level])
      count += angles[(*prefix)++].size();
    if (count >= static_cast<size_t>(target)) return level;
  }
  return space.searched + 1 < space.ladder.size() ? space.searched + 1 : space.searched;
}

// Indices 0..n-1 in the order their candidates lie in the images (octave, layer, row, column): neighbouring windows
// then share cache lines and pages (in strength order each window's rows came from memory). Outputs keep their index.
template <typename CandidateOf>
std::vector<size_t> ImageOrder(size_t n, CandidateOf&& candidate_of) {
  std::vector<size_t> order(n);
  std::iota(order.begin(), order.end(), size_t{0});
  std::sort(order.begin(), order.end(), [&](size_t a, size_t b) {
    const Candidate& p = candidate_of(a);
    const Candidate& q = candidate_of(b);
    return std::tie(p.octave, p.layer, p.row, p.col, a) < std::tie(q.octave, q.layer, q.row, q.col, b);
  });
  return order;
}

// Keypoints and descriptors of the kept (candidate, direction) pairs, in their order.
void DescribeKept(const ScaleSpace& space, const std::vector<Oriented>& kept, std::vector<SiftKeypoint>* keypoints,
                  cv::Mat* descriptors) {
  const bool doubled = space.options.double_first_octave;
  std::optional<SampleGrid> grid;
  if (space.options.descriptor_samples_per_cell > 0) grid.emplace(space.options.descriptor_samples_per_cell);
  // Octave pixel p is pixel p * 2^octave of the first octave; that one is input pixel p / 2 - 0.25 when doubled.
  const float to_input = doubled ? 0.5f : 1.f;
  const float shift = doubled ? -0.25f : 0.f;
  descriptors->create(static_cast<int>(kept.size()), kDescriptorSize, CV_32F);
  keypoints->resize(kept.size());
  const std::vector<size_t> order =
      ImageOrder(kept.size(), [&](size_t i) -> const Candidate& { return space.candidates[kept[i].candidate]; });
  ForRanges(static_cast<int>(kept.size()), ItemPieces(), [&](int begin, int end) {
    GradientScratch scratch;
    std::optional<SampledDescriber> sampled;
    if (grid) sampled.emplace(*grid);
    for (int at = begin; at < end; ++at) {
      const auto i = static_cast<int>(order[static_cast<size_t>(at)]);
      const Oriented& e = kept[static_cast<size_t>(i)];
      const Candidate& k = space.candidates[e.candidate];
      const float scale = space.ScaleOf(k);
      const float to_first = std::ldexp(1.f, k.octave);
      SiftKeypoint& out = (*keypoints)[static_cast<size_t>(i)];
      out.point = cv::Point2f(k.x * to_first * to_input + shift, k.y * to_first * to_input + shift);
      out.size = scale * 2.f * to_first * to_input;
      out.angle = e.angle;
      out.response = k.response;
      out.octave = k.octave;
      if (sampled)
        sampled->Describe(space.ImageOf(k), k.x, k.y, e.angle, scale, descriptors->ptr<float>(i));
      else
        Describe(space.ImageOf(k), k.x, k.y, e.angle, scale, &scratch, descriptors->ptr<float>(i));
    }
  });
}

}  // namespace

uchar* DogSiftBuffers::Take(size_t needed) {
  if (bytes() < needed) {
    block_.release();                                                // before the new one: never both
    block_.create(static_cast<int>((needed + 63) / 64), 64, CV_8U);  // rows of a cache line: any size an int counts
  }
  return block_.data;
}

double DogSiftScaleSpaceMiB(int width, int height, int octave_layers, bool double_first_octave) {
  const int f = double_first_octave ? 2 : 1;
  return static_cast<double>(ScaleSpaceBlockBytes(height * f, width * f, octave_layers)) / (1024.0 * 1024.0);
}

void DetectAndDescribeSift(const cv::Mat& gray, const DogSiftOptions& o, std::vector<SiftKeypoint>* keypoints,
                           cv::Mat* descriptors, double* contrast_threshold_used, DogSiftBuffers* buffers,
                           BurstWorkers* workers) {
  const WorkersScope scope(workers);  // this call's loops on `workers`, kept awake through it
  const BurstWorkers::Burst awake(workers);
  keypoints->clear();
  *descriptors = cv::Mat();
  if (contrast_threshold_used != nullptr) *contrast_threshold_used = o.contrast_threshold;
  CV_Assert(gray.type() == CV_8UC1);
  const int f = o.double_first_octave ? 2 : 1;
  if (std::min(gray.cols, gray.rows) * f < 2 * kImageBorder + 3) return;
  ScaleSpace space;
  SearchOctaves(gray, o, buffers, &space);
  std::vector<Candidate>& candidates = space.candidates;
  // Each candidate gives one keypoint or more (one per dominant direction), all with its response: the strongest
  // max_features keypoints come from the strongest max_features candidates.
  std::stable_sort(candidates.begin(), candidates.end(),
                   [](const Candidate& a, const Candidate& b) { return a.contrast > b.contrast; });
  if (o.max_features > 0 && candidates.size() > static_cast<size_t>(o.max_features))
    candidates.resize(static_cast<size_t>(o.max_features));
  std::vector<std::vector<float>> angles(candidates.size());
  const std::vector<size_t> order =
      ImageOrder(candidates.size(), [&](size_t i) -> const Candidate& { return candidates[i]; });
  ForRanges(static_cast<int>(candidates.size()), ItemPieces(), [&](int begin, int end) {
    GradientScratch scratch;
    for (int at = begin; at < end; ++at) {
      const auto i = static_cast<int>(order[static_cast<size_t>(at)]);
      const Candidate& k = candidates[static_cast<size_t>(i)];
      Orientations(space.ImageOf(k), k.col, k.row, space.ScaleOf(k), &scratch, &angles[static_cast<size_t>(i)]);
    }
  });
  size_t prefix = 0;
  const size_t level = ChooseLevel(space, angles, o.target_min_features, &prefix);
  if (level > space.searched) {  // the first octave promised more than the frame gave: detect again, lower
    DogSiftOptions lower = o;
    lower.contrast_threshold = space.ladder[space.searched + 1];
    space = ScaleSpace{};  // its images go before the next detection makes its own
    angles = {};
    DetectAndDescribeSift(gray, lower, keypoints, descriptors, contrast_threshold_used, buffers, workers);
    return;
  }
  if (contrast_threshold_used != nullptr) *contrast_threshold_used = space.ladder[level];
  std::vector<Oriented> kept;
  for (size_t i = 0; i < prefix; ++i)
    for (float a : angles[i]) kept.push_back({i, a});
  if (o.max_features > 0 && kept.size() > static_cast<size_t>(o.max_features))
    kept.resize(static_cast<size_t>(o.max_features));
  DescribeKept(space, kept, keypoints, descriptors);
}

}  // namespace uavm
