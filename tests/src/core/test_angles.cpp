#include <gtest/gtest.h>

#include <ceres/jet.h>
#include <cmath>
#include <limits>

#include "src/core/angles.h"

namespace stereoloc {

TEST(WrapAngle, RangeIsHalfOpenMinusPiToPi) {
  EXPECT_DOUBLE_EQ(wrapAngle(kPi), -kPi);
  EXPECT_DOUBLE_EQ(wrapAngle(-kPi), -kPi);
  EXPECT_DOUBLE_EQ(wrapAngle(0.0), 0.0);
  EXPECT_NEAR(wrapAngle(kPi - 1e-12), kPi - 1e-12, 1e-15);
  EXPECT_NEAR(wrapAngle(3 * kPi), -kPi, 1e-12);
  EXPECT_NEAR(wrapAngle(-3 * kPi), -kPi, 1e-12);
}

TEST(WrapAngle, LargeMultiplesKeepPrecision) {
  for (double k : {1.0, 7.0, 1e3, 1e6}) {
    const double a = 0.3 + k * kTwoPi;
    EXPECT_NEAR(wrapAngle(a), 0.3, 1e-15 * k * 10 + 1e-15) << k;
    EXPECT_NEAR(wrapAngle(-a), -0.3, 1e-15 * k * 10 + 1e-15) << k;
  }
}

TEST(WrapAngle, ResultAlwaysInRange) {
  for (int i = -100000; i <= 100000; i += 7) {
    const double w = wrapAngle(i * 0.01);
    EXPECT_GE(w, -kPi);
    EXPECT_LT(w, kPi);
    EXPECT_NEAR(std::remainder(w - i * 0.01, kTwoPi), 0.0, 1e-9);
  }
}

TEST(WrapAngle, RejectsNonFinite) {
  EXPECT_THROW(wrapAngle(std::numeric_limits<double>::quiet_NaN()), Error);
  EXPECT_THROW(wrapAngle(std::numeric_limits<double>::infinity()), Error);
}

TEST(WrapAngle, WorksForJetAndKeepsDerivative) {
  using Jet = ceres::Jet<double, 2>;
  Jet a(3 * kPi + 0.25, 0);
  a.v[1] = 0.5;
  const Jet w = wrapAngle(a);
  EXPECT_NEAR(w.a, -kPi + 0.25, 1e-12);
  EXPECT_DOUBLE_EQ(w.v[0], 1.0);
  EXPECT_DOUBLE_EQ(w.v[1], 0.5);
  EXPECT_NEAR(wrapAngle(Jet(-kPi)).a, -kPi, 1e-15);
}

TEST(AngleDiff, SmallestSignedDifferenceAcrossPi) {
  EXPECT_NEAR(angleDiff(kPi - 0.1, -kPi + 0.1), -0.2, 1e-12);
  EXPECT_NEAR(angleDiff(-kPi + 0.1, kPi - 0.1), 0.2, 1e-12);
  EXPECT_NEAR(rad2deg(deg2rad(37.5)), 37.5, 1e-12);
}

}  // namespace stereoloc
