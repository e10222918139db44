#pragma once
// The separable Gaussian's two passes in fixed point, for our SIFT's scale space (core/features/dog_sift.cpp): int16
// values (any, the scale space's use all 16 bits), weights in Q15 (w x 32768, positive, summing to 32768). A tap's
// products are summed exactly in 32 bits (AVX2's vpmaddwd, a pair of pixels on 16 lanes; NEON's smlal on 8, twice the
// lanes of floats) and each output rounded once, (sum + 2^14) >> 15: integers, so every machine gives the same values.
#include <cstdint>

namespace uavm::q15 {

// out[x] = w[0] c[x] + sum_{i=1..radius} w[i] (c[x-i] + c[x+i]) for x in [0, n), c = padded + radius (padded holds
// n + 2 radius values).
void ConvolveRow(const int16_t* padded, int n, const int16_t* w, int radius, int16_t* out);

// The vertical pass for two output rows: out0 from rows[0 .. 2 radius], out1 from rows[1 .. 2 radius + 1] (each
// weighted as above around its middle row), n columns.
void ConvolveColumnPair(const int16_t* const* rows, int n, const int16_t* w, int radius, int16_t* out0, int16_t* out1);

// The same, each compiled for one instruction set (q15_blur.cpp dispatches).
namespace generic {
void ConvolveRow(const int16_t* padded, int n, const int16_t* w, int radius, int16_t* out);
void ConvolveColumnPair(const int16_t* const* rows, int n, const int16_t* w, int radius, int16_t* out0, int16_t* out1);
}  // namespace generic
namespace avx2 {  // x86-64 only
void ConvolveRow(const int16_t* padded, int n, const int16_t* w, int radius, int16_t* out);
void ConvolveColumnPair(const int16_t* const* rows, int n, const int16_t* w, int radius, int16_t* out0, int16_t* out1);
}  // namespace avx2

}  // namespace uavm::q15
