// The Jacobian checker must fail on a wrong Jacobian (else every factor test is vacuous), and
// the pose manifold must wrap theta.
#include <ceres/sized_cost_function.h>
#include <gtest/gtest.h>

#include <cmath>

#include "factors/factor_check.h"
#include "factors/pose_manifold.h"
#include "src/core/angles.h"

namespace stereoloc {
namespace {

// r = (sin(a0) * b0, a1 * b0^2); `wrong` flips one Jacobian entry's sign and scales another.
class ToyCost final : public ceres::SizedCostFunction<2, 2, 1> {
 public:
  explicit ToyCost(int wrong) : wrong_(wrong) {}
  bool Evaluate(double const* const* p, double* r, double** J) const override {
    const double a0 = p[0][0], a1 = p[0][1], b0 = p[1][0];
    r[0] = std::sin(a0) * b0;
    r[1] = a1 * b0 * b0;
    if (J && J[0]) {
      J[0][0] = std::cos(a0) * b0 * (wrong_ == 1 ? -1.0 : 1.0);
      J[0][1] = 0.0;
      J[0][2] = 0.0;
      J[0][3] = b0 * b0;
    }
    if (J && J[1]) {
      J[1][0] = std::sin(a0);
      J[1][1] = (wrong_ == 2 ? 1.001 : 2.0) * a1 * b0;  // 1.001 instead of 2
    }
    return true;
  }

 private:
  int wrong_;
};

class FailingCost final : public ceres::SizedCostFunction<1, 1> {
 public:
  bool Evaluate(double const* const*, double*, double**) const override { return false; }
};

TEST(FactorCheck, PassesOnCorrectJacobian) {
  const ToyCost cost(0);
  const double a[2] = {0.3, -1.7}, b[1] = {2.5};
  const FactorCheck c = checkFactorJacobians(cost, {a, b});
  EXPECT_TRUE(c.ok) << c.message;
  EXPECT_LT(c.max_relative_error, 1e-8);
}

TEST(FactorCheck, FailsOnWrongSign) {
  const ToyCost cost(1);
  const double a[2] = {0.3, -1.7}, b[1] = {2.5};
  const FactorCheck c = checkFactorJacobians(cost, {a, b});
  EXPECT_FALSE(c.ok);
  EXPECT_GT(c.max_relative_error, 0.1);
  EXPECT_NE(c.message.find("parameter block 0"), std::string::npos) << c.message;
}

TEST(FactorCheck, FailsOnWrongSecondBlock) {
  const ToyCost cost(2);
  const double a[2] = {0.3, -1.7}, b[1] = {2.5};
  const FactorCheck c = checkFactorJacobians(cost, {a, b});
  EXPECT_FALSE(c.ok);
  EXPECT_NE(c.message.find("parameter block 1"), std::string::npos) << c.message;
}

TEST(FactorCheck, FailsOnEvaluationFailureAndWrongArity) {
  const FailingCost failing;
  const double x[1] = {1.0};
  EXPECT_FALSE(checkFactorJacobians(failing, {x}).ok);
  const ToyCost cost(0);
  EXPECT_FALSE(checkFactorJacobians(cost, {x}).ok);
}

TEST(PoseManifold, PlusMinusWrapAndRoundTrip) {
  const PoseManifold m;
  EXPECT_EQ(m.AmbientSize(), 3);
  EXPECT_EQ(m.TangentSize(), 3);
  const double x[3] = {100.0, -50.0, kPi - 0.01};
  const double d[3] = {1.0, 2.0, 0.03};
  double y[3];
  ASSERT_TRUE(m.Plus(x, d, y));
  EXPECT_DOUBLE_EQ(y[0], 101.0);
  EXPECT_DOUBLE_EQ(y[1], -48.0);
  EXPECT_NEAR(y[2], -kPi + 0.02, 1e-12);
  double back[3];
  ASSERT_TRUE(m.Minus(y, x, back));
  for (int i = 0; i < 3; ++i) EXPECT_NEAR(back[i], d[i], 1e-12);
  double J[9];
  ASSERT_TRUE(m.PlusJacobian(x, J));
  for (int i = 0; i < 9; ++i) EXPECT_EQ(J[i], i % 4 == 0 ? 1.0 : 0.0);
  ASSERT_TRUE(m.MinusJacobian(x, J));
  for (int i = 0; i < 9; ++i) EXPECT_EQ(J[i], i % 4 == 0 ? 1.0 : 0.0);
}

}  // namespace
}  // namespace stereoloc
