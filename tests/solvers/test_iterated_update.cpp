// The range-bearing update of a Gaussian pose belief (solvers/iterated_update.h): the residual's
// Jacobian against central differences, the one-step update against the information form, the
// iterated update at a stationary point of the MAP cost, step control where the full
// Gauss-Newton step overshoots, and the degenerate cases.
#include "solvers/iterated_update.h"

#include <gtest/gtest.h>

#include <Eigen/Cholesky>
#include <Eigen/LU>
#include <cmath>
#include <random>

#include "src/core/angles.h"
#include "src/core/error.h"
#include "src/core/measurement_model.h"
#include "src/core/numeric_diff.h"
#include "test_util.h"

namespace stereoloc {
namespace {

using test::jacobianMatches;

struct Problem {
  Pose2 prior;
  Eigen::Matrix3d P;
  Eigen::Vector2d z;
  Eigen::Matrix2d R;
  Eigen::Vector2d landmark;
};

double mapCost(const Problem& p, const Eigen::Vector3d& delta) {
  const std::optional<MapResidual> m = rangeBearingMapResidual(p.prior, p.P, p.z, p.R, p.landmark, delta);
  return m ? m->r.squaredNorm() : std::numeric_limits<double>::infinity();
}

// A stereo-sharp sighting (range to 1 %, bearing to 0.02 deg, correlated as (5.32) makes them)
// from a prior 75 mm and 5 deg off: the situation where one step leaves the MAP estimate.
Problem farPrior() {
  Problem p;
  const Pose2 truth(750.0, 650.0, -kPi / 2);
  p.prior = Pose2(686.8, 689.7, -kPi / 2 - 0.09);
  p.P = Eigen::Vector3d(900.0, 900.0, 0.0076).asDiagonal();
  p.landmark = Eigen::Vector2d(750.0, 0.0);
  p.z = predictRangeBearing(truth, p.landmark) + Eigen::Vector2d(-0.5, 0.0002);
  p.R << 643.5, -0.0282, -0.0282, 3.83e-6;
  return p;
}

TEST(IteratedUpdate, ResidualJacobianMatchesCentralDifferences) {
  const Problem p = farPrior();
  // Also with the bearing at +-pi: the landmark behind the robot, the wrap inside the residual.
  Problem behind = p;
  behind.prior = Pose2(750.0, -500.0, -kPi / 2);
  behind.z = Eigen::Vector2d(500.0, kPi - 1e-4);
  for (const Problem& q : {p, behind}) {
    for (const Eigen::Vector3d& delta : {Eigen::Vector3d(0, 0, 0), Eigen::Vector3d(40.0, -25.0, 0.07)}) {
      const std::optional<MapResidual> m = rangeBearingMapResidual(q.prior, q.P, q.z, q.R, q.landmark, delta);
      ASSERT_TRUE(m);
      const auto f = [&](const Eigen::Vector3d& d) {
        return rangeBearingMapResidual(q.prior, q.P, q.z, q.R, q.landmark, d)->r;
      };
      // The bearing rows are whitened by a 1e-3 rad sigma: compare relative to the largest entry.
      EXPECT_TRUE(jacobianMatches(m->J_r_delta, numericJacobian<5, 3>(f, delta, 1e-7), 1e-5));
      EXPECT_NEAR(m->r.squaredNorm(), mapCost(q, delta), 1e-9 * (1 + m->r.squaredNorm()));
    }
  }
}

// One step is the EKF update (5.15), (5.17), (5.19): the information form at the prior.
TEST(IteratedUpdate, OneStepEqualsTheInformationForm) {
  Problem p;
  p.prior = Pose2(700, 500, 2.5);
  p.P << 400, 50, 0.3, 50, 900, -0.2, 0.3, -0.2, 0.02;
  p.landmark = Eigen::Vector2d(150.0, 900.0);
  Matrix23d H;
  const Eigen::Vector2d zhat = predictRangeBearing(p.prior, p.landmark, &H);
  p.z = zhat + Eigen::Vector2d(15.0, -0.03);
  p.R << 400.0, 0.1, 0.1, 4e-4;
  const auto post = updateRangeBearingBelief(p.prior, p.P, p.z, p.R, p.landmark, IteratedUpdateOptions{});
  ASSERT_TRUE(post);
  const Eigen::Matrix3d Ppost = (p.P.inverse() + H.transpose() * p.R.inverse() * H).inverse();
  const Eigen::Vector3d dx = Ppost * H.transpose() * p.R.inverse() * Eigen::Vector2d(15.0, -0.03);
  EXPECT_NEAR(post->pose.x, p.prior.x + dx.x(), 1e-9);
  EXPECT_NEAR(post->pose.y, p.prior.y + dx.y(), 1e-9);
  EXPECT_NEAR(post->pose.theta, p.prior.theta + dx.z(), 1e-12);
  EXPECT_LT(((post->covariance - Ppost).array() / Ppost.cwiseAbs().array().max(1e-6)).abs().maxCoeff(), 1e-9);
  EXPECT_EQ(post->iterations, 1);
  const auto gate = rangeBearingInnovationAt(p.prior, p.P, p.z, p.R, p.landmark);
  ASSERT_TRUE(gate);
  EXPECT_NEAR(gate->mahalanobis_squared,
              Eigen::Vector2d(15.0, -0.03).dot((H * p.P * H.transpose() + p.R).inverse() * Eigen::Vector2d(15.0, -0.03)),
              1e-12);
}

// The iterated result is a stationary point of the MAP cost (gradient 2 J^T r = 0, with the
// Jacobian checked above) and no more expensive than the one-step result; the one step is not
// stationary from this prior.
TEST(IteratedUpdate, IteratedResultIsTheMapEstimate) {
  const Problem p = farPrior();
  const auto one = updateRangeBearingBelief(p.prior, p.P, p.z, p.R, p.landmark, IteratedUpdateOptions{});
  const auto it = updateRangeBearingBelief(p.prior, p.P, p.z, p.R, p.landmark, IteratedUpdateOptions{20, 1e-9, 10});
  ASSERT_TRUE(one && it);
  const auto gradient = [&](const Pose2& x) {
    const auto m = rangeBearingMapResidual(p.prior, p.P, p.z, p.R, p.landmark, minus(x, p.prior));
    return Eigen::Vector3d(2.0 * m->J_r_delta.transpose() * m->r);
  };
  // Scale: the prior term's gradient alone at the result.
  const Eigen::Vector3d prior_gradient = 2.0 * p.P.ldlt().solve(minus(it->pose, p.prior));
  EXPECT_LT(gradient(it->pose).norm(), 1e-6 * prior_gradient.norm()) << gradient(it->pose).transpose();
  EXPECT_GT(gradient(one->pose).norm(), 0.1 * prior_gradient.norm());
  EXPECT_LE(it->map_cost, one->map_cost);
  EXPECT_NEAR(it->map_cost, mapCost(p, minus(it->pose, p.prior)), 1e-9);
  EXPECT_GT(it->iterations, 1);
  EXPECT_LE(it->iterations, 20);
}

// A wide prior (300 mm) about a truth 200 mm from the landmark: the bearing is strongly
// curved over the prior, and the full Gauss-Newton step from the prior overshoots (it raises the
// MAP cost). Step control never accepts a step that raises the cost.
TEST(IteratedUpdate, StepControlNeverRaisesTheMapCost) {
  std::mt19937_64 rng(5);
  std::normal_distribution<double> n01;
  int overshooting = 0;
  for (int k = 0; k < 200; ++k) {
    Problem p;
    p.landmark = Eigen::Vector2d(500.0, 500.0);
    const Pose2 truth(300.0, 500.0, 0.1 * n01(rng));
    p.P = Eigen::Vector3d(300.0 * 300.0, 300.0 * 300.0, 0.1 * 0.1).asDiagonal();
    p.prior = plus(truth, Eigen::Vector3d(300.0 * n01(rng), 300.0 * n01(rng), 0.1 * n01(rng)));
    if ((p.prior.translation() - p.landmark).norm() < 50.0) continue;
    p.z = predictRangeBearing(truth, p.landmark) + Eigen::Vector2d(2.0 * n01(rng), 0.001 * n01(rng));
    p.R = Eigen::Vector2d(4.0, 1e-6).asDiagonal();
    const auto one = updateRangeBearingBelief(p.prior, p.P, p.z, p.R, p.landmark, IteratedUpdateOptions{});
    ASSERT_TRUE(one);
    const double c0 = mapCost(p, Eigen::Vector3d::Zero());
    if (one->map_cost > c0) ++overshooting;
    // Every accepted step lowers the cost: a longer iteration is never more expensive.
    double previous = c0;
    for (int n = 2; n <= 8; ++n) {
      const auto it = updateRangeBearingBelief(p.prior, p.P, p.z, p.R, p.landmark, IteratedUpdateOptions{n, 1e-9, 30});
      ASSERT_TRUE(it);
      EXPECT_LE(it->map_cost, previous) << k << " " << n;
      EXPECT_TRUE(it->pose.isFinite() && it->covariance.allFinite()) << k;
      previous = it->map_cost;
    }
    EXPECT_LE(previous, one->map_cost * (1 + 1e-12)) << k;
  }
  EXPECT_GT(overshooting, 10);  // the case the step control exists for does occur (24 of 193)
}

TEST(IteratedUpdate, DegenerateCasesAreExplicit) {
  Problem p = farPrior();
  // The landmark at the prior: the bearing is undefined, nothing to fuse, no gate.
  EXPECT_FALSE(updateRangeBearingBelief(p.prior, p.P, p.z, p.R, p.prior.translation(), IteratedUpdateOptions{10, 1e-6, 10}));
  EXPECT_FALSE(rangeBearingInnovationAt(p.prior, p.P, p.z, p.R, p.prior.translation()));
  // A semi-definite prior (theta known exactly): the cost is undefined, full steps; still finite.
  Problem known = p;
  known.P(2, 2) = 0.0;
  EXPECT_FALSE(rangeBearingMapResidual(known.prior, known.P, known.z, known.R, known.landmark, Eigen::Vector3d::Zero()));
  const auto post = updateRangeBearingBelief(known.prior, known.P, known.z, known.R, known.landmark, IteratedUpdateOptions{10, 1e-6, 10});
  ASSERT_TRUE(post);
  EXPECT_TRUE(post->pose.isFinite() && post->covariance.allFinite());
  EXPECT_NEAR(post->pose.theta, known.prior.theta, 1e-12);
  EXPECT_TRUE(std::isinf(post->map_cost));
  EXPECT_THROW(updateRangeBearingBelief(p.prior, p.P, p.z, p.R, p.landmark, IteratedUpdateOptions{0, 1e-6, 10}), Error);
  EXPECT_THROW(updateRangeBearingBelief(p.prior, p.P, p.z, p.R, p.landmark, IteratedUpdateOptions{3, -1.0, 10}), Error);
  EXPECT_THROW(updateRangeBearingBelief(p.prior, p.P, p.z, p.R, p.landmark, IteratedUpdateOptions{3, 1e-6, -1}), Error);
}

}  // namespace
}  // namespace stereoloc
