// Compiled with -mavx2 on x86-64 only (core/features/CMakeLists.txt); called when the CPU has AVX2.
#include "core/features/q15_blur.h"
#include "core/features/q15_blur_kernels.h"

namespace uavm::q15::avx2 {

void ConvolveRow(const int16_t* padded, int n, const int16_t* w, int radius, int16_t* out) {
  q15_kernels::ConvolveRowLanes(padded, n, w, radius, out);
}
void ConvolveColumnPair(const int16_t* const* rows, int n, const int16_t* w, int radius, int16_t* out0, int16_t* out1) {
  q15_kernels::ConvolveColumnPairLanes(rows, n, w, radius, out0, out1);
}

}  // namespace uavm::q15::avx2
