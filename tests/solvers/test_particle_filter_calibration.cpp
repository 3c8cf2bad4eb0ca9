// The self-calibrating particle filter (solvers/particle_filter.h, "Self-calibration"): its
// column model is the smoothers' and the EKF's (factors/stereo_pixel_calibration_factor.h) with
// its pose Jacobian against central differences; on a world whose given calibration is wrong in
// the ways its blocks model it recovers the calibration within its spread and is consistent where
// the filter on the given calibration is not; lost, it re-anchors on a fix that agrees and is
// re-drawn by a kidnap; a saved state replays bit for bit; settings it cannot serve are refused.
#include <gtest/gtest.h>

#include <cmath>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "factors/stereo_pixel_calibration_factor.h"
#include "solvers/calibrated_models.h"
#include "solvers/particle_filter.h"
#include "src/core/angles.h"
#include "src/core/error.h"
#include "src/core/numeric_diff.h"
#include "src/core/odometry_model.h"
#include "src/sim/simulator.h"
#include "planted_error_world.h"
#include "test_util.h"

namespace stereoloc {
namespace {

using test::meanNees;
using test::plantedErrorWorld;

ParticleFilterConfig pfKnownStart(const Dataset& d) { return test::knownStartConfig<ParticleFilterConfig>(d); }

ParticleFilterConfig calibratingPf(const Dataset& d, const std::string& blocks) {
  return test::calibratingConfig<ParticleFilterConfig>(d, blocks);
}

std::vector<Estimate> runPf(const Dataset& d, const ParticleFilterConfig& c,
                          std::optional<CalibrationEstimate>* calibration = nullptr) {
  ParticleFilter pf(d.map, d.odometry, c, 7);
  for (const Step& s : d.steps) pf.process(s);
  if (calibration) *calibration = pf.calibration();
  return pf.finish();
}

TEST(ParticleFilterCalibration, ColumnsAreThePixelFactorsAndTheirPoseJacobianMatchesCentralDifferences) {
  const StereoRig rig;
  const Eigen::Vector3d landmark(1300.0, 650.0, 0.0);
  const double pan = deg2rad(5.0);
  CalibrationEstimate::StereoVector q;
  q << deg2rad(0.6), 1.012, -1.5, 0.4, 0.004, -0.003;
  const CalibratedColumns columns(rig, landmark, pan);
  for (const Pose2& pose : {Pose2(400.0, 300.0, deg2rad(20.0)), Pose2(-200.0, 500.0, deg2rad(-10.0))}) {
    // The factor's predicted pixels (residual against zero pixels, identity covariance).
    std::unique_ptr<ceres::CostFunction> f(StereoPixelCalibrationFactor::Create(
        rig, landmark, StereoPixels{}, pan, Eigen::Matrix4d::Identity(), PixelResiduals::All));
    const double x[3] = {pose.x, pose.y, pose.theta};
    const double* blocks[2] = {x, q.data()};
    Eigen::Vector4d px;
    ASSERT_TRUE(f->Evaluate(blocks, px.data(), nullptr));
    Eigen::Vector2d u;
    Eigen::Matrix<double, 2, 3> J;
    ASSERT_TRUE(columns(q, pose.x, pose.y, std::cos(pose.theta), std::sin(pose.theta), &u, &J));
    EXPECT_NEAR(u(0), px(0), 1e-9);
    EXPECT_NEAR(u(1), px(2), 1e-9);
    const auto at = [&](const Eigen::Vector3d& p) {
      Eigen::Vector2d out;
      EXPECT_TRUE(columns(q, p.x(), p.y(), std::cos(p.z()), std::sin(p.z()), &out, nullptr));
      return out;
    };
    const Eigen::Matrix<double, 2, 3> numeric = numericJacobian<2, 3>(at, Eigen::Vector3d(pose.x, pose.y, pose.theta));
    EXPECT_TRUE(test::jacobianMatches(J, numeric));
  }
  // At the nominal calibration, the rig's own projection.
  const Pose2 pose(100.0, -50.0, deg2rad(35.0));
  Eigen::Vector2d u;
  ASSERT_TRUE(columns(CalibrationEstimate().head, pose.x, pose.y, std::cos(pose.theta), std::sin(pose.theta), &u));
  const Eigen::Vector2d d = landmark.head<2>() - Eigen::Vector2d(pose.x, pose.y);
  const Eigen::Vector3d robot(std::cos(pose.theta) * d.x() + std::sin(pose.theta) * d.y(),
                              -std::sin(pose.theta) * d.x() + std::cos(pose.theta) * d.y(), landmark.z());
  const std::optional<StereoPixels> projected = rig.project(robot, pan);
  ASSERT_TRUE(projected);
  EXPECT_NEAR(u(0), projected->u_left, 1e-9);
  EXPECT_NEAR(u(1), projected->u_right, 1e-9);
  // Behind the cameras: no columns.
  EXPECT_FALSE(columns(q, 2000.0, 650.0, 1.0, 0.0, &u));
}

TEST(ParticleFilterCalibration, RecoversPlantedWheelAndStereoErrorsAndIsConsistent) {
  // The filter on the given calibration is pulled off the truth and over-confident; each
  // particle carrying its own calibration, the set recovers the wheels, the disparity offset the
  // principal points make and the baseline within its spread, and its covariance holds its error.
  SimulationTrace trace;
  const Dataset d = plantedErrorWorld(&trace);
  const DrawnErrors& e = trace.errors;
  const std::vector<Estimate> given = runPf(d, pfKnownStart(d));
  std::optional<CalibrationEstimate> cal;
  const std::vector<Estimate> est = runPf(d, calibratingPf(d, "odometry,stereo"), &cal);
  ASSERT_TRUE(cal);
  EXPECT_TRUE(cal->odometry);
  EXPECT_TRUE(cal->stereo);
  const Eigen::Vector3d truth = test::drawnWheels(trace);
  for (int i = 0; i < 3; ++i) {
    const double sigma = std::sqrt(cal->wheels_covariance(i, i));
    EXPECT_NEAR(cal->wheels(i), truth(i), 3.0 * sigma) << "wheel parameter " << i;
    EXPECT_GT(sigma, 0.0);
  }
  EXPECT_LT(std::sqrt(cal->wheels_covariance(2, 2)), 0.5 * 0.04 * 75.0) << "the run determines the wheel base";
  const double dd = e.principal_px[0][0] - e.principal_px[1][0];
  EXPECT_NEAR(cal->head(2), dd, 3.0 * std::sqrt(cal->head_covariance(2, 2)));
  EXPECT_LT(std::sqrt(cal->head_covariance(2, 2)), 0.2 * 3.0) << "the run determines the disparity offset";
  EXPECT_NEAR(cal->head(1), 1 + e.baseline_rel, 3.0 * std::sqrt(cal->head_covariance(1, 1)));
  const double rmse_given = test::positionRmse(given, d), rmse = test::positionRmse(est, d);
  EXPECT_LT(rmse, 0.1 * rmse_given) << "given " << rmse_given << " mm, calibrating " << rmse << " mm";
  const double nees = meanNees(d, est), nees_given = meanNees(d, given);
  EXPECT_LT(nees, 6.0);
  EXPECT_GT(nees_given, 5.0 * nees) << "calibrating " << nees;
}

TEST(ParticleFilterCalibration, AFixThatAgreesWeightsTheSetAndAKidnapRedrawsIt) {
  // Lost after one gross outlier, the calibrating filter asks the global fix service (here: a fix
  // at a given pose, 100 mm sigma). One near the prediction weights the set, which keeps its
  // particles and their calibrations (the self-calibrating EKF fuses such a fix); one far away
  // (a kidnap) re-draws the set around it.
  const test::OutlierDrive drive = test::outlierDrive(true);
  const Dataset& d = drive.d;
  const Step& outlier = drive.outlier;
  for (const double offset : {20.0, 5000.0}) {
    ParticleFilterConfig c = calibratingPf(d, "odometry");
    c.particles = 500;
    c.gate.lost_after = 1;
    const Pose2 target = compose(*d.groundtruth[30], Pose2(offset, 0.0, 0.0));
    c.global_fix = [&](const Step&, const FieldMap&) {
      return std::optional<PoseFix>(PoseFix{target, Eigen::Vector3d(100.0, 100.0, 0.1).cwiseAbs2().asDiagonal()});
    };
    ParticleFilter pf(d.map, d.odometry, c, 5);
    Estimate before;
    for (int k = 0; k < 30; ++k) before = pf.process(d.steps[static_cast<size_t>(k)]);
    const Estimate e = pf.process(outlier);
    EXPECT_EQ(e.status, EstimateStatus::Reinitialised) << offset;
    const Pose2 predicted = predictPose(before.pose, before.covariance, outlier.d_left, outlier.d_right, d.odometry).pose;
    const double moved = std::hypot(e.pose.x - predicted.x, e.pose.y - predicted.y);
    if (offset < 100) {
      EXPECT_LT(moved, 10.0) << "the set stays where it was, one step on";
      EXPECT_LT(std::sqrt(e.covariance(0, 0)), 50.0) << "its own spread, not the fix's";
    } else {
      EXPECT_LT(std::hypot(e.pose.x - target.x, e.pose.y - target.y), 30.0) << "re-drawn around the fix";
      EXPECT_GT(std::sqrt(e.covariance(0, 0)), 70.0) << "with the fix's spread";
    }
    EXPECT_NE(pf.process(d.steps[31]).status, EstimateStatus::Lost) << "the gate starts again";
  }
}

TEST(ParticleFilterCalibration, ASavedStateReplaysBitForBit) {
  // The Localizer goes back to a saved state for a late frame: the calibrations are part of it.
  const Dataset d = plantedErrorWorld(nullptr);
  ParticleFilterConfig c = calibratingPf(d, "odometry,stereo");
  c.particles = 500;
  ParticleFilter pf(d.map, d.odometry, c, 11);
  const size_t k = 150, end = 260;
  for (size_t i = 0; i < k; ++i) pf.process(d.steps[i]);
  const ParticleFilter::State saved = pf.saveState();
  std::vector<Estimate> first;
  for (size_t i = k; i < end; ++i) first.push_back(pf.process(d.steps[i]));
  const std::optional<CalibrationEstimate> first_cal = pf.calibration();
  pf.restoreState(saved);
  for (size_t i = k; i < end; ++i) {
    const Estimate e = pf.process(d.steps[i]);
    EXPECT_EQ(e.pose.x, first[i - k].pose.x);
    EXPECT_EQ(e.pose.theta, first[i - k].pose.theta);
    EXPECT_EQ(e.covariance, first[i - k].covariance);
  }
  ASSERT_TRUE(first_cal);
  EXPECT_EQ(pf.calibration()->head, first_cal->head);
  EXPECT_EQ(pf.calibration()->wheels_covariance, first_cal->wheels_covariance);
  EXPECT_EQ(pf.particleCalibration(3), pf.particleCalibration(3));
  EXPECT_EQ(pf.particleCalibration(3).size(), 9);
}

TEST(ParticleFilterCalibration, SettingsItCannotServeAreRefused) {
  const Dataset d = plantedErrorWorld(nullptr);
  const auto refused = [&](const ParticleFilterConfig& c) {
    return test::errorOf([&] { ParticleFilter(d.map, d.odometry, c, 1); });
  };
  EXPECT_NE(refused(calibratingPf(d, "odometry,range")).find("odometry and stereo blocks only"), std::string::npos);
  ParticleFilterConfig field = calibratingPf(d, "odometry,stereo,field");
  EXPECT_NE(refused(field).find("odometry and stereo blocks only"), std::string::npos);
  ParticleFilterConfig considered = calibratingPf(d, "stereo");
  considered.calibration.consider = true;
  EXPECT_NE(refused(considered).find("odometry and stereo blocks only"), std::string::npos);
  ParticleFilterConfig prior = calibratingPf(d, "odometry");
  prior.proposal = ParticleProposal::Prior;
  EXPECT_NE(refused(prior).find("linearised optimal proposal"), std::string::npos);
  ParticleFilterConfig discount = calibratingPf(d, "odometry");
  discount.calibration_discount = 0.0;
  EXPECT_NE(refused(discount).find("calibration_discount"), std::string::npos);
  // The stereo block sees each sighting's pixels; a sighting without them is named.
  ParticleFilter pf(d.map, d.odometry, calibratingPf(d, "stereo"), 1);
  Step step = d.steps[1];
  ASSERT_FALSE(step.observations.empty());
  step.observations[0].pixels.reset();
  pf.process(d.steps[0]);
  const std::string error = test::errorOf([&] { pf.process(step); });
  EXPECT_NE(error.find("step 1: observation 0: the stereo calibration needs the sighting's pixels"), std::string::npos)
      << error;
  // Without a calibration block the filter reports none, and has none per particle.
  ParticleFilter plain(d.map, d.odometry, pfKnownStart(d), 1);
  EXPECT_FALSE(plain.calibration());
  EXPECT_EQ(plain.particleCalibration(0).size(), 0);
}

}  // namespace
}  // namespace stereoloc
