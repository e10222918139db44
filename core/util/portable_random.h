#pragma once
#include <cmath>
#include <cstdint>
#include <random>

namespace uavm {

// Random draws that are the same on every platform: std::mt19937_64's raw output is specified by the standard, but
// std::normal_distribution and std::uniform_real_distribution are not (libstdc++ differs between x86-64, whose long
// double is 80-bit, and aarch64, whose long double is 128-bit). Simulated flights and synthetic test scenes must not
// change with the machine that makes them.
class PortableRandom {
 public:
  explicit PortableRandom(uint64_t seed) : gen_(seed) {}
  double Uniform() { return static_cast<double>(gen_() >> 11) * 0x1.0p-53; }   // [0, 1)
  double Uniform(double lo, double hi) { return lo + (hi - lo) * Uniform(); }  // [lo, hi)
  double Symmetric() { return 2.0 * Uniform() - 1.0; }                         // [-1, 1)
  double Normal() {  // Box-Muller: no rejection loop, so a last-bit difference in log/cos cannot shift the stream
    const double u1 = 1.0 - Uniform();  // (0, 1]: log is finite
    const double u2 = Uniform();
    return std::sqrt(-2.0 * std::log(u1)) * std::cos(2.0 * 3.14159265358979323846 * u2);
  }
  double Normal(double sigma) { return sigma * Normal(); }

 private:
  std::mt19937_64 gen_;
};

}  // namespace uavm
