// The method registry and the frontend source through the library API.
#include <gtest/gtest.h>

#include <Eigen/Eigenvalues>

#include <cmath>

#include "src/core/odometry_delay.h"
#include "src/pipeline/frontend_source.h"
#include "src/pipeline/methods.h"
#include "src/pipeline/usage_error.h"
#include "src/sim/simulator.h"
#include "sighted_walk.h"
#include "test_util.h"

namespace stereoloc {
namespace {

Dataset circle(int steps) {
  SimulationConfig cfg;
  cfg.scenario.steps = steps;
  return simulate("circle", 0, cfg, 7);
}

TEST(Methods, SpecSplitsNameAndInit) {
  EXPECT_EQ(parseMethodSpec("ekf", InitMode::Known), std::make_pair(std::string("ekf"), InitMode::Known));
  EXPECT_EQ(parseMethodSpec("pf:global", InitMode::Known), std::make_pair(std::string("pf"), InitMode::Global));
  EXPECT_THROW(parseMethodSpec("kalman", InitMode::Known), UsageError);
  EXPECT_THROW(parseMethodSpec("ekf:somewhere", InitMode::Known), UsageError);
}

TEST(Methods, EveryTrackerGivesOneEstimatePerStepAndIsReproducible) {
  const Dataset d = circle(25);
  MethodOptions o;
  o.particles = 300;
  for (const std::string spec : {"ekf", "iekf", "pf", "window", "batch", "deadreckoning"}) {
    const MethodRun a = runMethod(spec, d, 3, o), b = runMethod(spec, d, 3, o);
    ASSERT_EQ(a.estimates.size(), d.steps.size()) << spec;
    EXPECT_EQ(a.method, spec);
    for (size_t k = 0; k < a.estimates.size(); ++k) {
      EXPECT_EQ(a.estimates[k].pose.x, b.estimates[k].pose.x) << spec << " step " << k;
      EXPECT_EQ(a.estimates[k].pose.theta, b.estimates[k].pose.theta) << spec << " step " << k;
    }
  }
}

TEST(Methods, TheSmoothersAndTheFiltersSelfCalibrate) {
  const Dataset d = circle(25);
  for (const std::string spec : {"ekf:calib", "ekf:known:calib", "window:calib", "batch:calib", "pf:calib"}) {
    const MethodRun run = runMethod(spec, d, 3, MethodOptions());
    ASSERT_EQ(run.estimates.size(), d.steps.size()) << spec;
    ASSERT_TRUE(run.calibration) << spec;
    EXPECT_TRUE(run.calibration->odometry && run.calibration->stereo) << spec;
  }
  EXPECT_FALSE(runMethod("ekf", d, 3, MethodOptions()).calibration);
  for (const std::string spec : {"iekf:calib", "pf:calib-field", "fix2:calib", "deadreckoning:calib"})
    EXPECT_THROW(parseMethodSpec(spec, InitMode::Known), UsageError) << spec;
  MethodOptions o;
  o.calibration = SelfCalibrationConfig::parse("odometry");
  EXPECT_THROW(runMethod("iekf", d, 3, o), UsageError);
  EXPECT_TRUE(runMethod("ekf", d, 3, o).calibration);
  o.particles = 300;
  const MethodRun pf = runMethod("pf", d, 3, o);
  ASSERT_TRUE(pf.calibration);
  EXPECT_TRUE(pf.calibration->odometry && !pf.calibration->stereo);
  // The particle filter's blocks are the odometry and the stereo head.
  o.calibration = SelfCalibrationConfig::parse("odometry,range");
  EXPECT_THROW(runMethod("pf", d, 3, o), UsageError);
}

TEST(Methods, TheEkfConsidersItsCalibration) {
  // ekf:consider: the calibrating EKF's blocks, considered (nothing estimated, so no
  // calibration estimate); its own estimates, not ekf:calib's; the same start draws as ekf.
  const Dataset d = circle(25);
  const MethodRun considered = runMethod("ekf:consider", d, 3, MethodOptions()),
                  known = runMethod("ekf:known:consider", d, 3, MethodOptions()),
                  estimated = runMethod("ekf:calib", d, 3, MethodOptions());
  ASSERT_EQ(considered.estimates.size(), d.steps.size());
  EXPECT_FALSE(considered.calibration);
  EXPECT_EQ(considered.estimates.back().pose.x, known.estimates.back().pose.x);
  EXPECT_NE(considered.estimates.back().pose.x, estimated.estimates.back().pose.x);
  EXPECT_EQ(withoutCalibrationSuffix("ekf:random:consider"), "ekf:random");
  EXPECT_EQ(parseMethodSpec("ekf:random:consider", InitMode::Known).second, InitMode::Random);
  for (const std::string spec : {"batch:consider", "window:consider", "iekf:consider", "pf:consider"})
    EXPECT_THROW(parseMethodSpec(spec, InitMode::Known), UsageError) << spec;
  MethodOptions o;
  o.calibration = SelfCalibrationConfig::parse("odometry");
  o.calibration.consider = true;
  EXPECT_THROW(runMethod("window", d, 3, o), UsageError);
  EXPECT_THROW(runMethod("batch", d, 3, o), UsageError);
}

TEST(Methods, TheFixesConsiderTheStereoCalibration) {
  // fix2:consider: fix2's poses with covariances that hold the stereo block's priors.
  const Dataset d = circle(200);
  const MethodRun plain = runMethod("fix2", d, 3, MethodOptions()), considered = runMethod("fix2:consider", d, 3, MethodOptions());
  ASSERT_GE(plain.estimates.size(), 5u);
  ASSERT_EQ(considered.estimates.size(), plain.estimates.size());
  EXPECT_FALSE(considered.calibration);
  for (size_t k = 0; k < plain.estimates.size(); ++k) {
    EXPECT_EQ(considered.estimates[k].pose.x, plain.estimates[k].pose.x);
    const Eigen::Matrix3d added = considered.estimates[k].covariance - plain.estimates[k].covariance;
    EXPECT_GT(added.trace(), 0.0) << "step " << k;
    EXPECT_GE(Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(added).eigenvalues().minCoeff(), -1e-9 * added.trace());
  }
  EXPECT_EQ(parseMethodSpec("fix1:consider", InitMode::Known).first, "fix1");
  MethodOptions o;
  o.calibration = SelfCalibrationConfig::parse("stereo");
  o.calibration.consider = true;
  EXPECT_EQ(runMethod("fix2", d, 3, o).estimates.size(), plain.estimates.size());
  o.calibration = SelfCalibrationConfig::parse("odometry,stereo");
  o.calibration.consider = true;
  EXPECT_THROW(runMethod("fix2", d, 3, o), UsageError);  // a fix has no odometry to consider
  o.calibration = SelfCalibrationConfig::parse("stereo");
  EXPECT_THROW(runMethod("fix2", d, 3, o), UsageError);  // estimated: fixes do not self-calibrate
}

// A random walk whose odometry runs 0.25 s late (the readings lead the motion).
Dataset lateOdometryWalk() {
  const SyntheticProblem p = test::lateOdometryWalk(400, 5, 0.25);
  Dataset d;
  d.name = "late odometry walk";
  d.map = p.map;
  d.odometry = p.odometry;
  d.steps = p.steps;
  for (const Pose2& t : p.truth) d.groundtruth.push_back(t);
  d.initial_pose = p.truth.front();
  return d;
}

double positionRmse(const MethodRun& run, const Dataset& d) {
  double sum = 0;
  for (const Estimate& e : run.estimates)
    sum += (e.pose.translation() - d.groundtruth[static_cast<size_t>(e.step)]->translation()).squaredNorm();
  return std::sqrt(sum / static_cast<double>(run.estimates.size()));
}

TEST(Methods, AnOdometryDelayGivenOrFittedByTheBatchRetimesTheStepsOfAnyMethod) {
  const Dataset d = lateOdometryWalk();
  MethodOptions o;
  o.odometry_delay = OdometryDelayMode::Given;
  o.given_odometry_delay_s = 0.25;
  Dataset retimed = d;
  retimed.steps = delayOdometry(d.steps, 0.25);
  const MethodRun given = runMethod("ekf", d, 3, o), on_retimed = runMethod("ekf", retimed, 3, MethodOptions());
  ASSERT_EQ(given.estimates.size(), on_retimed.estimates.size());
  for (size_t k = 0; k < given.estimates.size(); ++k) EXPECT_EQ(given.estimates[k].pose.x, on_retimed.estimates[k].pose.x);
  EXPECT_FALSE(given.odometry_delay);

  o.odometry_delay = OdometryDelayMode::Fit;
  o.odometry_delay_search.min_s = 0.0;
  o.odometry_delay_search.max_s = 0.5;
  const MethodRun fitted = runMethod("window", d, 3, o);
  ASSERT_TRUE(fitted.odometry_delay);
  EXPECT_NEAR(fitted.odometry_delay->delay_s, 0.25, 0.01);
  EXPECT_LT(positionRmse(fitted, d), 0.8 * positionRmse(runMethod("window", d, 3, MethodOptions()), d));
  // An unknown method is refused before any solve; a delay the search cannot bracket is an error.
  EXPECT_THROW(runMethod("kalman", d, 3, o), UsageError);
  o.odometry_delay_search.min_s = 0.3;
  o.odometry_delay_search.max_s = 0.8;
  EXPECT_NE(test::errorOf([&] { runMethod("batch", d, 3, o); }).find("edge of the search"), std::string::npos);
}

TEST(Methods, FixesCountAttemptedAndFixedSteps) {
  const MethodRun run = runMethod("fix2", circle(25), 1, MethodOptions());
  EXPECT_GT(run.attempted_steps, 0);
  EXPECT_LE(run.fixed_steps, run.attempted_steps);
  EXPECT_EQ(static_cast<long>(run.estimates.size()), run.fixed_steps);
}

TEST(Methods, KnownStartWithoutTruthIsAUsageError) {
  Dataset d = circle(5);
  d.initial_pose.reset();
  d.groundtruth.clear();
  EXPECT_THROW(runMethod("ekf", d, 1, MethodOptions()), UsageError);
  EXPECT_NO_THROW(runMethod("ekf:global", d, 1, MethodOptions()));
}

TEST(FrontendSource, NamesRoundTripAndUnknownNamesAreUsageErrors) {
  for (FrontendMode m : {FrontendMode::Pixels, FrontendMode::Images}) EXPECT_EQ(frontendModeFromString(toString(m)), m);
  for (FrontendLandmarks s : {FrontendLandmarks::All, FrontendLandmarks::GoalCorners})
    EXPECT_EQ(frontendLandmarksFromString(toString(s)), s);
  EXPECT_THROW(frontendModeFromString("lidar"), UsageError);
  EXPECT_THROW(imageFrontendOptions("some", ""), UsageError);
  EXPECT_EQ(imageFrontendOptions("goal_corners", "").landmarks, FrontendLandmarks::GoalCorners);
}

TEST(FrontendSource, SummaryNamesPairsObservationsAndDrops) {
  ImageFrontendStats st;
  for (int pair = 0; pair < 4; ++pair) {
    ImageFrontendStats one;
    one.pairs = 1;
    one.observations = pair < 2 ? 3 : 2;   // 10 in all
    one.identified = pair < 2 ? 2 : 1;     // 6
    one.dropped = pair % 2;                // 2
    one.ms_frontend = 2;                   // 8 ms
    st.merge(one);
  }
  EXPECT_EQ(frontendSummary(st), "frontend on 4 image pairs: 10 observations (6 goal corners), 2 unidentified dropped, 2.00 ms/pair");
  st.dropped = 0;
  EXPECT_EQ(frontendSummary(st), "frontend on 4 image pairs: 10 observations (6 goal corners), 2.00 ms/pair");
}

TEST(UsageErrorList, SplitDropsEmptyItems) {
  EXPECT_EQ(splitCommaList("a,b,,c,"), (std::vector<std::string>{"a", "b", "c"}));
  EXPECT_TRUE(splitCommaList("").empty());
}

TEST(ApplyErrorProfile, TheProfilesSigmasBecomeTheNoiseModelAndPriors) {
  MethodOptions ideal;
  applyErrorProfile(ErrorProfile::ideal(), 277.0, ideal);
  EXPECT_TRUE(ideal.noise.isZero());
  EXPECT_EQ(ideal.calibration.focal_scale_sigma, SelfCalibrationConfig().focal_scale_sigma);

  const ErrorProfile p = ErrorProfile::realistic();
  MethodOptions o;
  applyErrorProfile(p, 277.0, o);
  EXPECT_EQ(o.noise.k1_sigma, p.k1_estimate_sigma);
  EXPECT_EQ(o.noise.pitch_sigma_rad, p.pitch_sigma_rad);
  // 2 % of the steps, one wheel, 10-30 %: sqrt(0.01 * 0.13 / 3).
  EXPECT_NEAR(o.noise.slip_rel_sigma, std::sqrt(0.01 * 0.13 / 3.0), 1e-12);
  EXPECT_EQ(o.calibration.wheel_base_rel_sigma, p.wheel_base_rel_sigma);
  EXPECT_EQ(o.calibration.focal_scale_sigma, p.focal_rel_sigma);
  const double rot = 277.0 * p.relative_rotation_sigma_rad;
  EXPECT_NEAR(o.calibration.disparity_offset_sigma_px, std::sqrt(2.0 + rot * rot), 1e-12);
  o.calibration.validate();
  // What the calibration does not estimate on images: the right camera's rotation and the
  // marking features' disparity error on the rows it and the principal points misalign.
  EXPECT_EQ(o.noise.relative_rotation_sigma_rad, p.relative_rotation_sigma_rad);
  EXPECT_NEAR(o.noise.marking_disparity_sigma_px, 1.63, 0.01);
  // X-intersections are located on both images: they do not slide.
  EXPECT_EQ(o.noise.intersection_disparity_sigma_px, 0.0);
  // The misalignment itself (the row block's prior) and what the slide model leaves.
  EXPECT_NEAR(o.noise.row_offset_sigma_px, 1.49, 0.01);
  // Measured at the profile's 1.49 px of misalignment, they scale with it.
  const double row = o.noise.row_offset_sigma_px / 1.49;
  EXPECT_NEAR(o.noise.marking_slide_residual_sigma_px, 0.185 * row, 1e-12);
  EXPECT_NEAR(o.noise.marking_slide_residual_per_gain_px, 0.318 * row, 1e-12);
  EXPECT_NEAR(o.noise.marking_feature_offset_sigma_px, 0.583 * row, 1e-12);
  EXPECT_EQ(o.noise.intersection_slide_residual_sigma_px, 0.0);
  EXPECT_EQ(o.noise.intersection_feature_offset_sigma_px, 0.0);
  // The frontend's repeating column errors do not depend on the misalignment.
  EXPECT_EQ(o.noise.goal_feature_column_sigma_px, 0.12);
  EXPECT_EQ(o.noise.marking_feature_column_sigma_px, 0.19);
  EXPECT_EQ(o.noise.intersection_feature_column_sigma_px, 0.0);
  ErrorProfile aligned = p;  // no principal-point or rotation error: rows aligned
  aligned.principal_sigma_px = 0.0;
  aligned.relative_rotation_sigma_rad = 0.0;
  MethodOptions a;
  applyErrorProfile(aligned, 277.0, a);
  EXPECT_EQ(a.noise.marking_disparity_sigma_px, 0.0);
  EXPECT_EQ(a.noise.row_offset_sigma_px, 0.0);
  EXPECT_EQ(a.noise.marking_slide_residual_sigma_px, 0.0);
  EXPECT_EQ(a.noise.marking_slide_residual_per_gain_px, 0.0);
  EXPECT_EQ(a.noise.marking_feature_offset_sigma_px, 0.0);
}

}  // namespace
}  // namespace stereoloc
