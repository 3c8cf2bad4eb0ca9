// The batch smoother's field self-calibration (`--calibrate stereo,field`): on a long run over a
// field whose dimensions are off, it recovers them within their stated uncertainty and localizes
// better for it; the filters refuse it, and so does a map the field's dimensions do not place.
#include <gtest/gtest.h>

#include <cmath>
#include <vector>

#include "solvers/ekf.h"
#include "solvers/self_calibration.h"
#include "solvers/sliding_window_smoother.h"
#include "src/core/error.h"
#include "src/pipeline/methods.h"
#include "src/pipeline/usage_error.h"
#include "src/sim/simulator.h"
#include "test_util.h"

namespace stereoloc {
namespace {

double positionRmse(const std::vector<Estimate>& est, const Dataset& d) {
  double s = 0;
  for (size_t k = 0; k < est.size(); ++k) s += (est[k].pose.translation() - d.groundtruth[k]->translation()).squaredNorm();
  return std::sqrt(s / static_cast<double>(est.size()));
}

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
  EXPECT_LT(positionRmse(r.trajectory, d), 0.8 * positionRmse(off.trajectory, d));
  // The estimate is written beside the rig, which still reads back.
  test::TempDir dir;
  c.saveAsRig(dir.file("rig.yaml"), d.rig, 0.0);
  EXPECT_NO_THROW(StereoRig::load(dir.file("rig.yaml")));
  cv::FileStorage fs(dir.file("rig.yaml"), cv::FileStorage::READ);
  EXPECT_EQ(static_cast<double>(fs["field_length_mm"]), c.field_dimensions_mm[0]);
  EXPECT_GT(static_cast<double>(fs["field_length_sigma_mm"]), 0.0);
}

TEST(FieldCalibration, OnlyTheBatchOnAFieldItsDimensionsPlace) {
  EXPECT_THROW(SelfCalibrationConfig::parse("field").validate(), Error);  // needs the stereo block
  EXPECT_THROW(SelfCalibrationConfig::parse("stereo,fields"), Error);
  SelfCalibrationConfig considered = SelfCalibrationConfig::parse("stereo,field");
  considered.consider = true;
  EXPECT_THROW(considered.validate(), Error);

  SimulationConfig cfg;
  cfg.landmarks = LandmarkSet::All;
  cfg.scenario.steps = 20;
  const Dataset d = simulate("circle", 0, cfg, 1, nullptr);
  SlidingWindowConfig wc;
  wc.calibration = SelfCalibrationConfig::parse("stereo,field");
  wc.observation_model = {ObservationModel::PixelColumns, d.rig, 0.0, UnmodelledNoise()};
  EXPECT_THROW(SlidingWindowSmoother(d.map, d.odometry, wc), Error);
  EkfConfig ec;
  ec.calibration = wc.calibration;
  ec.observation_model = wc.observation_model;
  EXPECT_THROW(Ekf(d.map, d.odometry, ec), Error);
  EXPECT_THROW(parseMethodSpec("window:calib-field", InitMode::Known), UsageError);
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
}

}  // namespace
}  // namespace stereoloc
