// The odometry's delay estimated from the data alone (solvers/odometry_delay_profile.h): the
// profile's vertex and curvature on known costs, its failures, and the batch smoother finding a
// delay planted in a simulated random walk.
#include "solvers/odometry_delay_profile.h"

#include <gtest/gtest.h>

#include <cmath>

#include "solvers/batch_smoother.h"
#include "solvers/smoother_common.h"
#include "src/core/odometry_delay.h"
#include "sighted_walk.h"
#include "test_util.h"

namespace stereoloc {
namespace {

using test::errorOf;

TEST(OdometryDelayProfile, AQuadraticCostGivesItsVertexAndCurvature) {
  int calls = 0;
  auto cost = [&](double d) {
    ++calls;
    return 40.0 + 0.5 * std::pow((d - 0.23) / 0.01, 2);
  };
  OdometryDelaySearch search;
  search.prior_sigma_s = 0;
  const OdometryDelayEstimate e = profileOdometryDelay(cost, search);
  EXPECT_NEAR(e.delay_s, 0.23, 1e-9);
  EXPECT_NEAR(e.sigma_s, 0.01, 1e-9);
  // The grid (16 delays) and the two half steps around the least; each evaluated once.
  EXPECT_EQ(calls, 18);
  ASSERT_EQ(e.profile.size(), 18u);
  for (size_t i = 1; i < e.profile.size(); ++i) EXPECT_LT(e.profile[i - 1].first, e.profile[i].first);
  // With the prior, the product of the two Gaussians.
  search.prior_sigma_s = 0.02;
  const OdometryDelayEstimate p = profileOdometryDelay(cost, search);
  const double w = 1 / (0.01 * 0.01) + 1 / (0.02 * 0.02);
  EXPECT_NEAR(p.delay_s, 0.23 / (0.01 * 0.01) / w, 1e-9);
  EXPECT_NEAR(p.sigma_s, 1 / std::sqrt(w), 1e-9);
}

TEST(OdometryDelayProfile, NoInteriorMinimumOrAFlatCostIsAnErrorAndFarCostsDoNotEnter) {
  OdometryDelaySearch search;
  search.prior_sigma_s = 0;
  EXPECT_NE(errorOf([&] { profileOdometryDelay([](double d) { return std::pow(d - 1.4, 2); }, search); })
                .find("edge of the search"),
            std::string::npos);
  // A robot at constant speed: the delay changes nothing.
  EXPECT_NE(errorOf([&] { profileOdometryDelay([](double) { return 1234.0; }, search); }).find("do not determine"),
            std::string::npos);
  // Least over a wide flat stretch: no curvature to take a sigma from.
  auto flat_bottom = [](double d) { return std::fabs(d - 0.3) < 0.3 ? 1.0 : 2.0; };
  EXPECT_NE(errorOf([&] { profileOdometryDelay(flat_bottom, search); }).find("not convex"), std::string::npos);
  // Far from the least the batch may settle in another basin: such costs do not enter the
  // estimate (here at 0.1 s, two grid steps from the least).
  auto wild = [](double d) {
    const double c = 0.5 * std::pow((d - 0.26) / 0.02, 2);
    return std::fabs(d - 0.1) < 0.06 ? 1e5 : c;
  };
  const OdometryDelayEstimate w = profileOdometryDelay(wild, search);
  EXPECT_NEAR(w.delay_s, 0.26, 1e-9);
  EXPECT_NEAR(w.profile_sigma_s, 0.02, 1e-9);
  EXPECT_NE(errorOf([&] { profileOdometryDelay([](double) { return std::nan(""); }, search); }).find("not finite"),
            std::string::npos);
  search.step_s = 1.0;
  EXPECT_NE(errorOf([&] { profileOdometryDelay([](double d) { return d * d; }, search); }).find("step_s"),
            std::string::npos);
}

TEST(OdometryDelayProfile, TheBatchFindsADelayPlantedInARandomWalk) {
  // The readings lead the motion by 0.27 s (2.7 steps of 0.1 s): the odometry runs 0.27 s late.
  const double planted = 0.27;
  const SyntheticProblem p = test::lateOdometryWalk(600, 4, planted);
  const std::vector<Step>& late = p.steps;
  BatchSmootherConfig c;
  c.init = knownBelief(p.truth.front(), Eigen::Vector3d(20.0, 20.0, 0.03).cwiseAbs2().asDiagonal());
  OdometryDelaySearch search;
  search.min_s = -0.2;
  search.max_s = 0.7;
  const OdometryDelayEstimate e = estimateOdometryDelay(p.map, p.odometry, c, late, search);
  // A walk that turns at every step pins the profile down far below a step; what is left is the
  // steps' resolution (0.1 s / sqrt(12)), and the error is of its size, not of the profile's.
  EXPECT_GT(e.profile_sigma_s, 0.0);
  EXPECT_LT(e.profile_sigma_s, 0.2 * e.resolution_s);
  EXPECT_NEAR(e.resolution_s, 0.1 / std::sqrt(12.0), 1e-9);
  EXPECT_NEAR(e.sigma_s, std::hypot(e.profile_sigma_s, e.resolution_s), 1e-12);
  EXPECT_LT(std::fabs(e.delay_s - planted), 2 * e.sigma_s) << e.delay_s << " +- " << e.sigma_s;
  // Re-timed by the estimate, the batch is more accurate than on the late odometry.
  auto rmse = [&](const std::vector<Step>& steps) {
    BatchSmoother batch(p.map, p.odometry, c);
    for (const Step& s : steps) batch.process(s);
    double sum = 0;
    const std::vector<Estimate> est = batch.finish();
    for (const Estimate& x : est)
      sum += (x.pose.translation() - p.truth[static_cast<size_t>(x.step)].translation()).squaredNorm();
    return std::sqrt(sum / static_cast<double>(est.size()));
  };
  const double as_read = rmse(late), retimed = rmse(delayOdometry(late, e.delay_s));
  EXPECT_LT(retimed, 0.8 * as_read) << retimed << " against " << as_read;
}

}  // namespace
}  // namespace stereoloc
