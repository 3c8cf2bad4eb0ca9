// Every factor: residual value, whitening, and Jacobians against central differences,
// including poses and residual angles near +-pi.
#include <gtest/gtest.h>

#include <memory>
#include <random>

#include "factors/compass_factor.h"
#include "factors/factor_check.h"
#include "factors/marginal_prior_factor.h"
#include "factors/odometry_factor.h"
#include "factors/pose_prior_factor.h"
#include "factors/range_bearing_factor.h"
#include "src/core/measurement_model.h"
#include "src/core/odometry_model.h"
#include "src/core/pose2.h"
#include "test_util.h"

namespace stereoloc {
namespace {

// Headings that exercise the wrap: near +pi, near -pi, and ordinary.
const double kHeadingsAcrossTheWrap[] = {kPi - 1e-7, -kPi + 1e-7, kPi - 0.02, -kPi + 0.03, 0.4, -2.0};

using test::evaluateResiduals;

TEST(OdometryFactor, ZeroAtPredictionAndWhitened) {
  const OdometryParams params;
  for (double th : kHeadingsAcrossTheWrap) {
    const double a[3] = {300.0, 200.0, th};
    const Eigen::Vector3d u = controlVector(12.0, 18.0, params.wheel_base_mm);
    const Pose2 b = compose(Pose2(a[0], a[1], a[2]), Pose2(u.x(), u.y(), u.z()));
    const double bv[3] = {b.x, b.y, b.theta};
    std::unique_ptr<ceres::CostFunction> f(OdometryFactor::Create(12.0, 18.0, params));
    EXPECT_LT(evaluateResiduals(*f, {a, bv}).norm(), 1e-9) << th;
    // An error e gives |r|^2 = e^T U^-1 e.
    const Eigen::Vector3d e(0.5, -0.3, 0.01);
    const Pose2 b2 = compose(Pose2(a[0], a[1], a[2]), Pose2(u.x() + e.x(), u.y() + e.y(), u.z() + e.z()));
    const double b2v[3] = {b2.x, b2.y, b2.theta};
    const Eigen::Matrix3d U = controlCovariance(12.0, 18.0, params);
    EXPECT_NEAR(evaluateResiduals(*f, {a, b2v}).squaredNorm(), e.dot(U.ldlt().solve(e)), 1e-6 * e.dot(U.ldlt().solve(e)));
  }
}

TEST(OdometryFactor, JacobiansMatchNumericAndB18B19) {
  const OdometryParams params;
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<double> U(-1.0, 1.0);
  for (double th : kHeadingsAcrossTheWrap) {
    for (int i = 0; i < 5; ++i) {
      const double dl = 20 * U(rng), dr = 20 * U(rng);
      std::unique_ptr<ceres::CostFunction> f(OdometryFactor::Create(dl, dr, params));
      const double a[3] = {700 * U(rng), 600 * U(rng), th};
      // The second heading also lands near the wrap for the near-pi cases.
      const double b[3] = {a[0] + 15 * U(rng), a[1] + 15 * U(rng), wrapAngle(th + 0.05 * U(rng))};
      const FactorCheck c = checkFactorJacobians(*f, {a, b});
      EXPECT_TRUE(c.ok) << "theta " << th << "\n" << c.message;
    }
  }
  // At the prediction, the Jacobians are S * J_between (src/core/pose2.h convention).
  const Pose2 pa(100, 50, kPi - 1e-3);
  const Eigen::Vector3d u = controlVector(10.0, 14.0, params.wheel_base_mm);
  const Pose2 pb = compose(pa, Pose2(u.x(), u.y(), u.z()));
  Matrix3d Ja, Jb;
  between(pa, pb, &Ja, &Jb);
  const Eigen::Matrix3d S = sqrtInformationUpper<3>(controlCovariance(10.0, 14.0, params));
  std::unique_ptr<ceres::CostFunction> f(OdometryFactor::Create(10.0, 14.0, params));
  const double a[3] = {pa.x, pa.y, pa.theta}, b[3] = {pb.x, pb.y, pb.theta};
  const double* p[2] = {a, b};
  Eigen::Matrix<double, 3, 3, Eigen::RowMajor> JA, JB;
  double* J[2] = {JA.data(), JB.data()};
  Eigen::Vector3d r;
  ASSERT_TRUE(f->Evaluate(p, r.data(), J));
  EXPECT_LT((JA - S * Ja).cwiseAbs().maxCoeff(), 1e-9 * S.cwiseAbs().maxCoeff());
  EXPECT_LT((JB - S * Jb).cwiseAbs().maxCoeff(), 1e-9 * S.cwiseAbs().maxCoeff());
}

TEST(RangeBearingFactor, MatchesMeasurementModelAndWrapsBearing) {
  const Eigen::Vector2d l(750.0, 650.0);
  Eigen::Matrix2d R;
  R << 25.0, 0.02, 0.02, 1e-4;  // correlated on purpose: tests the upper square root
  const Eigen::Matrix2d S = sqrtInformationUpper<2>(R);
  for (double th : kHeadingsAcrossTheWrap) {
    const double pose[3] = {200.0, 900.0, th};
    Matrix23d Jz;
    const Eigen::Vector2d h = predictRangeBearing(Pose2(pose[0], pose[1], pose[2]), l, &Jz);
    // Measured bearing on the other side of the wrap from the prediction when h(1) ~ +-pi.
    const Eigen::Vector2d z(h(0) + 3.0, wrapAngle(h(1) - 0.004));
    std::unique_ptr<ceres::CostFunction> f(RangeBearingFactor::Create(l, z, R));
    const Eigen::VectorXd r = evaluateResiduals(*f, {pose});
    EXPECT_LT((r - S * Eigen::Vector2d(-3.0, 0.004)).norm(), 1e-9) << th;
    const FactorCheck c = checkFactorJacobians(*f, {pose});
    EXPECT_TRUE(c.ok) << "theta " << th << "\n" << c.message;
    Eigen::Matrix<double, 2, 3, Eigen::RowMajor> J;
    double* Jp[1] = {J.data()};
    const double* p[1] = {pose};
    Eigen::Vector2d rr;
    ASSERT_TRUE(f->Evaluate(p, rr.data(), Jp));
    EXPECT_LT((J - S * Jz).cwiseAbs().maxCoeff(), 1e-9 * std::max(1.0, (S * Jz).cwiseAbs().maxCoeff()));
  }
}

TEST(RangeBearingFactor, PredictedBearingNearPi) {
  // Landmark straight behind the robot: predicted bearing is +-pi.
  const Eigen::Vector2d l(100.0, 500.0 + 1e-6);
  const double pose[3] = {600.0, 500.0, 1e-9};
  std::unique_ptr<ceres::CostFunction> f(
      RangeBearingFactor::Create(l, Eigen::Vector2d(500.0, -kPi + 0.01), Eigen::Vector2d(9.0, 1e-4).asDiagonal()));
  const FactorCheck c = checkFactorJacobians(*f, {pose});
  EXPECT_TRUE(c.ok) << c.message;
  EXPECT_LT(std::fabs(evaluateResiduals(*f, {pose})(1)), 0.011 / 0.01);
}

TEST(RangeBearingFactor, CoincidentLandmarkFailsEvaluation) {
  const double pose[3] = {750.0, 650.0, 0.0};
  std::unique_ptr<ceres::CostFunction> f(RangeBearingFactor::Create(
      Eigen::Vector2d(750.0, 650.0), Eigen::Vector2d(10.0, 0.0), Eigen::Vector2d(1.0, 1e-4).asDiagonal()));
  const double* p[1] = {pose};
  double r[2];
  EXPECT_FALSE(f->Evaluate(p, r, nullptr));
}

TEST(CompassFactor, WrappedAndJacobian) {
  std::unique_ptr<ceres::CostFunction> f(CompassFactor::Create(-kPi + 0.01, 0.02));
  const double pose[3] = {0.0, 0.0, kPi - 0.01};
  EXPECT_NEAR(evaluateResiduals(*f, {pose})(0), -0.02 / 0.02, 1e-9);
  for (double th : kHeadingsAcrossTheWrap) {
    const double q[3] = {10.0, 20.0, th};
    const FactorCheck c = checkFactorJacobians(*f, {q});
    EXPECT_TRUE(c.ok) << c.message;
  }
  EXPECT_THROW(CompassFactor::Create(0.0, 0.0), Error);
}

TEST(PosePriorFactor, WhitenedAndJacobian) {
  Eigen::Matrix3d P;
  P << 100, 20, 0.1, 20, 50, -0.05, 0.1, -0.05, 0.01;
  const Pose2 mean(500, 400, kPi - 0.005);
  std::unique_ptr<ceres::CostFunction> f(PosePriorFactor::Create(mean, P));
  const Eigen::Vector3d e(3.0, -2.0, 0.01);
  const double x[3] = {mean.x + e.x(), mean.y + e.y(), wrapAngle(mean.theta + e.z())};
  EXPECT_NEAR(evaluateResiduals(*f, {x}).squaredNorm(), e.dot(P.ldlt().solve(e)), 1e-9);
  for (double th : kHeadingsAcrossTheWrap) {
    const double q[3] = {480.0, 410.0, th};
    const FactorCheck c = checkFactorJacobians(*f, {q});
    EXPECT_TRUE(c.ok) << c.message;
  }
}

TEST(MarginalPriorFactor, ReproducesQuadraticModelAndJacobian) {
  std::mt19937_64 rng(3);
  std::normal_distribution<double> N(0.0, 1.0);
  Eigen::MatrixXd A(9, 6);
  for (int i = 0; i < A.size(); ++i) A.data()[i] = N(rng);
  const Eigen::MatrixXd H = A.transpose() * A + 0.1 * Eigen::MatrixXd::Identity(6, 6);
  Eigen::VectorXd g(6);
  for (int i = 0; i < 6; ++i) g(i) = N(rng);
  const std::vector<Pose2> x0 = {Pose2(10, 20, kPi - 1e-3), Pose2(30, 40, -kPi + 2e-3)};
  std::unique_ptr<MarginalPriorFactor> f(MarginalPriorFactor::FromInformation(x0, H, g));
  EXPECT_EQ(f->num_residuals(), 6);
  // At x0: J^T r = g and J^T J = H.
  const double a[3] = {x0[0].x, x0[0].y, x0[0].theta}, b[3] = {x0[1].x, x0[1].y, x0[1].theta};
  const double* p[2] = {a, b};
  Eigen::Matrix<double, 6, 3, Eigen::RowMajor> J0, J1;
  double* J[2] = {J0.data(), J1.data()};
  Eigen::VectorXd r(6);
  ASSERT_TRUE(f->Evaluate(p, r.data(), J));
  Eigen::MatrixXd Jf(6, 6);
  Jf << J0, J1;
  EXPECT_LT((Jf.transpose() * r - g).norm(), 1e-9);
  EXPECT_LT((Jf.transpose() * Jf - H).norm(), 1e-9 * H.norm());
  // Across the wrap: a step of +0.002 rad from pi - 1e-3 lands at -pi + 1e-3.
  const double a2[3] = {x0[0].x, x0[0].y, -kPi + 1e-3};
  Eigen::VectorXd dx = Eigen::VectorXd::Zero(6);
  dx(2) = 2e-3;
  EXPECT_LT((evaluateResiduals(*f, {a2, b}) - (f->sqrtInformation() * dx + f->r0())).norm(), 1e-9);
  for (double th : kHeadingsAcrossTheWrap) {
    const double q[3] = {12.0, 18.0, th};
    const FactorCheck c = checkFactorJacobians(*f, {q, b});
    EXPECT_TRUE(c.ok) << c.message;
  }
  Eigen::MatrixXd singular = H;
  singular.row(5).setZero();
  singular.col(5).setZero();
  EXPECT_THROW(MarginalPriorFactor::FromInformation(x0, singular, g), Error);
}

}  // namespace
}  // namespace stereoloc
