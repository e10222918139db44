#pragma once
// Elementary functions that give the same bits on x86-64 and aarch64.
//
// The SIFT's keypoints and descriptors must not depend on the machine (the parity step compares the two builds to
// 0.0000 px), but libm's exp, atan2 and sin differ between architectures in their last bit (their own polynomials,
// fused multiply-adds on arm64). These are plain polynomials in IEEE arithmetic; the project builds with
// -ffp-contract=off, so every platform rounds the same operations in the same order. Accuracy is what SIFT needs
// (exp and sin/cos to ~1e-15, atan2 to 0.014 degree), tested against libm in tests/portable_math_test.cpp.
#include <cmath>
#include <cstdint>
#include <cstring>

namespace uavm::portable {

// e^x for x in [-700, 700]; 2^k * e^r with |r| <= ln2/2 (ln2 in two parts, so that r is exact) and a degree-12
// Taylor polynomial (relative error ~2e-16).
inline double Exp(double x) {
  constexpr double kLn2High = 0.6931471803691238;  // 33 significant bits: k * kLn2High is exact
  constexpr double kLn2Low = 1.9082149292705877e-10;
  constexpr double kInvLn2 = 1.4426950408889634;
  if (x < -700.0) return 0.0;
  if (x > 700.0) x = 700.0;
  const double kf = x * kInvLn2 + (x >= 0 ? 0.5 : -0.5);
  const auto k = static_cast<int64_t>(kf);  // rounds half away from zero
  const double r = (x - static_cast<double>(k) * kLn2High) - static_cast<double>(k) * kLn2Low;
  double p = 1.0 / 479001600.0;
  p = p * r + 1.0 / 39916800.0;
  p = p * r + 1.0 / 3628800.0;
  p = p * r + 1.0 / 362880.0;
  p = p * r + 1.0 / 40320.0;
  p = p * r + 1.0 / 5040.0;
  p = p * r + 1.0 / 720.0;
  p = p * r + 1.0 / 120.0;
  p = p * r + 1.0 / 24.0;
  p = p * r + 1.0 / 6.0;
  p = p * r + 0.5;
  p = p * r + 1.0;
  p = p * r + 1.0;
  // Scale by 2^k through the exponent field (k within the normal range here).
  const uint64_t bits = static_cast<uint64_t>(k + 1023) << 52;
  double scale;
  std::memcpy(&scale, &bits, sizeof scale);
  return p * scale;
}

// 2^x.
inline double Exp2(double x) {
  return Exp(x * 0.6931471805599453);
}

// Direction of (x, y) in degrees, [0, 360); 0 for (0, 0). A degree-7 odd minimax polynomial of atan on [0, 1] (the
// coefficients OpenCV's fastAtan2 publishes; max error ~0.014 degree), folded into the octants.
constexpr float kAtanP1 = 0.9997878412794807f * 57.29577951308232f;
constexpr float kAtanP3 = -0.3258083974640975f * 57.29577951308232f;
constexpr float kAtanP5 = 0.1555786518463281f * 57.29577951308232f;
constexpr float kAtanP7 = -0.04432655554792128f * 57.29577951308232f;
constexpr float kAtanEpsilon = 1.1920929e-07f;
inline float Atan2Degrees(float y, float x) {
  constexpr float p1 = kAtanP1;
  constexpr float p3 = kAtanP3;
  constexpr float p5 = kAtanP5;
  constexpr float p7 = kAtanP7;
  // Branch-free; core/features/dog_sift.cpp has the same steps in vector form.
  const float ax = std::fabs(x);
  const float ay = std::fabs(y);
  const float lo = ax < ay ? ax : ay;
  const float hi = ax < ay ? ay : ax;
  const float c = lo / (hi + kAtanEpsilon);
  const float c2 = c * c;
  float a = (((p7 * c2 + p5) * c2 + p3) * c2 + p1) * c;
  a = ax < ay ? 90.f - a : a;
  a = x < 0 ? 180.f - a : a;
  a = y < 0 ? 360.f - a : a;
  return a >= 360.f ? a - 360.f : a;
}

// cos and sin of an angle in degrees.
inline void SinCosDegrees(double degrees, double* sin_out, double* cos_out) {
  // Reduce to [-45, 45] degrees and a quadrant.
  double turns = degrees / 90.0;
  const double kq = turns + (turns >= 0 ? 0.5 : -0.5);
  const auto q = static_cast<int64_t>(kq);
  const double r = (degrees - static_cast<double>(q) * 90.0) * 0.017453292519943295;
  const double r2 = r * r;
  // Taylor to r^15 / r^14: |r| <= pi/4 gives ~1e-15.
  double s = -1.0 / 1307674368000.0;
  s = s * r2 + 1.0 / 6227020800.0;
  s = s * r2 - 1.0 / 39916800.0;
  s = s * r2 + 1.0 / 362880.0;
  s = s * r2 - 1.0 / 5040.0;
  s = s * r2 + 1.0 / 120.0;
  s = s * r2 - 1.0 / 6.0;
  s = (s * r2 + 1.0) * r;
  double c = -1.0 / 87178291200.0;
  c = c * r2 + 1.0 / 479001600.0;
  c = c * r2 - 1.0 / 3628800.0;
  c = c * r2 + 1.0 / 40320.0;
  c = c * r2 - 1.0 / 720.0;
  c = c * r2 + 1.0 / 24.0;
  c = c * r2 - 0.5;
  c = c * r2 + 1.0;
  switch (static_cast<int>(((q % 4) + 4) % 4)) {
    case 0:
      *sin_out = s;
      *cos_out = c;
      break;
    case 1:
      *sin_out = c;
      *cos_out = -s;
      break;
    case 2:
      *sin_out = -s;
      *cos_out = -c;
      break;
    default:
      *sin_out = -c;
      *cos_out = s;
      break;
  }
}

}  // namespace uavm::portable
