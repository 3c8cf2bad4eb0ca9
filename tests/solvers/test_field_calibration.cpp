// The field self-calibration (`--calibrate stereo,field`): on a long run over a field whose
// dimensions are off, the batch recovers them within their stated uncertainty and localizes
// better for it, and so do a real-time window and the EKF (on pixels and on range and bearing);
// a window as long as the data is the batch; a measured map's stated covariance is the block's
// prior; a map the field's dimensions do not place is refused.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <vector>

#include <Eigen/LU>
#include <opencv2/core.hpp>

#include "solvers/batch_smoother.h"
#include "solvers/ekf.h"
#include "solvers/self_calibration.h"
#include "solvers/sliding_window_smoother.h"
#include "src/core/error.h"
#include "src/eval/evaluation.h"
#include "src/pipeline/methods.h"
#include "src/pipeline/usage_error.h"
#include "src/sim/simulator.h"
#include "test_util.h"
#include "whole_data_window.h"

namespace stereoloc {
namespace {

TEST(FieldCalibration, RecoversTheFieldsDimensionsOnALongRun) {
  SimulationConfig cfg;
  cfg.landmarks = LandmarkSet::All;
  cfg.scenario.steps = 1500;
  cfg.profile.name = "field";
  cfg.profile.field_dimension_sigma_mm = 6.0;
  SimulationTrace trace;
  const Dataset d = simulate("random-walk", 0, cfg, 31, &trace);
  const std::vector<double>& truth = trace.errors.field_dimension_mm;
  ASSERT_EQ(truth.size(), static_cast<size_t>(kFieldDimensionCount));
  const InitialBelief start = knownBelief(*d.initial_pose, Eigen::Vector3d(1.0, 1.0, 1e-4).asDiagonal());

  SelfCalibrationConfig on = SelfCalibrationConfig::parse("stereo,field");
  on.field_dimension_sigma_mm = 10.0;
  const SelfCalibrationResult r = selfCalibratingBatch(d, start, on);
  ASSERT_TRUE(r.converged);
  ASSERT_TRUE(r.covariance_ok);
  const CalibrationEstimate& c = r.calibration;
  ASSERT_TRUE(c.field);
  int determined = 0;
  for (int k = 0; k < kFieldDimensionCount; ++k) {
    const double sd = std::sqrt(c.field_covariance(k, k));
    EXPECT_NEAR(c.field_dimensions_mm[k], truth[static_cast<size_t>(k)], 3.0 * sd) << kFieldDimensions[k].name;
    EXPECT_LT(sd, on.field_dimension_sigma_mm) << kFieldDimensions[k].name;
    determined += sd < 0.5 * std::fabs(truth[static_cast<size_t>(k)]);
  }
  EXPECT_GE(determined, 4) << "the run determines too few of the field's dimensions";
  // The poses are better for knowing the field.
  const SelfCalibrationResult off = selfCalibratingBatch(d, start, SelfCalibrationConfig::parse("stereo"));
  EXPECT_LT(test::positionRmse(r.trajectory, d), 0.8 * test::positionRmse(off.trajectory, d));
  // The estimate is written beside the rig, which still reads back.
  test::TempDir dir;
  c.saveAsRig(dir.file("rig.yaml"), d.rig, 0.0);
  EXPECT_NO_THROW(StereoRig::load(dir.file("rig.yaml")));
  cv::FileStorage fs(dir.file("rig.yaml"), cv::FileStorage::READ);
  EXPECT_EQ(static_cast<double>(fs["field_length_mm"]), c.field_dimensions_mm[0]);
  EXPECT_GT(static_cast<double>(fs["field_length_sigma_mm"]), 0.0);
}

// A realistic run on a field 6 mm off, identified sightings only (as the batch fuses them).
Dataset handBuiltFieldRun(uint64_t seed, int steps, SimulationTrace* trace) {
  SimulationConfig sc;
  sc.profile = ErrorProfile::realistic();
  sc.profile.field_dimension_sigma_mm = 6.0;
  sc.landmarks = LandmarkSet::All;
  sc.scenario.steps = steps;
  Dataset d = simulate("random-walk", 0, sc, seed, trace);
  test::keepIdentifiedSightings(d);
  return d;
}

// A field covariance of sigmas about `sigma` mm whose neighbouring dimensions correlate by 0.5.
FieldDimensionMatrix correlatedCovariance(double sigma) {
  const FieldDimensionVector sd = FieldDimensionVector::LinSpaced(0.5 * sigma, 1.5 * sigma);
  FieldDimensionMatrix c = sd.cwiseAbs2().asDiagonal();
  for (int k = 0; k + 1 < kFieldDimensionCount; ++k) c(k, k + 1) = c(k + 1, k) = 0.5 * sd[k] * sd[k + 1];
  return c;
}

TEST(FieldCalibration, WindowAsLongAsTheDataIsTheBatch) {
  const Dataset d = handBuiltFieldRun(3, 200, nullptr);
  const Eigen::Matrix3d P0 = Eigen::Vector3d(30.0, 30.0, deg2rad(5.0)).cwiseAbs2().asDiagonal();
  BatchSmootherConfig bc;
  bc.init = knownBelief(*d.groundtruth.front(), P0);
  bc.observation_model = {ObservationModel::PixelColumns, d.rig};
  bc.calibration = SelfCalibrationConfig::parse("odometry,stereo,field");
  // A prior of about 1 mm with correlated dimensions, as a measured map states it: with the
  // default 4 mm, the dimensions 200 steps hardly see leave the normal equations so flat that the
  // two solvers stop some 1e-6 mm apart (400 steps: within 1e-6).
  const FieldMap map = d.map.withDimensionCovariance(correlatedCovariance(1.0));
  test::solveToTheLimit(bc);
  BatchSmoother b(map, d.odometry, bc);
  for (const Step& s : d.steps) b.process(s);
  const std::vector<Estimate> eb = b.finish();

  SlidingWindowConfig c;
  c.init = bc.init;
  c.observation_model = bc.observation_model;
  c.calibration = bc.calibration;
  test::solveAsTheBatch(c, d.steps.size());
  SlidingWindowSmoother win(map, d.odometry, c);
  for (const Step& s : d.steps) win.process(s);
  const test::SolutionGap gap = test::solutionGap(win.finish(), eb);
  EXPECT_LT(gap.pose, 1e-6);
  EXPECT_LT(gap.covariance, 1e-6);
  const std::optional<CalibrationEstimate> cw = win.calibration();
  ASSERT_TRUE(cw.has_value());
  const CalibrationEstimate cb = b.calibration();
  ASSERT_TRUE(cw->field && cb.field);
  EXPECT_LT((cw->field_dimensions_mm - cb.field_dimensions_mm).cwiseAbs().maxCoeff(), 1e-6);
  EXPECT_LT(test::relativeDifference(cw->field_covariance, cb.field_covariance), 1e-6);
  EXPECT_GT(cb.field_dimensions_mm.cwiseAbs().maxCoeff(), 0.1);  // the data moved it
}

// A map that states how well it knows its dimensions (a field an earlier drive measured,
// `--field-out`) sets the field block's prior, correlations included, in place of the
// configuration's one sigma: the field's information is then the map's plus the drive's.
TEST(FieldCalibration, AMeasuredMapsCovarianceIsItsPrior) {
  const Dataset d = handBuiltFieldRun(3, 40, nullptr);
  const FieldDimensionMatrix stated = correlatedCovariance(2.5);
  BatchSmootherConfig bc;
  bc.init = knownBelief(*d.groundtruth.front(), Eigen::Vector3d(30.0, 30.0, deg2rad(5.0)).cwiseAbs2().asDiagonal());
  bc.observation_model = {ObservationModel::PixelColumns, d.rig};
  bc.calibration = SelfCalibrationConfig::parse("odometry,stereo,field");
  bc.calibration.field_dimension_sigma_mm = 8.0;
  auto field = [&](const FieldMap& map) {
    BatchSmoother b(map, d.odometry, bc);
    for (const Step& s : d.steps) b.process(s);
    b.finish();
    return b.calibration();
  };
  const CalibrationEstimate given = field(d.map), measured = field(d.map.withDimensionCovariance(stated));
  ASSERT_TRUE(given.field && measured.field);
  EXPECT_EQ(given.field_prior_sigma_mm, FieldDimensionVector::Constant(8.0));
  EXPECT_LT((measured.field_prior_sigma_mm - stated.diagonal().cwiseSqrt()).cwiseAbs().maxCoeff(), 1e-12);
  // The drive's information on the field is what the given run's marginal holds beyond its prior;
  // with the stated prior in its place the marginal is their sum (up to where the two solves
  // linearise).
  const FieldDimensionMatrix data = given.field_covariance.inverse() - FieldDimensionMatrix::Identity() / 64.0;
  const FieldDimensionMatrix expected = (data + stated.inverse()).inverse();
  for (int k = 0; k < kFieldDimensionCount; ++k) {
    const double sd = std::sqrt(measured.field_covariance(k, k));
    std::printf("%-20s the drive alone %.2f mm, the map %.2f mm: %.3f mm (from the information %.3f mm)\n",
                kFieldDimensions[k].name, std::sqrt(given.field_covariance(k, k)), std::sqrt(stated(k, k)), sd,
                std::sqrt(expected(k, k)));
    EXPECT_LE(sd, std::sqrt(stated(k, k)) * (1 + 1e-9)) << kFieldDimensions[k].name;
  }
  EXPECT_LT(test::relativeDifference(measured.field_covariance, expected), 0.02);
  // How far the estimate went is measured against the stated prior.
  const PriorDistance far = furthestFromPrior(measured, bc.calibration, d.odometry.wheel_base_mm);
  for (int k = 0; k < kFieldDimensionCount; ++k)
    EXPECT_GE(far.sigmas, std::fabs(measured.field_dimensions_mm[k]) / measured.field_prior_sigma_mm[k] - 1e-12);
  // The sliding window takes it too.
  SlidingWindowConfig wc;
  wc.init = bc.init;
  wc.observation_model = bc.observation_model;
  wc.calibration = bc.calibration;
  SlidingWindowSmoother win(d.map.withDimensionCovariance(stated), d.odometry, wc);
  for (const Step& s : d.steps) win.process(s);
  win.finish();
  ASSERT_TRUE(win.calibration() && win.calibration()->field);
  EXPECT_EQ(win.calibration()->field_prior_sigma_mm, measured.field_prior_sigma_mm);
}

TEST(FieldCalibration, RealTimeWindowRecoversTheField) {
  SimulationTrace trace;
  const Dataset d = handBuiltFieldRun(5, 700, &trace);
  SlidingWindowConfig c;
  c.window = 20;
  c.init = knownBelief(*d.groundtruth.front(), Eigen::Vector3d(1.0, 1.0, 1e-4).asDiagonal());
  c.observation_model = {ObservationModel::PixelColumns, d.rig};
  c.calibration = SelfCalibrationConfig::parse("odometry,stereo,field");
  c.calibration.field_dimension_sigma_mm = 10.0;
  SlidingWindowSmoother win(d.map, d.odometry, c);
  for (const Step& s : d.steps) win.process(s);
  const std::vector<Estimate> with = win.finish();
  const std::optional<CalibrationEstimate> e = win.calibration();
  ASSERT_TRUE(e && e->field);
  int determined = 0;
  for (int k = 0; k < kFieldDimensionCount; ++k) {
    const double sd = std::sqrt(e->field_covariance(k, k)), truth = trace.errors.field_dimension_mm[static_cast<size_t>(k)];
    EXPECT_NEAR(e->field_dimensions_mm[k], truth, 3.0 * sd) << kFieldDimensions[k].name;
    determined += sd < 0.5 * std::fabs(truth);
  }
  EXPECT_GE(determined, 3);
  c.calibration.field = false;
  SlidingWindowSmoother without(d.map, d.odometry, c);
  for (const Step& s : d.steps) without.process(s);
  EXPECT_LT(test::positionRmse(with, d), test::positionRmse(without.finish(), d));
}

// The EKF with the field block, stating the realistic robot's noise as the study does
// (applyErrorProfile): the field within 3 sigma, at least three of its dimensions determined,
// the poses better than without the block and their NEES near 3. The run is lost twice: the
// fixes that re-anchor it see the field's estimate and say how it moves them.
TEST(FieldCalibration, RealTimeEkfRecoversTheField) {
  SimulationTrace trace;
  const Dataset d = handBuiltFieldRun(5, 700, &trace);
  MethodOptions o;
  applyErrorProfile(ErrorProfile::realistic(), d.rig.focal(), o);
  o.calibration.field_dimension_sigma_mm = 10.0;
  const MethodRun with = runMethod("ekf:calib-field", d, 1, o), without = runMethod("ekf:calib", d, 1, o);
  ASSERT_TRUE(with.calibration && with.calibration->field);
  const CalibrationEstimate& e = *with.calibration;
  EXPECT_EQ(e.field_prior_sigma_mm, FieldDimensionVector::Constant(10.0));
  int determined = 0;
  for (int k = 0; k < kFieldDimensionCount; ++k) {
    const double sd = std::sqrt(e.field_covariance(k, k)), truth = trace.errors.field_dimension_mm[static_cast<size_t>(k)];
    EXPECT_NEAR(e.field_dimensions_mm[k], truth, 3.0 * sd) << kFieldDimensions[k].name;
    determined += sd < 0.5 * std::fabs(truth);
  }
  EXPECT_GE(determined, 3);
  int reinitialised = 0;
  for (const Estimate& est : with.estimates) reinitialised += est.status == EstimateStatus::Reinitialised;
  EXPECT_GE(reinitialised, 1) << "the run no longer tests the re-anchoring fixes";
  const TruthByStep truth = truthByStep(d.steps, d.groundtruth);
  const TrajectoryMetrics on = trajectoryMetrics(poseErrors(with.estimates, truth));
  const TrajectoryMetrics off = trajectoryMetrics(poseErrors(without.estimates, truth));
  std::printf("position RMSE %.2f -> %.2f mm, mean NEES %.2f -> %.2f with the field block\n", off.position_rmse,
              on.position_rmse, off.mean_nees, on.mean_nees);
  EXPECT_LT(on.position_rmse, 0.5 * off.position_rmse);
  EXPECT_LT(on.mean_nees, 3.5);
}

// The EKF that considers its calibration (a Schmidt-Kalman filter) with the field among it, on a
// field 2 mm off with its 4 mm prior: the field stays as given, its uncertainty in every
// covariance, so the filter stays honest where the same filter without the field is not.
TEST(FieldCalibration, AFilterConsideringTheFieldStaysHonest) {
  SimulationConfig sc;
  sc.profile = ErrorProfile::realistic();
  sc.profile.field_dimension_sigma_mm = 2.0;
  sc.landmarks = LandmarkSet::All;
  sc.scenario.steps = 400;
  Dataset d = simulate("random-walk", 0, sc, 7, nullptr);
  test::keepIdentifiedSightings(d);
  MethodOptions o;
  applyErrorProfile(ErrorProfile::realistic(), d.rig.focal(), o);
  const MethodRun without = runMethod("ekf:consider", d, 1, o);
  o.calibration.field = true;
  const MethodRun with = runMethod("ekf:consider", d, 1, o);
  EXPECT_FALSE(with.calibration.has_value());  // considered: nothing estimated
  const TruthByStep truth = truthByStep(d.steps, d.groundtruth);
  const TrajectoryMetrics on = trajectoryMetrics(poseErrors(with.estimates, truth));
  const TrajectoryMetrics off = trajectoryMetrics(poseErrors(without.estimates, truth));
  std::printf("mean NEES %.2f -> %.2f considering the field (position RMSE %.2f -> %.2f mm)\n", off.mean_nees,
              on.mean_nees, off.position_rmse, on.position_rmse);
  EXPECT_GT(off.mean_nees, 4.0);
  EXPECT_LT(on.mean_nees, 3.5);
  EXPECT_GT(on.mean_nees, 1.0);
  // A fix considers the stereo block only.
  EXPECT_THROW(runMethod("fix2:consider", d, 1, o), UsageError);
}

TEST(FieldCalibration, OnlyOnAFieldItsDimensionsPlace) {
  EXPECT_THROW(SelfCalibrationConfig::parse("field").validate(), Error);  // needs the stereo block
  EXPECT_THROW(SelfCalibrationConfig::parse("stereo,fields"), Error);
  SelfCalibrationConfig considered = SelfCalibrationConfig::parse("stereo,field");
  considered.consider = true;
  EXPECT_NO_THROW(considered.validate());  // the EKF considers it

  SimulationConfig cfg;
  cfg.landmarks = LandmarkSet::All;
  cfg.scenario.steps = 20;
  const Dataset d = simulate("circle", 0, cfg, 1, nullptr);
  SlidingWindowConfig wc;
  wc.calibration = SelfCalibrationConfig::parse("stereo,field");
  wc.observation_model = {ObservationModel::PixelColumns, d.rig, 0.0, UnmodelledNoise()};
  EkfConfig ec;
  ec.calibration = wc.calibration;
  ec.observation_model = wc.observation_model;
  ec.observation_model.model = ObservationModel::RangeBearing;  // the field would take the range bias
  EXPECT_THROW(Ekf(d.map, d.odometry, ec), Error);
  ec.observation_model.model = ObservationModel::PixelColumns;
  EXPECT_THROW(parseMethodSpec("pf:calib-field", InitMode::Known), UsageError);
  EXPECT_EQ(parseMethodSpec("ekf:calib-field", InitMode::Known).first, "ekf");
  EXPECT_EQ(parseMethodSpec("window:calib-field", InitMode::Known).first, "window");
  EXPECT_EQ(parseMethodSpec("batch:calib-field", InitMode::Known).first, "batch");
  EXPECT_TRUE(hasFieldSuffix("batch:global:calib-field"));
  EXPECT_EQ(withoutCalibrationSuffix("batch:global:calib-field"), "batch:global");

  // A map with landmarks of its own: the field's dimensions do not place them.
  std::vector<Landmark> own = d.map.landmarks();
  own[2].position.y() += 5.0;
  Dataset edited = d;
  edited.map = FieldMap("edited", d.map.bounds(), own, *d.map.geometry());
  const InitialBelief start = knownBelief(*d.initial_pose, Eigen::Vector3d(1.0, 1.0, 1e-4).asDiagonal());
  try {
    selfCalibratingBatch(edited, start, SelfCalibrationConfig::parse("stereo,field"));
    FAIL() << "a map of its own was calibrated as a field";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("'edited'"), std::string::npos) << e.what();
  }
  try {
    SlidingWindowSmoother(edited.map, d.odometry, wc);
    FAIL() << "the window took a map of its own as a field";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("'edited'"), std::string::npos) << e.what();
  }
  try {
    Ekf(edited.map, d.odometry, ec);
    FAIL() << "the EKF took a map of its own as a field";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("'edited'"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace stereoloc
