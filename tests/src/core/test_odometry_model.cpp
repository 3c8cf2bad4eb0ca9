#include <gtest/gtest.h>

#include <Eigen/Eigenvalues>
#include <random>

#include "src/core/odometry_model.h"
#include "test_util.h"

namespace stereoloc {
namespace {

constexpr double kW = 75.0;

Matrix32d numericJu(double dl, double dr) {
  auto g = [](const Eigen::Vector2d& d) { return controlVector(d(0), d(1), kW); };
  return numericJacobian<3, 2>(g, Eigen::Vector2d(dl, dr), 1e-5);
}

}  // namespace

TEST(Odometry, ControlVectorMatchesB5ForCurvedMotion) {
  const double dl = 8.0, dr = 12.0;
  const double alpha = (dr - dl) / kW, c = kW * (dr + dl) / (2 * (dr - dl));  // (B.1), (B.3)
  const Eigen::Vector3d u = controlVector(dl, dr, kW);
  EXPECT_NEAR(u.x(), c * std::sin(alpha), 1e-12);
  EXPECT_NEAR(u.y(), c * (1 - std::cos(alpha)), 1e-12);
  EXPECT_NEAR(u.z(), alpha, 1e-15);
}

TEST(Odometry, StraightLineAndSpinLimitsAreExact) {
  const Eigen::Vector3d straight = controlVector(10.0, 10.0, kW);  // (B.20)
  EXPECT_DOUBLE_EQ(straight.x(), 10.0);
  EXPECT_DOUBLE_EQ(straight.y(), 0.0);
  EXPECT_DOUBLE_EQ(straight.z(), 0.0);
  const Eigen::Vector3d spin = controlVector(-5.0, 5.0, kW);  // (B.24)
  EXPECT_DOUBLE_EQ(spin.x(), 0.0);
  EXPECT_DOUBLE_EQ(spin.y(), 0.0);
  EXPECT_NEAR(spin.z(), 2 * 5.0 / kW, 1e-15);
  const Eigen::Vector3d still = controlVector(0.0, 0.0, kW);
  EXPECT_TRUE(still.isZero());
}

TEST(Odometry, JacobianMatchesCentralDifferencesEverywhere) {
  std::mt19937_64 rng(11);
  std::uniform_real_distribution<double> U(-30, 30);
  for (int i = 0; i < 500; ++i) {
    const double dl = U(rng), dr = U(rng);
    Matrix32d J;
    controlVector(dl, dr, kW, &J);
    EXPECT_TRUE(test::jacobianMatches(J, numericJu(dl, dr))) << dl << " " << dr;
  }
}

TEST(Odometry, JacobianNearBothLimits) {
  for (double eps : {0.0, 1e-12, 1e-9, -1e-9, 1e-6, 1e-3}) {
    for (double d : {-20.0, 0.5, 9.0}) {
      Matrix32d J;
      controlVector(d, d + eps, kW, &J);  // straight line
      EXPECT_TRUE(test::jacobianMatches(J, numericJu(d, d + eps))) << "straight " << d << " " << eps;
      controlVector(-d, d + eps, kW, &J);  // turn on the spot
      EXPECT_TRUE(test::jacobianMatches(J, numericJu(-d, d + eps))) << "spin " << d << " " << eps;
    }
  }
  // (B.22) corrected: at the straight-line limit dy/dd_l = -v/(2w), dy/dd_r = +v/(2w).
  Matrix32d J;
  controlVector(10, 10, kW, &J);
  EXPECT_NEAR(J(0, 0), 0.5, 1e-15);
  EXPECT_NEAR(J(1, 0), -10.0 / (2 * kW), 1e-15);
  EXPECT_NEAR(J(1, 1), 10.0 / (2 * kW), 1e-15);
  EXPECT_NEAR(J(2, 0), -1 / kW, 1e-15);
  // (B.26) at the spin limit: columns equal in the first two rows, w sin(a)/(4 v_r).
  controlVector(-6, 6, kW, &J);
  const double a = 12 / kW;
  EXPECT_NEAR(J(0, 0), kW * std::sin(a) / (4 * 6), 1e-14);
  EXPECT_NEAR(J(0, 1), J(0, 0), 1e-14);
  EXPECT_NEAR(J(1, 0), kW * (1 - std::cos(a)) / (4 * 6), 1e-14);
}

TEST(Odometry, ControlVectorContinuousAcrossLimits) {
  for (double d : {-15.0, 3.0, 40.0}) {
    const Eigen::Vector3d at = controlVector(d, d, kW);
    for (double eps : {1e-9, 1e-7, 1e-5}) {
      EXPECT_LT((controlVector(d, d + eps, kW) - at).norm(), 10 * eps);
      EXPECT_LT((controlVector(d, d - eps, kW) - at).norm(), 10 * eps);
    }
  }
  // Crossing the series/closed-form switch at |alpha| = 1e-2 is seamless.
  const double dr = 1e-2 * kW;
  EXPECT_LT((controlVector(0, dr * (1 - 1e-12), kW) - controlVector(0, dr * (1 + 1e-12), kW)).norm(), 1e-10);
}

TEST(Odometry, CovarianceSymmetricPsdAndContinuous) {
  OdometryParams p;
  p.control_variance_floor.setZero();
  std::mt19937_64 rng(12);
  std::uniform_real_distribution<double> U(-25, 25);
  for (int i = 0; i < 300; ++i) {
    const double dl = U(rng), dr = (i % 3 == 0) ? dl + 1e-10 : ((i % 3 == 1) ? -dl + 1e-10 : U(rng));
    const Eigen::Matrix3d Uk = controlCovariance(dl, dr, p);
    EXPECT_LT((Uk - Uk.transpose()).norm(), 1e-15);
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(Uk);
    EXPECT_GE(es.eigenvalues().minCoeff(), -1e-12 * std::max(1.0, Uk.norm()));
  }
  // Continuous across both limits (B.10 vs B.23/B.27).
  for (double d : {-12.0, 7.0}) {
    const Eigen::Matrix3d straight = controlCovariance(d, d, p), spin = controlCovariance(-d, d, p);
    EXPECT_LT((controlCovariance(d, d + 1e-9, p) - straight).norm(), 1e-8);
    EXPECT_LT((controlCovariance(-d, d + 1e-9, p) - spin).norm(), 1e-8);
    // (B.27): U33 = (s_l^2 + s_r^2)/w^2 at the spin.
    EXPECT_NEAR(spin(2, 2), (p.k_left + p.k_right) * std::fabs(d) / (kW * kW), 1e-15);
  }
}

TEST(Odometry, CovarianceMatchesClosedFormB10Elements) {
  OdometryParams p;
  p.control_variance_floor.setZero();
  const double vl = 9, vr = 13, sl = p.k_left * vl, sr = p.k_right * vr;
  const double a = (vr - vl) / kW, D = vr - vl, Q = vr * vr - vl * vl;
  const double U11 = (Q * Q * (sl + sr) * std::cos(a) * std::cos(a) + 4 * kW * kW * (vr * vr * sl + vl * vl * sr) * std::sin(a) * std::sin(a) -
                      4 * kW * Q * (vr * sl + vl * sr) * std::sin(a) * std::cos(a)) /
                     (4 * std::pow(D, 4));
  const double U13 = (Q * (sl + sr) * std::cos(a) - 2 * kW * (vr * sl + vl * sr) * std::sin(a)) / (2 * kW * D * D);
  const double U33 = (sl + sr) / (kW * kW);
  const Eigen::Matrix3d Uk = controlCovariance(vl, vr, p);
  EXPECT_NEAR(Uk(0, 0), U11, 1e-12 * std::fabs(U11));
  EXPECT_NEAR(Uk(0, 2), U13, 1e-12 * std::fabs(U13) + 1e-18);
  EXPECT_NEAR(Uk(2, 2), U33, 1e-15);
}

TEST(Odometry, CovarianceMatchesMonteCarlo) {
  OdometryParams p;
  p.control_variance_floor.setZero();
  const double dl = 6, dr = 14;
  std::mt19937_64 rng(13);
  std::normal_distribution<double> Nl(0, std::sqrt(p.k_left * dl)), Nr(0, std::sqrt(p.k_right * dr));
  const Eigen::Vector3d u0 = controlVector(dl, dr, kW);
  Eigen::Matrix3d acc = Eigen::Matrix3d::Zero();
  const int n = 200000;
  for (int i = 0; i < n; ++i) {
    const Eigen::Vector3d e = controlVector(dl + Nl(rng), dr + Nr(rng), kW) - u0;
    acc += e * e.transpose();
  }
  const Eigen::Matrix3d Uk = controlCovariance(dl, dr, p);
  for (int i = 0; i < 3; ++i) EXPECT_NEAR(acc(i, i) / n, Uk(i, i), 0.03 * Uk(i, i));
}

TEST(Odometry, PredictionCompoundsAndPropagates) {
  OdometryParams p;
  const Pose2 start(100, 200, kPi - 0.01);
  Eigen::Matrix3d P = Eigen::Matrix3d::Identity();
  const PosePrediction pred = predictPose(start, P, 10, 12, p);
  const Eigen::Vector3d u = controlVector(10, 12, kW);
  const Pose2 expect = compose(start, Pose2(u.x(), u.y(), u.z()));
  EXPECT_NEAR(minus(pred.pose, expect).norm(), 0, 1e-12);
  EXPECT_GT(pred.pose.theta, -kPi);  // wrapped across +-pi
  EXPECT_GT(pred.covariance.trace(), P.trace());
  EXPECT_THROW(controlVector(std::nan(""), 1, kW), Error);
  OdometryParams bad;
  for (const double w : {-1.0, 0.5, 1e-300, 1e6}) {
    bad.wheel_base_mm = w;
    EXPECT_THROW(bad.validate(), Error) << w;
  }
}

TEST(Odometry, WheelIncrementsForArcInvertsControl) {
  const WheelIncrements w = wheelIncrementsForArc(50.0, 0.3, kW);
  const Eigen::Vector3d u = controlVector(w.d_left, w.d_right, kW);
  EXPECT_NEAR(u.z(), 0.3, 1e-15);
  // Arc of length 50 with heading change 0.3: chord = 2 R sin(0.15), R = 50/0.3.
  EXPECT_NEAR(u.head<2>().norm(), 2 * (50 / 0.3) * std::sin(0.15), 1e-12);
}

TEST(NoiseTravel, MeanOfTheStepsBeforeWithHalfTheOwnReadingAsFloor) {
  NoiseTravel t(OdometryReadings::Encoders, 3);
  // The first step has no history: its own |reading|.
  WheelIncrements w = t.next(-2.0, 4.0);
  EXPECT_DOUBLE_EQ(w.d_left, 2.0);
  EXPECT_DOUBLE_EQ(w.d_right, 4.0);
  w = t.next(1.0, 1.0);  // mean of (2, 4) before it
  EXPECT_DOUBLE_EQ(w.d_left, 2.0);
  EXPECT_DOUBLE_EQ(w.d_right, 4.0);
  w = t.next(3.0, -3.0);  // means of (2, 1) and (4, 1)
  EXPECT_DOUBLE_EQ(w.d_left, 1.5);
  EXPECT_DOUBLE_EQ(w.d_right, 2.5);
  w = t.next(0.0, 0.0);  // means of (2, 1, 3) and (4, 1, 3)
  EXPECT_DOUBLE_EQ(w.d_left, 2.0);
  EXPECT_DOUBLE_EQ(w.d_right, 8.0 / 3.0);
  w = t.next(30.0, 0.0);  // history (1, 3, 0): a start far above its mean takes half its own
  EXPECT_DOUBLE_EQ(w.d_left, 15.0);
  EXPECT_DOUBLE_EQ(w.d_right, 4.0 / 3.0);  // (1, 3, 0) on the right too
  EXPECT_THROW(NoiseTravel(OdometryReadings::Encoders, 0), Error);
}

TEST(NoiseTravel, CommandsAreTheirOwnTravel) {
  NoiseTravel t(OdometryReadings::Commands, 3);
  t.next(5.0, 5.0);
  const WheelIncrements w = t.next(-1.0, 30.0);
  EXPECT_DOUBLE_EQ(w.d_left, 1.0);
  EXPECT_DOUBLE_EQ(w.d_right, 30.0);
  EXPECT_EQ(odometryReadingsFromString(toString(OdometryReadings::Commands)), OdometryReadings::Commands);
  EXPECT_EQ(odometryReadingsFromString("encoders"), OdometryReadings::Encoders);
  EXPECT_THROW(odometryReadingsFromString("velocities"), Error);
}

}  // namespace stereoloc
