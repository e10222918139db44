#include "core/features/portable_math.h"

#include <gtest/gtest.h>

#include <cmath>

namespace uavm {
namespace {

// Against libm (an independent implementation): the polynomials hold their stated accuracy over the ranges SIFT uses.
TEST(PortableMathTest, ExpMatchesLibm) {
  for (double x = -60.0; x <= 60.0; x += 0.0137) {
    const double want = std::exp(x);
    EXPECT_NEAR(portable::Exp(x), want, 1e-14 * want) << x;
  }
  EXPECT_EQ(portable::Exp(-800.0), 0.0);
  EXPECT_NEAR(portable::Exp2(1.0 / 3.0), std::cbrt(2.0), 1e-15);
}

TEST(PortableMathTest, Atan2DegreesMatchesLibmWithinTwoHundredthsOfADegree) {
  double worst = 0.0;
  for (int i = 0; i < 3600; ++i) {
    const double t = (i + 0.37) * M_PI / 1800.0;
    for (double r : {1e-3, 0.7, 250.0}) {
      const auto x = static_cast<float>(r * std::cos(t));
      const auto y = static_cast<float>(r * std::sin(t));
      double want = std::atan2(static_cast<double>(y), static_cast<double>(x)) * 180.0 / M_PI;
      if (want < 0) want += 360.0;
      const double got = portable::Atan2Degrees(y, x);
      ASSERT_GE(got, 0.0);
      ASSERT_LT(got, 360.0);
      double diff = std::abs(got - want);
      diff = std::min(diff, 360.0 - diff);
      worst = std::max(worst, diff);
    }
  }
  EXPECT_LT(worst, 0.02);  // measured 0.0135
  EXPECT_EQ(portable::Atan2Degrees(0.f, 0.f), 0.f);
  EXPECT_NEAR(portable::Atan2Degrees(0.f, -1.f), 180.f, 1e-4f);
  EXPECT_NEAR(portable::Atan2Degrees(-1.f, 0.f), 270.f, 1e-4f);
}

TEST(PortableMathTest, SinCosDegreesMatchesLibm) {
  for (double d = -725.0; d <= 725.0; d += 0.173) {
    double s = 0.0;
    double c = 0.0;
    portable::SinCosDegrees(d, &s, &c);
    EXPECT_NEAR(s, std::sin(d * M_PI / 180.0), 1e-13) << d;
    EXPECT_NEAR(c, std::cos(d * M_PI / 180.0), 1e-13) << d;
  }
}

}  // namespace
}  // namespace uavm
