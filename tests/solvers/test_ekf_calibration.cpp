// The self-calibrating EKF (solvers/ekf.h, "Self-calibration"): the calibrated sighting's
// Jacobians against central differences; with vanishing priors it is the plain EKF; on worlds
// with the errors its blocks model it recovers them within their stated sigmas (the wheel base,
// considered, keeps its prior) and tracks where the EKF on the given calibration does not; a fix
// that agrees re-anchors it, a kidnap restarts it; a feature's offsets, added as states when it
// is first fused, give exactly the white noise they replace until it is seen again.
#include <gtest/gtest.h>

#include <cmath>
#include <memory>
#include <set>
#include <string>
#include <vector>

#include "factors/stereo_pixel_calibration_factor.h"
#include "solvers/batch_smoother.h"
#include "solvers/calibrated_models.h"
#include "solvers/ekf.h"
#include "src/core/error.h"
#include "src/core/measurement_model.h"
#include "src/core/numeric_diff.h"
#include "src/sim/error_profile.h"
#include "src/sim/simulator.h"
#include "planted_error_world.h"
#include "test_util.h"

namespace stereoloc {
namespace {

using test::meanNees;
using test::plantedErrorWorld;

EkfConfig ekfKnownStart(const Dataset& d) { return test::knownStartConfig<EkfConfig>(d); }

EkfConfig calibratingEkf(const Dataset& d, const std::string& blocks, ObservationModel model = ObservationModel::PixelColumns) {
  EkfConfig c = test::calibratingConfig<EkfConfig>(d, blocks);
  c.observation_model.model = model;
  return c;
}

std::vector<Estimate> runEkf(const Dataset& d, const EkfConfig& c, std::optional<CalibrationEstimate>* calibration = nullptr) {
  Ekf ekf(d.map, d.odometry, c);
  for (const Step& s : d.steps) ekf.process(s);
  if (calibration) *calibration = ekf.calibration();
  return ekf.finish();
}

double positionRmse(const Dataset& d, const std::vector<Estimate>& est) {
  double sse = 0;
  for (size_t i = 0; i < est.size(); ++i) {
    const Pose2& t = *d.groundtruth[static_cast<size_t>(est[i].step)];
    sse += std::pow(est[i].pose.x - t.x, 2) + std::pow(est[i].pose.y - t.y, 2);
  }
  return std::sqrt(sse / static_cast<double>(est.size()));
}

TEST(EkfCalibration, CalibratedSightingJacobiansMatchCentralDifferences) {
  const StereoRig rig;
  const Pose2 pose(400.0, 300.0, deg2rad(20.0));
  const Eigen::Vector3d landmark(1300.0, 650.0, 0.0);
  const double pan = deg2rad(5.0);
  // The pixels a calibrated pair sees (the calibrated pixel factor with z = 0 and unit weight).
  CalibrationEstimate::StereoVector q0;
  q0 << deg2rad(0.6), 1.012, -1.5, 0.4, 0.004, -0.003;
  std::unique_ptr<ceres::CostFunction> f(StereoPixelCalibrationFactor::Create(
      rig, landmark, StereoPixels{}, pan, Eigen::Matrix4d::Identity(), PixelResiduals::All));
  const double x[3] = {pose.x, pose.y, pose.theta};
  const double* blocks[2] = {x, q0.data()};
  Eigen::Vector4d px;
  ASSERT_TRUE(f->Evaluate(blocks, px.data(), nullptr));
  Observation obs = observationFromPixels(rig, 3, LandmarkType::Junction, StereoPixels{px(0), px(1), px(2), px(3)}, pan,
                                          isotropicPixelCovariance(0.5));
  obs.slide_gain = 0.8;
  const double dv = 0.7;
  const Eigen::Vector2d lm = landmark.head<2>();
  const CalibratedSighting s = calibratedSighting(obs, rig, pose, lm, q0, dv);
  auto wrapped = [](const Eigen::Vector2d& a, const Eigen::Vector2d& b) {
    return Eigen::Vector2d(a(0) - b(0), angleDiff(a(1), b(1)));
  };
  // The state (x, y, theta, q, dv) in one vector.
  Eigen::Matrix<double, 10, 1> x0;
  x0 << pose.x, pose.y, pose.theta, q0, dv;
  const auto nu = [&](const Eigen::Matrix<double, 10, 1>& v) {
    return calibratedSighting(obs, rig, Pose2(v(0), v(1), v(2)), lm, v.segment<6>(3), v(9)).nu;
  };
  const Eigen::Matrix<double, 2, 10> J = numericJacobian<2, 10>(nu, x0, wrapped, 1e-6);
  EXPECT_TRUE(test::jacobianMatches(s.J_nu_pose, Eigen::Matrix<double, 2, 3>(J.leftCols<3>())));
  EXPECT_TRUE(test::jacobianMatches(s.J_nu_q, Eigen::Matrix<double, 2, 6>(J.middleCols<6>(3)), 1e-5));
  EXPECT_TRUE(test::jacobianMatches(s.J_nu_row, Eigen::Vector2d(J.col(9))));
  // At the calibration that made the pixels, with no row offset: the landmark as it is.
  EXPECT_LT(calibratedSighting(obs, rig, pose, lm, q0, 0.0).nu.norm(), 1e-6);
  EXPECT_GT(s.nu.norm(), 1e-3);  // the slide s dv moves it
  obs.slide_gain = 0.0;
  EXPECT_LT(calibratedSighting(obs, rig, pose, lm, q0, dv).nu.norm(), 1e-6);
  // A correction that leaves no disparity cannot be triangulated.
  CalibrationEstimate::StereoVector far = q0;
  far(2) = px(0) - px(2) + 1.0;
  EXPECT_THROW(calibratedSighting(obs, rig, pose, lm, far, 0.0), GeometryError);
}

TEST(EkfCalibration, WithVanishingPriorsItIsThePlainEkf) {
  // The joint state's calibration blocks with (almost) no uncertainty: every update and
  // prediction is the iterated EKF's (both Gauss-Newton to convergence), whose observations were
  // triangulated from the same pixels.
  SimulationConfig sc;
  sc.scenario.steps = 120;
  const Dataset d = simulate("circle", 0, sc, 7);
  EkfConfig c = calibratingEkf(d, "odometry,stereo", ObservationModel::RangeBearing);
  SelfCalibrationConfig& k = c.calibration;
  k.wheel_scale_sigma = k.wheel_base_rel_sigma = k.tilt_sigma_rad = k.baseline_scale_sigma = 1e-12;
  k.disparity_offset_sigma_px = k.column_offset_sigma_px = k.focal_ratio_sigma = k.focal_scale_sigma = 1e-12;
  std::optional<CalibrationEstimate> cal;
  EkfConfig iterated = ekfKnownStart(d);
  iterated.max_iterations = 10;
  const std::vector<Estimate> a = runEkf(d, iterated), b = runEkf(d, c, &cal);
  ASSERT_EQ(a.size(), b.size());
  for (size_t i = 0; i < a.size(); ++i) {
    EXPECT_LT((minus(a[i].pose, b[i].pose)).cwiseAbs().maxCoeff(), 1e-5) << "step " << i;
    EXPECT_LT((a[i].covariance - b[i].covariance).cwiseAbs().maxCoeff(), 1e-5 * a[i].covariance.cwiseAbs().maxCoeff())
        << "step " << i;
    EXPECT_EQ(a[i].status, b[i].status) << "step " << i;
  }
  ASSERT_TRUE(cal);
  EXPECT_TRUE(cal->odometry && cal->stereo);
  EXPECT_NEAR(cal->wheels(2), d.odometry.wheel_base_mm, 1e-6);
  EXPECT_FALSE(runEkf(d, ekfKnownStart(d)).empty());
  std::optional<CalibrationEstimate> none;
  runEkf(d, ekfKnownStart(d), &none);
  EXPECT_FALSE(none);
}

TEST(EkfCalibration, RecoversPlantedWheelAndStereoErrors) {
  // The EKF on the given calibration is pulled off the truth and over-confident; the
  // calibrating one recovers the wheels within their stated sigmas, the disparity offset the
  // principal points make, and is consistent.
  SimulationTrace trace;
  const Dataset d = plantedErrorWorld(&trace);
  const DrawnErrors& e = trace.errors;
  const std::vector<Estimate> given = runEkf(d, ekfKnownStart(d));
  std::optional<CalibrationEstimate> cal;
  const std::vector<Estimate> est = runEkf(d, calibratingEkf(d, "odometry,stereo"), &cal);
  ASSERT_TRUE(cal);
  const Eigen::Vector3d truth = test::drawnWheels(trace);
  for (int i = 0; i < 2; ++i) {
    EXPECT_NEAR(cal->wheels(i), truth(i), 3.0 * std::sqrt(cal->wheels_covariance(i, i))) << "wheel scale " << i;
    EXPECT_LT(std::sqrt(cal->wheels_covariance(i, i)), 0.5 * 0.01) << "the run does not determine wheel scale " << i;
  }
  // The wheel base is considered: nominal, with its prior's uncertainty, which holds the truth.
  EXPECT_EQ(cal->wheels(2), 75.0);
  EXPECT_NEAR(std::sqrt(cal->wheels_covariance(2, 2)), 0.04 * 75.0, 1e-9);
  EXPECT_NEAR(cal->wheels(2), truth(2), 3.0 * std::sqrt(cal->wheels_covariance(2, 2)));
  // The disparity offset: the principal points' column difference (left minus right).
  const double dd = e.principal_px[0][0] - e.principal_px[1][0];
  EXPECT_NEAR(cal->head(2), dd, 3.0 * std::sqrt(cal->head_covariance(2, 2)));
  // The baseline scale: updated on range-bearing, the calibration would absorb the range's
  // conversion bias here (1.036, 4.8 sigma off); on the pixel columns it does not.
  EXPECT_NEAR(cal->head(1), 1 + e.baseline_rel, 3.0 * std::sqrt(cal->head_covariance(1, 1)));
  const double rmse_given = positionRmse(d, given), rmse = positionRmse(d, est);
  EXPECT_LT(rmse, 0.5 * rmse_given) << "given " << rmse_given << " mm, calibrating " << rmse << " mm";
  EXPECT_LT(meanNees(d, est), 6.0);
  EXPECT_GT(meanNees(d, given), 2.0 * meanNees(d, est));
}

TEST(EkfCalibration, AFixThatAgreesReanchorsAndAKidnapRestarts) {
  // Lost after one gross outlier, the filter asks the global fix service (here: a fix at a given
  // pose). One near the prediction is fused through the joint state: the pose moves toward it,
  // the wheels learn from the odometry it corrects, the stereo calibration (which the fix saw the
  // sightings through) stays. One far away (a kidnap) restarts the filter at it.
  const test::OutlierDrive drive = test::outlierDrive(false);
  const Dataset& d = drive.d;
  const Step& outlier = drive.outlier;
  for (const double offset : {20.0, 3000.0}) {
    EkfConfig c = calibratingEkf(d, "odometry,stereo");
    c.gate.lost_after = 1;
    const Pose2 target = compose(*d.groundtruth[30], Pose2(offset, 0.0, 0.0));
    c.global_fix = [&](const Step&, const FieldMap&) {
      return std::optional<PoseFix>(PoseFix{target, Eigen::Vector3d(5.0, 5.0, 0.01).cwiseAbs2().asDiagonal()});
    };
    Ekf ekf(d.map, d.odometry, c);
    for (int k = 0; k < 30; ++k) ekf.process(d.steps[static_cast<size_t>(k)]);
    const Pose2 predicted = ekf.pose();
    const CalibrationEstimate before = *ekf.calibration();
    const Estimate e = ekf.process(outlier);
    EXPECT_EQ(e.status, EstimateStatus::Reinitialised) << offset;
    EXPECT_FALSE(ekf.lost());
    const CalibrationEstimate after = *ekf.calibration();
    EXPECT_EQ(after.head, before.head) << offset;
    EXPECT_EQ(after.head_covariance, before.head_covariance) << offset;
    if (offset < 100.0) {
      EXPECT_GT(minus(e.pose, predicted).head<2>().norm(), 1.0);
      EXPECT_GT(minus(e.pose, target).head<2>().norm(), 0.01);  // fused, not taken as it is
      EXPECT_NE(after.wheels(0), before.wheels(0));
      EXPECT_EQ(after.wheels(2), before.wheels(2));  // considered
      const double scales_after = after.wheels_covariance(0, 0) + after.wheels_covariance(1, 1);
      EXPECT_LT(scales_after, before.wheels_covariance(0, 0) + before.wheels_covariance(1, 1));
    } else {
      EXPECT_LT(minus(e.pose, target).cwiseAbs().maxCoeff(), 1e-9);
      EXPECT_EQ(after.wheels, before.wheels);
    }
  }
}

// A realistic robot's line (simulated pixels: goal corners, and marking features the filter
// associates).
Dataset realisticLine(int steps, uint64_t seed) {
  SimulationConfig sc;
  sc.profile = ErrorProfile::realistic();
  sc.scenario.steps = steps;
  return simulate("line", 0, sc, seed);
}

EkfConfig withNoiseModel(const Dataset& d, bool feature_offsets) {
  EkfConfig c = calibratingEkf(d, "odometry,stereo");
  c.observation_model.unmodelled = UnmodelledNoise::load(std::string(STEREOLOC_DATA_DIR) + "/noise_realistic.yaml");
  c.calibration.feature_offsets = feature_offsets;
  return c;
}

TEST(EkfCalibration, AFeaturesOffsetsAreItsWhiteNoiseUntilItIsSeenAgain) {
  // The offsets (b_c, b_d) enter the pixel columns linearly with a zero-mean prior: fused once
  // as states they give the pose, the calibration and e^2 of the same noise held in R. Seen
  // again, the repetition is what the states carry and white noise does not.
  Dataset d = realisticLine(60, 3);
  Ekf states(d.map, d.odometry, withNoiseModel(d, true)), white(d.map, d.odometry, withNoiseModel(d, false));
  std::set<int> fused;  // landmarks fused so far (sightings associated by the filter included)
  bool repeated = false;
  size_t compared = 0;
  for (const Step& s : d.steps) {
    const Estimate a = states.process(s), b = white.process(s);
    std::set<int> now;
    for (const EkfUpdateRecord& r : states.lastUpdates())
      if (r.accepted && !r.compass) repeated |= fused.count(r.landmark_id) > 0 || !now.insert(r.landmark_id).second;
    fused.insert(now.begin(), now.end());
    if (repeated) continue;  // from here on they differ
    const double scale = b.covariance.cwiseAbs().maxCoeff();
    EXPECT_LT(minus(a.pose, b.pose).cwiseAbs().maxCoeff(), 1e-6) << "step " << s.step;
    EXPECT_LT((a.covariance - b.covariance).cwiseAbs().maxCoeff(), 1e-6 * scale) << "step " << s.step;
    ASSERT_EQ(states.lastUpdates().size(), white.lastUpdates().size());
    for (size_t i = 0; i < states.lastUpdates().size(); ++i)
      EXPECT_NEAR(states.lastUpdates()[i].mahalanobis_squared, white.lastUpdates()[i].mahalanobis_squared,
                  1e-6 * std::max(1.0, white.lastUpdates()[i].mahalanobis_squared));
    compared += now.size();
  }
  ASSERT_TRUE(repeated);
  EXPECT_GT(compared, 0u);
  const CalibrationEstimate c = *states.calibration(), w = *white.calibration();
  EXPECT_TRUE(c.image && w.image);
  EXPECT_TRUE(w.feature_offsets.empty());
  ASSERT_FALSE(c.feature_offsets.empty());
  const UnmodelledNoise noise = withNoiseModel(d, true).observation_model.unmodelled;
  std::set<int> ids;
  for (const CalibrationEstimate::FeatureOffset& f : c.feature_offsets) {
    EXPECT_TRUE(ids.insert(f.landmark_id).second) << f.landmark_id;
    EXPECT_TRUE(fused.count(f.landmark_id)) << f.landmark_id;
    const FeatureOffsetSigma prior = featureOffsetSigma(d.map.at(f.landmark_id).type, noise);
    EXPECT_LE(f.column_variance, prior.column * prior.column * (1 + 1e-9)) << f.landmark_id;
    EXPECT_LE(f.variance, prior.disparity * prior.disparity * (1 + 1e-9)) << f.landmark_id;
  }
  // Seen again and again, the same noise as states is not the white noise.
  EXPECT_GT((states.covariance() - white.covariance()).cwiseAbs().maxCoeff(), 1e-6 * white.covariance().maxCoeff());
}

TEST(EkfCalibration, EstimatesAPlantedFeatureOffset) {
  // One goal corner's columns 1 px off in every sighting (its corner fitted on the same aliased
  // edges), the noise model stating such offsets at 1 px: the filter finds that corner's offset
  // against the others' (their mean goes with the column offset of q), and tracks closer than
  // with the offsets as white noise (8.3 against 8.8 mm).
  SimulationConfig sc;
  sc.scenario.steps = 1000;
  Dataset d = simulate("circle", 0, sc, 11);
  for (Step& s : d.steps)
    for (Observation& o : s.observations)
      if (o.landmark_id == 0) {
        o.pixels->u_left += 1.0;
        o.pixels->u_right += 1.0;
      }
  EkfConfig c = calibratingEkf(d, "stereo");
  c.observation_model.unmodelled.row_offset_sigma_px = 0.5;
  c.observation_model.unmodelled.goal_feature_column_sigma_px = 1.0;
  std::optional<CalibrationEstimate> with, without;
  const std::vector<Estimate> a = runEkf(d, c, &with);
  c.calibration.feature_offsets = false;
  const std::vector<Estimate> b = runEkf(d, c, &without);
  ASSERT_TRUE(with && without);
  ASSERT_EQ(with->feature_offsets.size(), 4u);  // the four goal corners
  double others = 0;
  for (const CalibrationEstimate::FeatureOffset& f : with->feature_offsets)
    if (f.landmark_id != 0) others += f.column_px / 3.0;
  const CalibrationEstimate::FeatureOffset& planted = with->feature_offsets.front();
  ASSERT_EQ(planted.landmark_id, 0);
  // The circle sees the corners mostly one at a time, so the pose takes most of each bearing:
  // the offset is learned slowly (sigma 0.71 px after 1000 steps), and found within it.
  const double sigma = std::sqrt(planted.column_variance);
  EXPECT_LT(sigma, 0.8);
  EXPECT_NEAR(planted.column_px - others, 1.0, 3.0 * sigma);
  EXPECT_GT(planted.column_px - others, 0.5);
  EXPECT_LT(positionRmse(d, a), 0.97 * positionRmse(d, b));
}

TEST(EkfCalibration, ASightingSetAsideTakesItsFeatureOffsetsWithIt) {
  // The joint gate fuses a step's sightings, then goes back to the prediction to set aside an
  // incompatible one: the offsets the first attempt added as states go back with it.
  const Dataset d = realisticLine(30, 4);
  size_t k = 0;
  while (k < d.steps.size() && d.steps[k].observations.empty()) ++k;
  ASSERT_LT(k, d.steps.size());
  Step step = d.steps[k];
  Observation outlier = step.observations.front();
  outlier.pixels->u_left += 40.0;  // the same feature 40 px to the side: a bearing 8 deg off
  outlier.pixels->u_right += 40.0;
  step.observations.push_back(outlier);
  Ekf ekf(d.map, d.odometry, withNoiseModel(d, true));
  for (size_t i = 0; i < k; ++i) ekf.process(d.steps[i]);
  const Estimate e = ekf.process(step);
  EXPECT_NE(e.status, EstimateStatus::Lost);
  int accepted = 0, rejected = 0;
  for (const EkfUpdateRecord& r : ekf.lastUpdates()) (r.accepted ? accepted : rejected) += r.compass ? 0 : 1;
  EXPECT_EQ(rejected, 1);
  EXPECT_EQ(accepted, static_cast<int>(step.observations.size()) - 1);
  std::set<int> sighted;
  for (const Observation& o : d.steps[k].observations) sighted.insert(o.landmark_id);
  std::set<int> ids;
  const CalibrationEstimate cal = *ekf.calibration();
  for (const CalibrationEstimate::FeatureOffset& f : cal.feature_offsets) {
    EXPECT_TRUE(ids.insert(f.landmark_id).second) << f.landmark_id;  // once
    EXPECT_TRUE(sighted.count(f.landmark_id)) << f.landmark_id;
  }
  EXPECT_FALSE(ids.empty());
  for (size_t i = k + 1; i < d.steps.size(); ++i) EXPECT_TRUE(ekf.process(d.steps[i]).pose.isFinite());
}

TEST(EkfCalibration, AConsideredCalibrationStaysAsGivenAndMakesTheCovarianceHonest) {
  // The planted-error world. Considered (a Schmidt gain), the calibration is never updated: it
  // ends as given, with exactly its prior covariance; the pose's covariance carries its
  // uncertainty, so the filter is consistent where the EKF that takes the given calibration as
  // exact is not, and it tracks better for it (its gate keeps the sightings the over-confident
  // filter rejects).
  const Dataset d = plantedErrorWorld(nullptr);
  EkfConfig considering = calibratingEkf(d, "odometry,stereo");
  considering.calibration.consider = true;
  Ekf ekf(d.map, d.odometry, considering);
  for (const Step& s : d.steps) ekf.process(s);
  const std::optional<CalibrationEstimate> cal = ekf.calibration();
  ASSERT_TRUE(cal);
  const SelfCalibrationConfig& k = considering.calibration;
  const double w = d.odometry.wheel_base_mm;
  EXPECT_EQ(cal->wheels, Eigen::Vector3d(1.0, 1.0, w));
  EXPECT_NEAR(std::sqrt(cal->wheels_covariance(0, 0)), k.wheel_scale_sigma, 1e-12);
  EXPECT_NEAR(std::sqrt(cal->wheels_covariance(2, 2)), k.wheel_base_rel_sigma * w, 1e-9);
  EXPECT_EQ(cal->head, CalibrationEstimate().head);
  EXPECT_NEAR(std::sqrt(cal->head_covariance(1, 1)), k.baseline_scale_sigma, 1e-12);
  EXPECT_NEAR(std::sqrt(cal->head_covariance(2, 2)), k.disparity_offset_sigma_px, 1e-12);
  const std::vector<Estimate> est = ekf.finish(), given = runEkf(d, ekfKnownStart(d));
  const double nees = meanNees(d, est), nees_given = meanNees(d, given);
  EXPECT_LT(nees, 4.0);
  EXPECT_GT(nees_given, 5.0 * nees) << "considered " << nees;
  EXPECT_LT(positionRmse(d, est), positionRmse(d, given));
  // The smoothers estimate the calibration; considering it is refused there.
  BatchSmootherConfig batch;
  batch.calibration = considering.calibration;
  EXPECT_THROW(batch.validate(), Error);
}

TEST(EkfCalibration, BadSettingsAreRejected) {
  SimulationConfig sc;
  sc.scenario.steps = 5;
  const Dataset d = simulate("circle", 0, sc, 1);
  EkfConfig c = calibratingEkf(d, "odometry");
  c.max_iterations = 3;  // the iterated update does not carry the calibration
  EXPECT_THROW(Ekf(d.map, d.odometry, c), Error);
  c = calibratingEkf(d, "stereo");
  c.calibration.disparity_offset_sigma_px = -1.0;
  EXPECT_THROW(Ekf(d.map, d.odometry, c), Error);
}

}  // namespace
}  // namespace stereoloc
