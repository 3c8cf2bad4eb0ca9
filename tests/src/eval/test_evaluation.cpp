#include <gtest/gtest.h>

#include <random>

#include "src/eval/evaluation.h"
#include "src/core/gaussian.h"

namespace stereoloc {

TEST(Evaluation, ErrorStatsThesisFormat) {
  const ErrorStats s = errorStats({1, 2, 3, 4});
  EXPECT_EQ(s.count, 4u);
  EXPECT_DOUBLE_EQ(s.mean, 2.5);
  EXPECT_DOUBLE_EQ(s.std, std::sqrt(1.25));
  EXPECT_DOUBLE_EQ(s.min, 1);
  EXPECT_DOUBLE_EQ(s.max, 4);
  EXPECT_EQ(errorStats({}).count, 0u);
}

TEST(Evaluation, PoseErrorsMatchByStepAndWrapTheta) {
  std::vector<Step> steps(3);
  for (int i = 0; i < 3; ++i) steps[i].step = 10 + i;
  const std::vector<std::optional<Pose2>> gt = {Pose2(0, 0, kPi - 0.01), std::nullopt, Pose2(5, 5, 0)};
  const TruthByStep truth = truthByStep(steps, gt);
  ASSERT_EQ(truth.size(), 2u);
  Estimate a;
  a.step = 10;
  a.pose = Pose2(3, 4, -kPi + 0.01);
  a.covariance = Eigen::Matrix3d::Identity();
  a.status = EstimateStatus::Tracking;
  Estimate b = a;
  b.step = 11;  // no truth
  Estimate c = a;
  c.step = 12;
  c.status = EstimateStatus::Uninitialised;  // skipped
  const auto errs = poseErrors({a, b, c}, truth);
  ASSERT_EQ(errs.size(), 1u);
  EXPECT_DOUBLE_EQ(errs[0].distance, 5);
  EXPECT_NEAR(errs[0].dtheta, 0.02, 1e-12);
  ASSERT_TRUE(errs[0].nees.has_value());
  EXPECT_NEAR(*errs[0].nees, 25 + 0.0004, 1e-9);
  EXPECT_NEAR(errs[0].position_nees.value_or(-1), 25, 1e-9);
  EXPECT_NEAR(errs[0].heading_nees.value_or(-1), 0.0004, 1e-12);
  const TrajectoryMetrics m = trajectoryMetrics(errs);
  EXPECT_DOUBLE_EQ(m.position_rmse, 5);
  EXPECT_NEAR(m.theta_rmse, 0.02, 1e-12);
}

TEST(Evaluation, NeesOfConsistentEstimatorIsNearDofAndInBand) {
  std::mt19937_64 rng(3);
  std::normal_distribution<double> N;
  Eigen::Matrix3d P;
  P << 100, 20, 0.1, 20, 50, -0.05, 0.1, -0.05, 0.01;
  const Eigen::Matrix3d L = P.llt().matrixL();
  // The same errors against P and against P with the heading's variance stated 4x too wide.
  Eigen::Matrix3d wide_heading = P;
  wide_heading.row(2) *= 2.0;
  wide_heading.col(2) *= 2.0;
  std::vector<PoseError> errs, wide;
  const Pose2 truth(500, 500, 3.1);
  for (int i = 0; i < 20000; ++i) {
    const Eigen::Vector3d e = L * Eigen::Vector3d(N(rng), N(rng), N(rng));
    Estimate est;
    est.step = i;
    est.pose = plus(truth, e);
    est.covariance = P;
    est.status = EstimateStatus::Tracking;
    errs.push_back(poseErrors({est}, TruthByStep{{i, truth}})[0]);
    est.covariance = wide_heading;
    wide.push_back(poseErrors({est}, TruthByStep{{i, truth}})[0]);
  }
  const TrajectoryMetrics m = trajectoryMetrics(errs);
  EXPECT_NEAR(m.mean_nees, 3.0, 0.1);
  EXPECT_NEAR(m.nees_in_band, 0.95, 0.01);
  // Its parts: 2 for the position, 1 for the heading; the too wide heading shows in its part only.
  EXPECT_NEAR(m.mean_position_nees, 2.0, 0.07);
  EXPECT_NEAR(m.mean_heading_nees, 1.0, 0.05);
  const TrajectoryMetrics w = trajectoryMetrics(wide);
  EXPECT_EQ(w.mean_position_nees, m.mean_position_nees);
  EXPECT_NEAR(w.mean_heading_nees, 0.25 * m.mean_heading_nees, 1e-12);
  const NeesBand band = neesBand(3, 100);
  EXPECT_LT(band.lo, 3.0);
  EXPECT_GT(band.hi, 3.0);
  EXPECT_NEAR(band.lo, chi2Quantile(0.025, 300) / 100, 1e-12);
  // An overconfident covariance is detected.
  EXPECT_GT(*nees(plus(truth, Eigen::Vector3d(30, 0, 0)), Eigen::Matrix3d::Identity(), truth), band.hi);
  EXPECT_FALSE(nees(truth, Eigen::Matrix3d::Zero(), truth).has_value());
}

}  // namespace stereoloc
