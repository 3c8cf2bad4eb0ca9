// Wheels whose calibration drifts (UnmodelledNoise::wheel_scale_drift, wheel_base_drift): the
// calibrating EKF and sliding window let their wheel estimate take a random walk with the travel
// (exactly its variance where nothing observes the wheels); on a drive whose simulated wheels do
// drift, the EKF follows them within its stated sigmas where the constant-calibration model locks
// onto an old value; the report measures an estimate against the walked prior.
#include <gtest/gtest.h>

#include <cmath>
#include <string>
#include <vector>

#include "solvers/calibrated_models.h"
#include "solvers/ekf.h"
#include "solvers/sliding_window_smoother.h"
#include "src/sim/error_profile.h"
#include "src/sim/simulator.h"
#include "test_util.h"

namespace stereoloc {
namespace {

const Eigen::Matrix3d kDriftStartCovariance = Eigen::Vector3d(10.0, 10.0, deg2rad(2.0)).cwiseAbs2().asDiagonal();

UnmodelledNoise drifting(double scale, double base) {
  UnmodelledNoise n;
  n.wheel_scale_drift = scale;
  n.wheel_base_drift = base;
  return n;
}

// Odometry alone: nothing observes the wheels, so their variance is the prior's plus the walk.
SyntheticProblem blindDrive() {
  SyntheticProblemOptions o;
  o.steps = 601;
  o.max_observations = 0;
  return makeRandomWalkProblem(o, 3);
}

Eigen::Vector3d walkOver(const std::vector<Step>& steps, long first, long last, const UnmodelledNoise& noise,
                         double wheel_base_mm) {
  Eigen::Vector3d v = Eigen::Vector3d::Zero();
  for (const Step& s : steps)
    if (s.step >= first && s.step <= last) v += wheelDriftVariance(noise, s.d_left, s.d_right, wheel_base_mm);
  return v;
}

TEST(WheelDrift, DriftVarianceGrowsWithEachWheelsTravel) {
  const Eigen::Vector3d v = wheelDriftVariance(drifting(0.002, 0.01), 30.0, -10.0, 75.0);
  EXPECT_NEAR(v[0], 0.002 * 0.002 * 0.030, 1e-18);
  EXPECT_NEAR(v[1], 0.002 * 0.002 * 0.010, 1e-18);
  EXPECT_NEAR(v[2], 0.75 * 0.75 * 0.020, 1e-15);  // (0.01 x 75 mm)^2 per m of the mean travel
  EXPECT_EQ(wheelDriftVariance(UnmodelledNoise(), 30.0, -10.0, 75.0), Eigen::Vector3d::Zero());
}

TEST(WheelDrift, TheFiltersWheelVarianceIsThePriorsPlusTheWalk) {
  const SyntheticProblem p = blindDrive();
  for (const bool consider : {false, true}) {
    EkfConfig c;
    c.init = knownBelief(p.truth.front(), kDriftStartCovariance);
    c.calibration = SelfCalibrationConfig::parse("odometry");
    c.calibration.consider = consider;
    c.observation_model.unmodelled = drifting(0.002, 0.01);
    Ekf ekf(p.map, p.odometry, c);
    for (const Step& s : p.steps) ekf.process(s);
    const Eigen::Vector3d prior = wheelPriorSigma(c.calibration, p.odometry.wheel_base_mm).cwiseAbs2();
    const Eigen::Vector3d expected =
        prior + walkOver(p.steps, 1, p.steps.back().step, c.observation_model.unmodelled, p.odometry.wheel_base_mm);
    const Eigen::Matrix3d got = ekf.calibration()->wheels_covariance;
    for (int i = 0; i < 3; ++i) EXPECT_NEAR(got(i, i), expected[i], 1e-12 * expected[i]) << i << " consider " << consider;
    EXPECT_GT(expected[0], 1.5 * prior[0]);  // the walk is not negligible here
    EXPECT_LT((ekf.calibration()->wheels_walk_variance - (expected - prior)).cwiseAbs().maxCoeff(), 1e-12 * expected[2]);
  }
}

TEST(WheelDrift, TheWindowsMarginalPriorWalksOverTheMarginalisedTravel) {
  // Keyframes every 10 steps, W = 4: after step 600 the window holds 570..600; the prior has
  // walked over the travel of steps 1..570, and the window's one block is constant from there.
  const SyntheticProblem p = blindDrive();
  SlidingWindowConfig c;
  c.window = 4;
  c.keyframe_max_steps = 10;
  c.init = knownBelief(p.truth.front(), kDriftStartCovariance);
  c.calibration = SelfCalibrationConfig::parse("odometry");
  c.observation_model.unmodelled = drifting(0.002, 0.01);
  SlidingWindowSmoother win(p.map, p.odometry, c);
  for (const Step& s : p.steps) win.process(s);
  ASSERT_EQ(win.windowSize(), 4);
  ASSERT_EQ(win.stats().marginalisations, 57);
  const Eigen::Vector3d prior = wheelPriorSigma(c.calibration, p.odometry.wheel_base_mm).cwiseAbs2();
  const Eigen::Vector3d expected =
      prior + walkOver(p.steps, 1, 570, c.observation_model.unmodelled, p.odometry.wheel_base_mm);
  const Eigen::Matrix3d got = win.calibration()->wheels_covariance;
  for (int i = 0; i < 3; ++i) EXPECT_NEAR(got(i, i), expected[i], 1e-8 * expected[i]) << i;
  // What the run walked, for the report: the whole run's travel.
  const Eigen::Vector3d walked =
      walkOver(p.steps, 1, p.steps.back().step, c.observation_model.unmodelled, p.odometry.wheel_base_mm);
  EXPECT_LT((win.calibration()->wheels_walk_variance - walked).cwiseAbs().maxCoeff(), 1e-12 * walked[2]);
  // Without the drift, the prior's variance stays.
  c.observation_model.unmodelled = UnmodelledNoise();
  SlidingWindowSmoother fixed(p.map, p.odometry, c);
  for (const Step& s : p.steps) fixed.process(s);
  for (int i = 0; i < 3; ++i) EXPECT_NEAR(fixed.calibration()->wheels_covariance(i, i), prior[i], 1e-8 * prior[i]) << i;
}

// The final wheel scales of a simulated drive against the drawn radii with their walk at the last
// step, in the estimate's sigmas.
std::vector<double> finalWheelScaleZ(const SimulationTrace& trace, const CalibrationEstimate& e) {
  const DrawnErrors& t = trace.errors;
  const double truth[2] = {1 + t.wheel_radius_rel[0] + t.wheel_radius_drift_left.back(),
                           1 + t.wheel_radius_rel[1] + t.wheel_radius_drift_right.back()};
  std::vector<double> z;
  for (int i = 0; i < 2; ++i) z.push_back((e.wheels[i] - truth[i]) / std::sqrt(e.wheels_covariance(i, i)));
  return z;
}

// A drive whose only errors are wheels that walk 0.3 % per sqrt(m) (about 3 % over its 120 m),
// every landmark in view, three seeds: the EKF that knows the drift ends within 3 sigma of the
// walked wheels (2.3 at worst); the one that takes them as constant 38 sigma off.
TEST(WheelDrift, TheCalibratingFilterFollowsWheelsThatDrift) {
  SimulationConfig sc;
  sc.landmarks = LandmarkSet::All;
  sc.profile.name = "drifting wheels";
  sc.profile.wheel_radius_rel_sigma = 0.005;
  sc.profile.wheel_radius_drift = 0.003;
  sc.scenario.steps = 6000;
  double worst_locked = 0, worst_drifting = 0;
  for (const uint64_t seed : {1, 2, 3}) {
    SimulationTrace trace;
    const Dataset d = simulate("random-walk", 0, sc, seed, &trace);
    for (const bool drift : {false, true}) {
      EkfConfig c;
      c.init = knownBelief(*d.groundtruth.front(), kDriftStartCovariance);
      c.calibration = SelfCalibrationConfig::parse("odometry");
      c.observation_model = {ObservationModel::PixelColumns, d.rig};
      if (drift) c.observation_model.unmodelled = drifting(0.003, 0.0);
      Ekf ekf(d.map, d.odometry, c);
      for (const Step& s : d.steps) ekf.process(s);
      for (const double z : finalWheelScaleZ(trace, *ekf.calibration()))
        (drift ? worst_drifting : worst_locked) = std::max(drift ? worst_drifting : worst_locked, std::fabs(z));
    }
  }
  ::testing::Test::RecordProperty("worst_z_drifting", std::to_string(worst_drifting));
  ::testing::Test::RecordProperty("worst_z_constant", std::to_string(worst_locked));
  EXPECT_LT(worst_drifting, 3.0);
  EXPECT_GT(worst_locked, 5.0);
}

// An estimate that walked away from the nominal wheels is measured against the prior widened
// by the walk, not flagged as a failed solve.
TEST(WheelDrift, TheWalkWidensThePriorAnEstimateIsMeasuredAgainst) {
  const SelfCalibrationConfig c = SelfCalibrationConfig::parse("odometry");  // wheel scale sigma 0.01
  CalibrationEstimate e;
  e.odometry = true;
  e.wheels = Eigen::Vector3d(1.06, 1.0, 75.0);
  EXPECT_NEAR(furthestFromPrior(e, c, 75.0).sigmas, 6.0, 1e-9);
  e.wheels_walk_variance = Eigen::Vector3d(0.0003, 0.0003, 0.0);
  const PriorDistance d = furthestFromPrior(e, c, 75.0);
  EXPECT_EQ(d.parameter, "wheel_scale_left");
  EXPECT_NEAR(d.sigmas, 3.0, 1e-9);  // 0.06 / sqrt(0.01^2 + 0.0003)
}

}  // namespace
}  // namespace stereoloc
