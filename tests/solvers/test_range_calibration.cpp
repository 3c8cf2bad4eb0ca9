// The range block of the self-calibration (solvers/self_calibration.h): a range-bearing sensor
// whose range factor varies across its field of view and whose bearings are offset, as MR.CLAM's
// barcode camera. The batch and the window recover a planted sensor model from the data alone,
// a window as long as the data is the batch, the window's gate sees the sightings through the
// calibration, and the EKF estimates it as states beside the pose (or considers it).
#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "factors/range_bearing_calibration_factor.h"
#include "solvers/batch_smoother.h"
#include "solvers/calibrated_models.h"
#include "solvers/ekf.h"
#include "solvers/self_calibration.h"
#include "solvers/sliding_window_smoother.h"
#include "src/core/estimator.h"
#include "src/core/measurement_model.h"
#include "src/core/numeric_diff.h"
#include "src/core/stereo_rig.h"
#include "src/core/yaml_util.h"
#include "sighted_walk.h"
#include "test_util.h"

namespace stereoloc {
namespace {

const Eigen::Matrix3d kRangeStartCovariance = Eigen::Vector3d(20.0, 20.0, deg2rad(2.0)).cwiseAbs2().asDiagonal();
// A sensor that reads 3 % long on its axis, 7 % short 0.5 rad off it, and 0.6 degrees to the left.
const Eigen::Vector4d kPlanted(0.03, 0.02, -0.4, deg2rad(0.6));

// A random walk seen through that sensor: each sighting's bearing offset, its range scaled at
// the bearing it reports.
SyntheticProblem plantedSensorWalk(int steps, uint64_t seed) {
  SyntheticProblemOptions o = test::sightedWalkOptions(steps);
  o.half_fov = 0.6;
  o.sigma_bearing = deg2rad(0.5);
  SyntheticProblem p = makeRandomWalkProblem(o, seed);
  for (Step& s : p.steps)
    for (Observation& obs : s.observations) {
      obs.bearing = wrapAngle(obs.bearing + kPlanted[3]);
      const double b = obs.bearing;
      obs.range *= 1.0 + kPlanted[0] + kPlanted[1] * b + kPlanted[2] * b * b;
    }
  return p;
}

std::vector<Estimate> run(Estimator& estimator, const SyntheticProblem& p) {
  for (const Step& s : p.steps) estimator.process(s);
  return estimator.finish();
}

double rmse(const std::vector<Estimate>& e, const std::vector<Pose2>& truth) {
  double sum = 0;
  for (const Estimate& x : e)
    sum += (x.pose.translation() - truth[static_cast<size_t>(x.step)].translation()).squaredNorm();
  return std::sqrt(sum / static_cast<double>(e.size()));
}

double meanNees(const std::vector<Estimate>& e, const std::vector<Pose2>& truth) {
  double sum = 0;
  for (const Estimate& x : e) {
    const Eigen::Vector3d d = minus(x.pose, truth[static_cast<size_t>(x.step)]);
    sum += d.dot(x.covariance.ldlt().solve(d));
  }
  return sum / static_cast<double>(e.size());
}

void expectPlantedWithin3Sigma(const CalibrationEstimate& c, const char* who) {
  ASSERT_TRUE(c.range) << who;
  for (int i = 0; i < 4; ++i) {
    const double sd = std::sqrt(c.range_bearing_covariance(i, i));
    EXPECT_GT(sd, 0.0) << who << " parameter " << i;
    EXPECT_LT(std::fabs(c.range_bearing[i] - kPlanted[i]), 3.0 * sd)
        << who << " parameter " << i << ": " << c.range_bearing[i] << " +- " << sd << ", planted " << kPlanted[i];
  }
}

TEST(RangeCalibration, BatchAndWindowRecoverAPlantedSensorModelFromTheDataAlone) {
  const SyntheticProblem p = plantedSensorWalk(1500, 3);
  BatchSmootherConfig bc;
  bc.init = knownBelief(p.truth.front(), kRangeStartCovariance);
  BatchSmoother plain(p.map, p.odometry, bc);
  const double rmse_plain = rmse(run(plain, p), p.truth);

  bc.calibration = SelfCalibrationConfig::parse("range");
  BatchSmoother batch(p.map, p.odometry, bc);
  const double rmse_batch = rmse(run(batch, p), p.truth);
  expectPlantedWithin3Sigma(batch.calibration(), "batch");
  // The planted curvature is determined to a few per cent of itself.
  EXPECT_LT(std::sqrt(batch.calibration().range_bearing_covariance(2, 2)), 0.1 * std::fabs(kPlanted[2]));
  EXPECT_LT(rmse_batch, 0.5 * rmse_plain) << rmse_batch << " against " << rmse_plain;

  SlidingWindowConfig wc;
  wc.window = 20;
  wc.init = bc.init;
  wc.calibration = bc.calibration;
  SlidingWindowSmoother window(p.map, p.odometry, wc);
  const double rmse_window = rmse(run(window, p), p.truth);
  EXPECT_GT(window.stats().marginalisations, 1000);
  const std::optional<CalibrationEstimate> cw = window.calibration();
  ASSERT_TRUE(cw.has_value());
  expectPlantedWithin3Sigma(*cw, "window");
  EXPECT_LT(rmse_window, 0.5 * rmse_plain) << rmse_window << " against " << rmse_plain;
}

TEST(RangeCalibration, WindowAsLongAsTheDataIsTheBatch) {
  const SyntheticProblem p = plantedSensorWalk(150, 4);
  BatchSmootherConfig bc;
  bc.init = knownBelief(p.truth.front(), kRangeStartCovariance);
  bc.calibration = SelfCalibrationConfig::parse("odometry,range");
  bc.cut_at_reinitialisation = false;
  bc.function_tolerance = bc.parameter_tolerance = bc.gradient_tolerance = 1e-16;
  BatchSmoother b(p.map, p.odometry, bc);
  for (const Step& s : p.steps) b.process(s);
  const std::vector<Estimate> eb = b.finish();

  SlidingWindowConfig c;
  c.window = static_cast<int>(p.steps.size());
  c.keyframe_max_steps = 1;  // every step a window pose, as the batch's
  c.init = bc.init;
  c.calibration = bc.calibration;
  c.gate_enabled = false;
  c.linearisation = WindowLinearisation::Current;
  c.final_iterations = 100;
  c.function_tolerance = c.parameter_tolerance = c.gradient_tolerance = 1e-16;
  SlidingWindowSmoother win(p.map, p.odometry, c);
  for (const Step& s : p.steps) win.process(s);
  const std::vector<Estimate> ew = win.finish();
  EXPECT_EQ(win.stats().marginalisations, 0);
  ASSERT_EQ(ew.size(), eb.size());
  double pose = 0;
  for (size_t i = 0; i < ew.size(); ++i) pose = std::max(pose, minus(ew[i].pose, eb[i].pose).cwiseAbs().maxCoeff());
  EXPECT_LT(pose, 1e-6);
  const CalibrationEstimate cb = b.calibration();
  const CalibrationEstimate cw = *win.calibration();
  EXPECT_LT((cw.range_bearing - cb.range_bearing).cwiseAbs().maxCoeff(), 1e-6);
  EXPECT_LT((cw.range_bearing_covariance - cb.range_bearing_covariance).cwiseAbs().maxCoeff(),
            1e-6 * cb.range_bearing_covariance.cwiseAbs().maxCoeff());
  EXPECT_GT((cb.range_bearing - Eigen::Vector4d::Zero()).cwiseAbs().maxCoeff(), 0.01);  // moved off nominal
}

TEST(RangeCalibration, TheGateSeesTheSightingsThroughTheCalibration) {
  // A sensor 15 % long: with a 10 mm range sigma every sighting beyond a few hundred mm is far
  // outside the gate of the given model. The calibrating window tests each through its estimate
  // and then through the prior (c0 with a 10 % sigma here), fuses them and learns the scale.
  SyntheticProblem p = plantedSensorWalk(400, 5);
  for (Step& s : p.steps)
    for (Observation& obs : s.observations) {
      const double b = obs.bearing;
      obs.range *= 1.15 / (1.0 + kPlanted[0] + kPlanted[1] * b + kPlanted[2] * b * b);
    }
  SlidingWindowConfig c;
  c.window = 20;
  c.init = knownBelief(p.truth.front(), kRangeStartCovariance);
  SlidingWindowSmoother given(p.map, p.odometry, c);
  for (const Step& s : p.steps) given.process(s);
  given.finish();
  c.calibration = SelfCalibrationConfig::parse("range");
  c.calibration.range_scale_sigma = 0.1;
  SlidingWindowSmoother calibrating(p.map, p.odometry, c);
  for (const Step& s : p.steps) calibrating.process(s);
  calibrating.finish();
  EXPECT_GT(given.stats().rejected_observations, 5 * calibrating.stats().rejected_observations + 10);
  EXPECT_NEAR(calibrating.calibration()->range_bearing[0], 0.15, 0.01);
}

TEST(RangeCalibration, CalibratedObservationInvertsTheSensorModelAndCarriesItsUncertainty) {
  const Observation obs = observationFromRangeBearing(3, LandmarkType::Point, 2400.0, 0.35, 20.0, 0.01);
  const Eigen::Vector4d k(0.02, -0.01, -0.3, 0.004);
  const Eigen::Matrix4d Ck = Eigen::Vector4d(1e-4, 4e-4, 1e-2, 1e-6).asDiagonal();
  const Observation c = withRangeCalibration(obs, k, Ck);
  const double f = 1.0 + k[0] + k[1] * 0.35 + k[2] * 0.35 * 0.35;
  EXPECT_NEAR(c.range, 2400.0 / f, 1e-9);
  EXPECT_NEAR(c.bearing, 0.35 - 0.004, 1e-15);
  // R: the range row scaled by 1/f, plus J Ck J^T with J from central differences.
  const Eigen::Matrix<double, 2, 4> J = numericJacobian<2, 4>(
      [&](const Eigen::Vector4d& kk) {
        const Observation o = withRangeCalibration(obs, kk, Eigen::Matrix4d::Zero());
        return Eigen::Vector2d(o.range, o.bearing);
      },
      k);
  Eigen::Matrix2d want = obs.covariance;
  want(0, 0) /= f * f;
  want += J * Ck * J.transpose();
  EXPECT_LT((c.covariance - want).cwiseAbs().maxCoeff(), 1e-6 * want.cwiseAbs().maxCoeff());
  const Eigen::Vector4d absurd(0.0, 0.0, -20.0, 0.0);  // factor below zero at 0.35 rad
  EXPECT_NE(test::errorOf([&] { withRangeCalibration(obs, absurd, Ck); }).find("not positive"), std::string::npos);
}

TEST(RangeCalibration, FurthestFromPriorAndTheRigFileNameTheRangeBlock) {
  CalibrationEstimate e;
  e.range = true;
  e.range_bearing = Eigen::Vector4d(0.05, 0.0, -1.6, deg2rad(0.5));  // c2 at 3.2 prior sigmas
  e.range_bearing_covariance = Eigen::Vector4d(1e-6, 4e-6, 1e-4, 1e-6).asDiagonal();
  const PriorDistance far = furthestFromPrior(e, SelfCalibrationConfig::parse("range"), 75.0);
  EXPECT_EQ(far.parameter, "range_scale_c2");
  EXPECT_NEAR(far.sigmas, 3.2, 1e-12);
  test::TempDir dir("range_rig");
  e.saveAsRig(dir.file("rig.yaml"), StereoRig(), 0.0);
  const YamlReader y(dir.file("rig.yaml"));
  EXPECT_DOUBLE_EQ(y.getDouble("range_scale_c2"), -1.6);
  EXPECT_DOUBLE_EQ(y.getDouble("range_scale_c2_sigma"), 0.01);
  EXPECT_DOUBLE_EQ(y.getDouble("bearing_offset_rad"), deg2rad(0.5));
  EXPECT_FALSE(y.has("wheel_scale_left"));
}

TEST(RangeCalibration, TheEkfEstimatesOrConsidersTheRangeBlock) {
  const SyntheticProblem p = plantedSensorWalk(1500, 3);
  EkfConfig c;
  c.init = knownBelief(p.truth.front(), kRangeStartCovariance);
  Ekf plain(p.map, p.odometry, c);
  const double rmse_plain = rmse(run(plain, p), p.truth);
  c.calibration = SelfCalibrationConfig::parse("range");
  Ekf ekf(p.map, p.odometry, c);
  const double rmse_ekf = rmse(run(ekf, p), p.truth);
  const std::optional<CalibrationEstimate> e = ekf.calibration();
  ASSERT_TRUE(e.has_value());
  expectPlantedWithin3Sigma(*e, "ekf");
  EXPECT_LT(rmse_ekf, 0.5 * rmse_plain) << rmse_ekf << " against " << rmse_plain;
  // Considered: the block stays at its prior, and its uncertainty makes the covariance honest
  // where the EKF that takes the sensor as exact is far too sure of itself.
  c.calibration.consider = true;
  Ekf considering(p.map, p.odometry, c);
  const double nees_considering = meanNees(run(considering, p), p.truth);
  const double nees_plain = meanNees(plain.finish(), p.truth);
  EXPECT_LT(nees_considering, 6.0);
  EXPECT_GT(nees_plain, 3.0 * nees_considering);
}

TEST(RangeCalibration, TheListParses) {
  const SelfCalibrationConfig c = SelfCalibrationConfig::parse("odometry,range");
  EXPECT_TRUE(c.odometry);
  EXPECT_TRUE(c.range);
  EXPECT_FALSE(c.stereo);
  EXPECT_TRUE(c.any());
  EXPECT_FALSE(SelfCalibrationConfig::parse("none").any());
  EXPECT_NE(test::errorOf([] { SelfCalibrationConfig::parse("rang"); }).find("odometry, stereo, range and/or field"),
            std::string::npos);
}

}  // namespace
}  // namespace stereoloc
