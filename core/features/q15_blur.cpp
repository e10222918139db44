#include "core/features/q15_blur.h"

#include "core/features/q15_blur_kernels.h"

namespace uavm::q15 {

namespace generic {
void ConvolveRow(const int16_t* padded, int n, const int16_t* w, int radius, int16_t* out) {
  q15_kernels::ConvolveRowLanes(padded, n, w, radius, out);
}
void ConvolveColumnPair(const int16_t* const* rows, int n, const int16_t* w, int radius, int16_t* out0, int16_t* out1) {
  q15_kernels::ConvolveColumnPairLanes(rows, n, w, radius, out0, out1);
}
}  // namespace generic

#if defined(__x86_64__)
namespace {
const bool kHasAvx2 = __builtin_cpu_supports("avx2");
}  // namespace

void ConvolveRow(const int16_t* padded, int n, const int16_t* w, int radius, int16_t* out) {
  (kHasAvx2 ? avx2::ConvolveRow : generic::ConvolveRow)(padded, n, w, radius, out);
}
void ConvolveColumnPair(const int16_t* const* rows, int n, const int16_t* w, int radius, int16_t* out0, int16_t* out1) {
  (kHasAvx2 ? avx2::ConvolveColumnPair : generic::ConvolveColumnPair)(rows, n, w, radius, out0, out1);
}
#else
void ConvolveRow(const int16_t* padded, int n, const int16_t* w, int radius, int16_t* out) {
  generic::ConvolveRow(padded, n, w, radius, out);
}
void ConvolveColumnPair(const int16_t* const* rows, int n, const int16_t* w, int radius, int16_t* out0, int16_t* out1) {
  generic::ConvolveColumnPair(rows, n, w, radius, out0, out1);
}
#endif

}  // namespace uavm::q15
