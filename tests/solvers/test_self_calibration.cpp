// Self-calibration recovers planted wheel and head errors (with a disparity offset from the
// principal points) on a long simulated run, within their
// reported uncertainty, and estimates the poses better than the nominal calibration does.
#include "solvers/self_calibration.h"

#include <gtest/gtest.h>

#include <array>
#include <map>
#include <optional>

#include <cstdio>
#include <random>

#include "solvers/batch_smoother.h"
#include "solvers/sliding_window_smoother.h"
#include "src/core/error.h"
#include "src/core/exposure_offset.h"
#include "src/sim/simulator.h"
#include "test_util.h"

namespace stereoloc {
namespace {

// A random walk whose turn rate changes, its sightings identified.
Dataset randomWalk(uint64_t seed) {
  SimulationConfig sc;
  sc.scenario.steps = 300;
  Dataset d = simulate("random-walk", 0, sc, seed, nullptr);
  test::keepIdentifiedSightings(d);
  return d;
}

// Every right column as the right camera saw it tau later than the left, at the true motion
// over the step before it; returns the largest shift (px).
double plantExposureOffset(Dataset& d, double tau) {
  double largest_shift = 0;
  for (size_t k = 1; k < d.steps.size(); ++k) {
    const Pose2 a = *d.groundtruth[k - 1], b = *d.groundtruth[k];
    const double dt = d.steps[k].t - d.steps[k - 1].t;
    const BodyRate truth{std::hypot(b.x - a.x, b.y - a.y) / dt, wrapAngle(b.theta - a.theta) / dt};
    for (Observation& o : d.steps[k].observations) {
      if (!o.pixels) continue;
      const double later = rightColumnAfter(d.rig, *o.pixels, o.head_pan, truth, tau);
      largest_shift = std::max(largest_shift, std::fabs(later - o.pixels->u_right));
      o.pixels->u_right = later;
    }
  }
  return largest_shift;
}

// The batch's or the window's config for these fits: the true start, pixel columns, the head
// calibrated with the exposure offset's prior sigma_s (0: not estimated) at body rates from `rate`.
template <class Config>
Config exposureFitConfig(const Dataset& d, double sigma_s, BodyRateSource rate) {
  UnmodelledNoise noise;
  noise.exposure_offset_sigma_s = sigma_s;
  Config c;
  c.init = knownBelief(*d.groundtruth.front(), Eigen::Vector3d(1.0, 1.0, 1e-4).asDiagonal());
  c.observation_model = {ObservationModel::PixelColumns, d.rig, 0.0, noise};
  c.calibration = SelfCalibrationConfig::parse("stereo");
  c.exposure_rate = rate;
  return c;
}

// The batch on them; returns the position RMSE.
double calibratingBatch(const Dataset& d, double sigma_s, CalibrationEstimate* estimate,
                        BodyRateSource rate = BodyRateSource::SmoothedPoses) {
  BatchSmootherConfig bc = exposureFitConfig<BatchSmootherConfig>(d, sigma_s, rate);
  bc.cut_at_reinitialisation = false;
  BatchSmoother batch(d.map, d.odometry, bc);
  for (const Step& s : d.steps) batch.process(s);
  const std::vector<Estimate> out = batch.finish();
  EXPECT_EQ(batch.summary().covariance_status, CovarianceStatus::Ok);
  *estimate = batch.calibration();
  return test::positionRmse(out, d);
}

// The sliding window (W = 20, real time) on them; returns the position RMSE.
double calibratingWindow(const Dataset& d, double sigma_s, CalibrationEstimate* estimate, BodyRateSource rate) {
  SlidingWindowSmoother window(d.map, d.odometry, exposureFitConfig<SlidingWindowConfig>(d, sigma_s, rate));
  for (const Step& s : d.steps) window.process(s);
  const std::vector<Estimate> out = window.finish();
  const std::optional<CalibrationEstimate> calibration = window.calibration();
  EXPECT_TRUE(calibration.has_value());
  *estimate = calibration.value_or(CalibrationEstimate());
  return test::positionRmse(out, d);
}

TEST(SelfCalibration, ParsesTheList) {
  const SelfCalibrationConfig c = SelfCalibrationConfig::parse("stereo,odometry");
  EXPECT_TRUE(c.odometry && c.stereo);
  EXPECT_FALSE(SelfCalibrationConfig::parse("none").odometry);
  EXPECT_THROW(SelfCalibrationConfig::parse("odometry,lens"), Error);
  EXPECT_FALSE(SelfCalibrationConfig::parse("").any());  // nothing asked for
  for (const char* list : {",", "odometry,", ",stereo", "odometry,,range"})
    EXPECT_NE(test::errorOf([&] { SelfCalibrationConfig::parse(list); }).find("unknown part ''"), std::string::npos)
        << list;
}

// Both cameras' focal lengths off (1 % each): the left one's error is the focal scale psi, the
// right one's relative to it the focal ratio phi. A bearing scale error the baseline scale
// cannot take up; with psi the run determines it and the poses follow the truth.
TEST(SelfCalibration, FurthestFromPriorNamesTheParameterInPriorSigmas) {
  SelfCalibrationConfig c;  // priors: wheel scales 0.01, wheel base 4 %, baseline scale 0.02, ...
  CalibrationEstimate e;
  EXPECT_TRUE(furthestFromPrior(e, c, 75.0).parameter.empty()) << "no block estimated";
  e.odometry = e.stereo = true;
  e.wheels = Eigen::Vector3d(1.0, 1.0, 75.0);
  EXPECT_DOUBLE_EQ(furthestFromPrior(e, c, 75.0).sigmas, 0.0);
  e.wheels = Eigen::Vector3d(1.02, 0.995, 36.0);  // wheel base at about half: 13 sigmas
  e.head[1] = 0.72;                               // baseline scale 14 sigmas
  e.head[2] = -6.0;                               // disparity offset 2 sigmas
  PriorDistance far = furthestFromPrior(e, c, 75.0);
  EXPECT_EQ(far.parameter, "baseline_scale");
  EXPECT_NEAR(far.sigmas, 0.28 / 0.02, 1e-12);
  e.stereo = false;
  far = furthestFromPrior(e, c, 75.0);
  EXPECT_EQ(far.parameter, "wheel_base_mm");
  EXPECT_NEAR(far.sigmas, 39.0 / (0.04 * 75.0), 1e-12);
  EXPECT_GT(far.sigmas, kImplausiblePriorSigmas);
}

TEST(SelfCalibration, RecoversTheFocalLengthErrors) {
  SimulationConfig cfg;
  cfg.landmarks = LandmarkSet::All;
  cfg.scenario.steps = 600;
  cfg.profile.name = "focal";
  cfg.profile.focal_rel_sigma = 0.01;
  SimulationTrace trace;
  const Dataset d = simulate("random-walk", 0, cfg, 7, &trace);
  const DrawnErrors& e = trace.errors;
  const InitialBelief start = knownBelief(*d.initial_pose, Eigen::Vector3d(1.0, 1.0, 1e-4).asDiagonal());
  SelfCalibrationConfig on = SelfCalibrationConfig::parse("stereo");
  on.residuals = PixelResiduals::Columns;
  const SelfCalibrationResult r = selfCalibratingBatch(d, start, on);
  ASSERT_TRUE(r.converged);
  ASSERT_TRUE(r.covariance_ok);
  const CalibrationEstimate& c = r.calibration;
  const double psi = e.focal_rel[0], phi = (1 + e.focal_rel[1]) / (1 + e.focal_rel[0]) - 1;
  const double sd_psi = std::sqrt(c.head_covariance(5, 5)), sd_phi = std::sqrt(c.head_covariance(4, 4));
  EXPECT_NEAR(c.head[5], psi, 3 * sd_psi);
  EXPECT_LT(sd_psi, 0.5 * std::fabs(psi)) << "psi " << psi << " is not determined by the run";
  EXPECT_NEAR(c.head[4], phi, 3 * sd_phi);
  // The calibrated batch's poses are consistent with its covariance: mean NEES (3 dof) well
  // below the uncalibrated one's and near 3.
  auto meanNees = [&](const std::vector<Estimate>& est) {
    double sum = 0;
    int n = 0;
    for (size_t i = 0; i < est.size(); ++i) {
      if (!d.groundtruth[i]) continue;
      Eigen::Vector3d dx = est[i].pose.vector() - d.groundtruth[i]->vector();
      dx.z() = wrapAngle(dx.z());
      sum += dx.dot(est[i].covariance.ldlt().solve(dx));
      ++n;
    }
    return sum / n;
  };
  SelfCalibrationConfig none;
  none.residuals = PixelResiduals::Columns;
  const SelfCalibrationResult off = selfCalibratingBatch(d, start, none);
  EXPECT_LT(meanNees(r.trajectory), 6.0);
  EXPECT_LT(test::positionRmse(r.trajectory, d), 0.8 * test::positionRmse(off.trajectory, d));
}

// Floor markings come unidentified and are paired by the filter pass with the nominal
// calibration. With focal lengths 1.5 % apart the nominal disparity is off by ~2 px at the image's
// edge, several of the frontend's disparity sigmas, and markings get the wrong landmark; the
// self-calibrating batch pairs them again at the calibration the identified goal corners give.
TEST(SelfCalibration, PairsTheUnidentifiedMarkingsAtTheCalibratedSolution) {
  SimulationConfig cfg;
  cfg.landmarks = LandmarkSet::All;
  cfg.pixel_noise = PixelNoiseModel::PerKind;  // the image frontend's per-kind sigmas
  cfg.profile.name = "focal";
  cfg.profile.focal_rel_sigma = 0.0075;
  cfg.profile.principal_sigma_px = 0.5;
  double rmse_paired = 0, rmse_nominal = 0, rmse_truth = 0;
  for (uint64_t seed : {11u, 12u, 13u, 14u}) {
    const Dataset truth = simulate("circle", 0, cfg, seed);
    Dataset d = truth;
    for (Step& s : d.steps)
      for (Observation& o : s.observations)
        if (o.type != LandmarkType::GoalCorner) o.landmark_id = -1;
    auto run = [&](const Dataset& data, bool reassociate) {
      BatchSmootherConfig c;
      c.init = knownBelief(*data.initial_pose, Eigen::Vector3d(1.0, 1.0, 1e-4).asDiagonal());
      c.observation_model = {ObservationModel::PixelColumns, data.rig};
      c.calibration = SelfCalibrationConfig::parse("odometry,stereo");
      c.reassociate_with_calibration = reassociate;
      BatchSmoother b(data.map, data.odometry, c);
      for (const Step& s : data.steps) b.process(s);
      return test::positionRmse(b.finish(), data);
    };
    const double paired = run(d, true), nominal = run(d, false), known = run(truth, true);
    std::printf("seed %llu: paired again %.2f mm, nominal pairing %.2f mm, true ids %.2f mm\n",
                static_cast<unsigned long long>(seed), paired, nominal, known);
    rmse_paired += paired;
    rmse_nominal += nominal;
    rmse_truth += known;
  }
  // Seeds 11-14: 7.1 mm summed over the four runs paired again, 39.4 mm with the nominal
  // pairings (one run 32 mm off), 3.7 mm with the true ids.
  EXPECT_LT(rmse_paired, 2.0 * rmse_truth);
  EXPECT_LT(rmse_paired, 0.5 * rmse_nominal);
}

TEST(SelfCalibration, RecoversPlantedParametersOnALongRun) {
  SimulationConfig cfg;
  cfg.landmarks = LandmarkSet::All;
  cfg.scenario.steps = 1500;
  cfg.profile.name = "planted";
  cfg.profile.wheel_radius_rel_sigma = 0.01;
  cfg.profile.wheel_base_rel_sigma = 0.03;
  cfg.profile.tilt_sigma_rad = deg2rad(0.5);
  cfg.profile.baseline_rel_sigma = 0.01;
  // Principal points 2 px apart at most: a disparity offset (a relative yaw of the cameras adds
  // one too, but also a bearing-dependent part the model does not have).
  cfg.profile.principal_sigma_px = 1.0;
  SimulationTrace trace;
  const Dataset d = simulate("random-walk", 0, cfg, 22, &trace);
  const DrawnErrors& e = trace.errors;
  const InitialBelief start = knownBelief(*d.initial_pose, Eigen::Vector3d(1.0, 1.0, 1e-4).asDiagonal());

  // The columns only: a principal point's row error acts as a tilt, which the rows would fold
  // into the tilt correction.
  SelfCalibrationConfig on = SelfCalibrationConfig::parse("odometry,stereo");
  on.residuals = PixelResiduals::Columns;
  const SelfCalibrationResult r = selfCalibratingBatch(d, start, on);
  ASSERT_TRUE(r.converged);
  ASSERT_TRUE(r.covariance_ok);
  const CalibrationEstimate& c = r.calibration;
  // The disparity offset of the rectified pair: the principal points' difference.
  const double disparity_offset = e.principal_px[0][0] - e.principal_px[1][0];
  const double truth[6] = {1 + e.wheel_radius_rel[0], 1 + e.wheel_radius_rel[1], 75.0 * (1 + e.wheel_base_rel),
                           e.tilt_rad, 1 + e.baseline_rel, disparity_offset};
  const double est[6] = {c.wheels[0], c.wheels[1], c.wheels[2], c.head[0], c.head[1], c.head[2]};
  const double sd[6] = {std::sqrt(c.wheels_covariance(0, 0)), std::sqrt(c.wheels_covariance(1, 1)),
                        std::sqrt(c.wheels_covariance(2, 2)), std::sqrt(c.head_covariance(0, 0)),
                        std::sqrt(c.head_covariance(1, 1)), std::sqrt(c.head_covariance(2, 2))};
  // Planted errors are several sigma of what the run determines ...
  const double planted[6] = {e.wheel_radius_rel[0], e.wheel_radius_rel[1], 75.0 * e.wheel_base_rel, e.tilt_rad,
                             e.baseline_rel, disparity_offset};
  for (int i = 0; i < 6; ++i) {
    EXPECT_NEAR(est[i], truth[i], 3.0 * sd[i]) << "parameter " << i << " planted " << planted[i];
    if (i != 3) {  // the columns hardly see the tilt: it stays near its prior
      EXPECT_LT(sd[i], std::fabs(planted[i])) << "parameter " << i << " is not determined by the run";
    }
  }
  // ... and the poses are better for knowing them.
  SelfCalibrationConfig none;
  none.residuals = PixelResiduals::Columns;
  const SelfCalibrationResult off = selfCalibratingBatch(d, start, none);
  EXPECT_LT(test::positionRmse(r.trajectory, d), 0.8 * test::positionRmse(off.trajectory, d));

  // The written rig carries the estimate and reads back as a rig.
  test::TempDir dir;
  c.saveAsRig(dir.file("rig.yaml"), d.rig, 0.0);
  const StereoRig back = StereoRig::load(dir.file("rig.yaml"));
  EXPECT_NEAR(back.params().tilt_rad, d.rig.params().tilt_rad + c.head[0], 1e-12);
  EXPECT_NEAR(back.params().baseline_mm, d.rig.params().baseline_mm * c.head[1], 1e-9);
  // ... with the pixel corrections folded into its cameras (selfCalibratedRig), so the frontend
  // measures with them: the raw principal points differ by the disparity offset.
  ASSERT_TRUE(back.calibration());
  const StereoCalibration& cal = *back.calibration();
  const double f_raw_over_f = cal.K1.at<double>(0, 0) / ((1 + c.head[5]) * cal.rectifiedFocal());
  EXPECT_NEAR(cal.K1.at<double>(0, 2) - cal.K2.at<double>(0, 2), c.head[2] * f_raw_over_f, 1e-9);
  EXPECT_NEAR(cal.K2.at<double>(0, 0) / cal.K1.at<double>(0, 0), 1 + c.head[4], 1e-12);
}

// The image block: with a noise model that states the lens estimate's error and the cameras'
// relative rotation, the batch estimates them (whitened, back in their units) instead of
// adding them to the pixel noise; on a realistic run each lies within 3 sigma of the drawn
// truth (true minus given distortion; the right camera's rotation, pitch with the sign of its
// column term), no sigma exceeds its prior, and the pixel covariance keeps those terms only on
// the rows.
TEST(SelfCalibration, EstimatesTheImageErrorsTheNoiseModelStates) {
  SimulationConfig sc;
  sc.profile = ErrorProfile::realistic();
  sc.scenario.steps = 300;
  SimulationTrace trace;
  Dataset d = simulate("random-walk", 0, sc, 5, &trace);
  test::keepIdentifiedSightings(d);
  UnmodelledNoise noise;
  noise.k1_sigma = sc.profile.k1_estimate_sigma;
  noise.k2_sigma = sc.profile.k2_estimate_sigma;
  noise.tangential_sigma = sc.profile.tangential_estimate_sigma;
  noise.relative_rotation_sigma_rad = sc.profile.relative_rotation_sigma_rad;
  BatchSmootherConfig bc;
  bc.init = knownBelief(*d.groundtruth.front(), Eigen::Vector3d(1.0, 1.0, 1e-4).asDiagonal());
  bc.observation_model = {ObservationModel::PixelColumns, d.rig, 0.0, noise};
  bc.calibration = SelfCalibrationConfig::parse("stereo");
  bc.cut_at_reinitialisation = false;
  const std::optional<CalibrationEstimate::ImageVector> sigmas = imageErrorSigmas(bc.calibration, noise);
  ASSERT_TRUE(sigmas);
  BatchSmoother b(d.map, d.odometry, bc);
  for (const Step& s : d.steps) b.process(s);
  b.finish();
  ASSERT_EQ(b.summary().covariance_status, CovarianceStatus::Ok);
  const CalibrationEstimate& c = b.calibration();
  ASSERT_TRUE(c.image);
  const DrawnErrors& e = trace.errors;
  CalibrationEstimate::ImageVector truth;
  for (int cam = 0; cam < 2; ++cam)
    for (int j = 0; j < 4; ++j) truth[4 * cam + j] = e.distortion[cam][j] - e.distortion_given[cam][j];
  truth.tail<3>() << -e.relative_rotation_rad[0], e.relative_rotation_rad[1], e.relative_rotation_rad[2];
  for (int i = 0; i < 11; ++i) {
    const double sd = std::sqrt(c.image_covariance(i, i));
    EXPECT_GT(sd, 0.0) << "image error " << i;
    EXPECT_LE(sd, (*sigmas)[i] * (1 + 1e-9)) << "image error " << i;
    EXPECT_NEAR(c.image_errors[i], truth[i], 3 * sd) << "image error " << i;
  }
  // The run informs the lens terms: k1 of both cameras ends well inside its prior.
  EXPECT_LT(std::sqrt(c.image_covariance(0, 0)), 0.7 * (*sigmas)[0]);
  EXPECT_LT(std::sqrt(c.image_covariance(4, 4)), 0.7 * (*sigmas)[4]);
  const double sd_k = std::sqrt(c.head_covariance(1, 1));
  EXPECT_NEAR(c.head[1], 1 + e.baseline_rel, 3 * sd_k);
  // Off: no image block.
  SelfCalibrationConfig off = bc.calibration;
  off.image_errors = false;
  EXPECT_FALSE(imageErrorSigmas(off, noise));
  EXPECT_FALSE(imageErrorSigmas(bc.calibration, UnmodelledNoise()));

  // The covariance of a calibrated pixel factor: the lens and rotation terms leave the columns.
  const Observation& o = d.steps[1].observations.front();
  const Landmark& lm = d.map.at(o.landmark_id);
  ObservationModelConfig without = bc.observation_model;
  without.unmodelled = UnmodelledNoise();
  const Eigen::Matrix4d full = pixelCovarianceFor(o, lm, bc.observation_model);
  const Eigen::Matrix4d C = calibratedPixelCovariance(o, lm, bc.observation_model, true);
  const Eigen::Matrix4d bare = pixelCovarianceFor(o, lm, without);
  EXPECT_TRUE(calibratedPixelCovariance(o, lm, bc.observation_model, false).isApprox(full));
  for (int i = 0; i < 4; ++i)
    for (int j = 0; j < 4; ++j) {
      const bool rows = (i == 1 || i == 3) && (j == 1 || j == 3);
      EXPECT_NEAR(C(i, j), rows ? full(i, j) : bare(i, j), 1e-12) << i << "," << j;
    }
  EXPECT_GT(full(0, 0) - bare(0, 0), 1e-4);
}

// A planted row misalignment: every sighting's right column slid by s dv with its own slide
// gain s (as the frontend reports them for marking features), on a run with the realistic
// profile's other errors. The row block, with the stated sigma as its prior, recovers dv within
// its reported uncertainty, well inside the prior, with and without the image block; the slide
// stays out of the pixel factors without the row block (it is not stated).
TEST(SelfCalibration, RecoversAPlantedRowOffset) {
  SimulationConfig sc;
  sc.profile = ErrorProfile::realistic();
  sc.scenario.steps = 300;
  SimulationTrace trace;
  Dataset d = simulate("random-walk", 0, sc, 7, &trace);
  const double dv = 1.3;  // px, right rows below the left
  std::mt19937_64 rng(3);
  std::uniform_real_distribution<double> U(-1.5, 1.5);
  for (Step& s : d.steps) {
    std::vector<Observation> kept;
    for (Observation o : s.observations) {
      if (o.landmark_id < 0 || !o.pixels) continue;
      o.slide_gain = U(rng);
      o.pixels->u_right += o.slide_gain * dv;
      kept.push_back(o);
    }
    s.observations = kept;
  }
  for (bool image : {false, true}) {
    UnmodelledNoise noise;
    if (image) {
      noise.k1_sigma = sc.profile.k1_estimate_sigma;
      noise.k2_sigma = sc.profile.k2_estimate_sigma;
      noise.tangential_sigma = sc.profile.tangential_estimate_sigma;
      noise.relative_rotation_sigma_rad = sc.profile.relative_rotation_sigma_rad;
    }
    noise.row_offset_sigma_px = 1.49;
    BatchSmootherConfig bc;
    bc.init = knownBelief(*d.groundtruth.front(), Eigen::Vector3d(1.0, 1.0, 1e-4).asDiagonal());
    bc.observation_model = {ObservationModel::PixelColumns, d.rig, 0.0, noise};
    bc.calibration = SelfCalibrationConfig::parse("stereo");
    bc.cut_at_reinitialisation = false;
    ASSERT_TRUE(rowOffsetSigma(bc.calibration, noise));
    BatchSmoother b(d.map, d.odometry, bc);
    for (const Step& s : d.steps) b.process(s);
    b.finish();
    ASSERT_EQ(b.summary().covariance_status, CovarianceStatus::Ok);
    const CalibrationEstimate& c = b.calibration();
    ASSERT_TRUE(c.row);
    EXPECT_EQ(c.image, image);
    const double sd = std::sqrt(c.row_offset_variance);
    EXPECT_GT(sd, 0.0);
    EXPECT_LT(sd, 0.3 * noise.row_offset_sigma_px) << "image block " << image;
    EXPECT_NEAR(c.row_offset_px, dv, 3 * sd) << "image block " << image;
  }
  // Off, or not stated: no row block.
  UnmodelledNoise noise;
  noise.row_offset_sigma_px = 1.49;
  SelfCalibrationConfig off = SelfCalibrationConfig::parse("stereo");
  off.row_offset = false;
  EXPECT_FALSE(rowOffsetSigma(off, noise));
  EXPECT_FALSE(rowOffsetSigma(SelfCalibrationConfig::parse("odometry"), noise));
  EXPECT_FALSE(rowOffsetSigma(SelfCalibrationConfig::parse("stereo"), UnmodelledNoise()));
}

// A planted exposure offset: every right column as the right camera saw it 4 ms after the left,
// on a random walk whose turn rate changes (so that the offset is not one constant disparity
// offset). With the noise model's sigma of the offset the image block estimates it within its
// reported uncertainty, well inside its prior, and the poses come out no further from the truth
// than without it (the disparity offset takes the offset's mean); the rig written back carries it.
TEST(SelfCalibration, RecoversAPlantedExposureOffset) {
  Dataset d = randomWalk(9);
  const double tau = 0.004;  // s
  ASSERT_GT(plantExposureOffset(d, tau), 0.5);  // px
  auto run = [&](double sigma_s, CalibrationEstimate* estimate) { return calibratingBatch(d, sigma_s, estimate); };
  const double prior = 0.005;  // s
  CalibrationEstimate with, without;
  const double rmse_with = run(prior, &with), rmse_without = run(0.0, &without);
  ASSERT_TRUE(with.image);
  EXPECT_FALSE(without.image);
  constexpr int k = stereo_pixel_calibration::kExposureOffsetEntry;
  const double sd = std::sqrt(with.image_covariance(k, k));
  EXPECT_GT(sd, 0.0);
  EXPECT_LT(sd, 0.3 * tau);
  EXPECT_NEAR(with.image_errors[k], tau, 3 * sd);
  EXPECT_LT(rmse_with, rmse_without);
  std::printf("exposure offset %.2f +- %.2f ms (planted %.1f); RMSE %.2f mm, without %.2f mm\n",
              1e3 * with.image_errors[k], 1e3 * sd, 1e3 * tau, rmse_with, rmse_without);
  // The rig written back carries the offset, the file its sigma, which a next run takes as its prior.
  test::TempDir dir;
  with.saveAsRig(dir.file("rig.yaml"), d.rig, 0.0);
  EXPECT_NEAR(StereoRig::load(dir.file("rig.yaml")).params().exposure_offset_s, with.image_errors[k], 1e-12);
  const CalibrationHandover handover = CalibrationHandover::load(dir.file("rig.yaml"));
  ASSERT_TRUE(handover.exposure_offset_sigma_s);
  EXPECT_NEAR(*handover.exposure_offset_sigma_s, sd, 1e-12);
  SelfCalibrationConfig config;
  UnmodelledNoise next;
  next.exposure_offset_sigma_s = prior;
  handover.applyPriors(config, next);
  EXPECT_NEAR(next.exposure_offset_sigma_s, sd, 1e-12);
  UnmodelledNoise unstated;  // the noise model does not state it: it stays unestimated
  handover.applyPriors(config, unstated);
  EXPECT_EQ(unstated.exposure_offset_sigma_s, 0.0);
}

// randomWalk(seed) with wheels noisier by extra_k (mm^2/mm), stated as such.
Dataset noisyWheelWalk(uint64_t seed, double extra_k) {
  Dataset d = randomWalk(seed);
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> unit;
  for (Step& s : d.steps) {
    s.d_left += std::sqrt(extra_k * std::fabs(s.d_left)) * unit(rng);
    s.d_right += std::sqrt(extra_k * std::fabs(s.d_right)) * unit(rng);
  }
  d.odometry.k_left += extra_k;
  d.odometry.k_right += extra_k;
  return d;
}

// The offset is fitted against each image's turn rate from the smoothed poses, not the wheels'.
// With wheels five times noisier than the simulator's (k 0.1 mm^2/mm, stated as such) the
// wheels' rate carries their noise into the fit as if it were the truth and shrinks the offset
// towards zero by more than its sigma allows; the smoothed poses' rate does not: on three random
// walks the batch's offset comes out within 2.5 of its sigmas and, on the mean, within 5 % of the
// planted one. The sliding window in real time, its poses' factors re-made at the central
// difference of their neighbours' estimates before each solve, gives the batch's offset (within a
// tenth of its sigma); on the wheels' rate it shrinks as the batch's does.
TEST(SelfCalibration, FitsTheExposureOffsetAgainstTheSmoothedPoses) {
  const double tau = 0.004, extra_k = 0.08;  // s, mm^2/mm
  constexpr int k = stereo_pixel_calibration::kExposureOffsetEntry;
  // The batch and the window, each on the smoothed poses' and on the wheels' rate.
  enum { kBatchPoses, kBatchWheels, kWindowPoses, kWindowWheels, kRuns };
  std::array<double, kRuns> ratio{};
  for (uint64_t seed : {9u, 10u, 11u}) {
    Dataset d = noisyWheelWalk(seed, extra_k);
    ASSERT_GT(plantExposureOffset(d, tau), 0.5);  // px
    std::array<CalibrationEstimate, kRuns> e;
    calibratingBatch(d, 0.005, &e[kBatchPoses], BodyRateSource::SmoothedPoses);
    calibratingBatch(d, 0.005, &e[kBatchWheels], BodyRateSource::Odometry);
    calibratingWindow(d, 0.005, &e[kWindowPoses], BodyRateSource::SmoothedPoses);
    calibratingWindow(d, 0.005, &e[kWindowWheels], BodyRateSource::Odometry);
    for (const CalibrationEstimate& c : e) ASSERT_TRUE(c.image);
    auto ms = [&](int run) { return 1e3 * e[static_cast<size_t>(run)].image_errors[k]; };
    auto sigma = [&](int run) { return std::sqrt(e[static_cast<size_t>(run)].image_covariance(k, k)); };
    std::printf("seed %d: exposure offset %.2f +- %.2f ms (batch) and %.2f +- %.2f ms (window) at the smoothed "
                "poses' rate, %.2f and %.2f ms at the wheels' (planted %.1f)\n",
                static_cast<int>(seed), ms(kBatchPoses), 1e3 * sigma(kBatchPoses), ms(kWindowPoses),
                1e3 * sigma(kWindowPoses), ms(kBatchWheels), ms(kWindowWheels), 1e3 * tau);
    EXPECT_NEAR(ms(kBatchPoses), 1e3 * tau, 2.5e3 * sigma(kBatchPoses)) << "seed " << seed;
    EXPECT_NEAR(ms(kWindowPoses), ms(kBatchPoses), 0.1e3 * sigma(kWindowPoses)) << "seed " << seed;
    for (int run = 0; run < kRuns; ++run) ratio[static_cast<size_t>(run)] += ms(run) / (1e3 * tau) / 3.0;
  }
  EXPECT_NEAR(ratio[kBatchPoses], 1.0, 0.05);
  EXPECT_NEAR(ratio[kWindowPoses], 1.0, 0.05);
  EXPECT_LT(ratio[kBatchWheels], 0.95);
  EXPECT_LT(ratio[kWindowWheels], 0.95);
}

// Window poses whose neighbours lie more than the wheels' 0.5 s averaging window apart keep the
// wheels' rate: with images 0.3 s apart (neighbours 0.6 s) both sources give the same window.
TEST(SelfCalibration, TheWindowKeepsTheWheelsRateBetweenDistantNeighbours) {
  Dataset d = randomWalk(9);
  for (Step& s : d.steps) s.t *= 3.0;
  ASSERT_GT(plantExposureOffset(d, 0.004), 0.1);  // px
  CalibrationEstimate poses, wheels;
  const double rmse_poses = calibratingWindow(d, 0.005, &poses, BodyRateSource::SmoothedPoses);
  const double rmse_wheels = calibratingWindow(d, 0.005, &wheels, BodyRateSource::Odometry);
  constexpr int k = stereo_pixel_calibration::kExposureOffsetEntry;
  ASSERT_TRUE(poses.image && wheels.image);
  EXPECT_EQ(poses.image_errors[k], wheels.image_errors[k]);
  EXPECT_EQ(rmse_poses, rmse_wheels);
}

// Planted constant offsets per feature (its errors repeat from sighting to sighting): a column
// offset of every feature (both images) and a u_r offset of the marking features, on top of a row
// misalignment. The batch estimates each within its reported uncertainty, tighter than its prior
// where the feature is seen often, and the poses come out closer to the truth than with the
// offsets left as white noise.
TEST(SelfCalibration, RecoversPlantedFeatureOffsets) {
  SimulationConfig sc;
  sc.profile = ErrorProfile::realistic();
  sc.scenario.steps = 300;
  sc.landmarks = LandmarkSet::All;
  SimulationTrace trace;
  Dataset d = simulate("random-walk", 0, sc, 7, &trace);
  const double dv = 1.3, column_prior = 0.3, prior = 0.6;  // px
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> U(-1.5, 1.5);
  std::normal_distribution<double> N(0.0, 1.0);
  std::map<int, std::array<double, 2>> planted;  // landmark id -> (column, u_r) offset
  for (const Landmark& l : d.map.landmarks()) {
    const bool marking = l.type == LandmarkType::MarkingCorner || l.type == LandmarkType::Junction ||
                         l.type == LandmarkType::Intersection;
    if (marking || l.type == LandmarkType::GoalCorner)
      planted[l.id] = {column_prior * N(rng), marking ? prior * N(rng) : 0.0};
  }
  std::map<int, int> sightings;
  for (Step& s : d.steps) {
    std::vector<Observation> kept;
    for (Observation o : s.observations) {
      if (o.landmark_id < 0 || !o.pixels) continue;
      const auto b = planted.find(o.landmark_id);
      if (b != planted.end()) {
        if (o.type != LandmarkType::GoalCorner) o.slide_gain = U(rng);
        o.pixels->u_left += b->second[0];
        o.pixels->u_right += o.slide_gain * dv + b->second[0] + b->second[1];
        ++sightings[o.landmark_id];
      }
      kept.push_back(o);
    }
    s.observations = kept;
  }
  UnmodelledNoise noise;
  noise.row_offset_sigma_px = 1.49;
  noise.marking_feature_offset_sigma_px = noise.intersection_feature_offset_sigma_px = prior;
  noise.goal_feature_column_sigma_px = noise.marking_feature_column_sigma_px =
      noise.intersection_feature_column_sigma_px = column_prior;
  auto run = [&](bool offsets, CalibrationEstimate* estimate) {
    BatchSmootherConfig bc;
    bc.init = knownBelief(*d.groundtruth.front(), Eigen::Vector3d(1.0, 1.0, 1e-4).asDiagonal());
    bc.observation_model = {ObservationModel::PixelColumns, d.rig, 0.0, noise};
    bc.calibration = SelfCalibrationConfig::parse("stereo");
    bc.calibration.feature_offsets = offsets;
    bc.cut_at_reinitialisation = false;
    BatchSmoother b(d.map, d.odometry, bc);
    for (const Step& s : d.steps) b.process(s);
    const std::vector<Estimate> e = b.finish();
    EXPECT_EQ(b.summary().covariance_status, CovarianceStatus::Ok);
    *estimate = b.calibration();
    double sse = 0;
    for (size_t k = 0; k < e.size(); ++k) {
      const Pose2& t = *d.groundtruth[k];
      sse += std::pow(e[k].pose.x - t.x, 2) + std::pow(e[k].pose.y - t.y, 2);
    }
    return std::sqrt(sse / static_cast<double>(e.size()));
  };
  CalibrationEstimate with, without;
  const double rmse_with = run(true, &with), rmse_without = run(false, &without);
  EXPECT_TRUE(without.feature_offsets.empty());
  ASSERT_EQ(with.feature_offsets.size(), planted.size());
  int seen_often = 0;
  for (const CalibrationEstimate::FeatureOffset& f : with.feature_offsets) {
    const std::array<double, 2>& truth = planted.at(f.landmark_id);
    const bool marking = d.map.at(f.landmark_id).type != LandmarkType::GoalCorner;
    const double sd_column = std::sqrt(f.column_variance), sd = std::sqrt(f.variance);
    ASSERT_GT(sd_column, 0.0) << f.landmark_id;
    EXPECT_LE(sd_column, column_prior * (1 + 1e-9)) << f.landmark_id;
    EXPECT_NEAR(f.column_px, truth[0], 3 * sd_column) << f.landmark_id;
    if (marking) {
      ASSERT_GT(sd, 0.0) << f.landmark_id;
      EXPECT_LE(sd, prior * (1 + 1e-9)) << f.landmark_id;
      EXPECT_NEAR(f.offset_px, truth[1], 3 * sd) << f.landmark_id;
    } else {
      EXPECT_EQ(f.variance, 0.0) << "a goal corner has no u_r offset";
    }
    if (marking && sightings[f.landmark_id] >= 20) {
      ++seen_often;
      EXPECT_LT(sd, 0.5 * prior) << f.landmark_id << " seen " << sightings[f.landmark_id] << " times";
    }
  }
  EXPECT_GE(seen_often, 3);
  EXPECT_NEAR(with.row_offset_px, dv, 3 * std::sqrt(with.row_offset_variance));
  EXPECT_LT(rmse_with, rmse_without);
}

// With the row offset estimated, a marking feature's u_r term is what the slide model leaves:
// a white part growing with the slide gain above a floor the stated noise counts toward, and the
// feature's constant unless the caller estimates it; other features and entries are unchanged.
TEST(SelfCalibration, SlideResidualReplacesTheMarkingTermWithTheRowBlock) {
  const StereoRig rig;
  const auto px = rig.project(Eigen::Vector3d(600, 50, 0), 0.0);
  ASSERT_TRUE(px);
  Observation o = observationFromPixels(rig, 3, LandmarkType::MarkingCorner, *px, 0.0, 0.5);
  o.slide_gain = -2.0;
  UnmodelledNoise noise;
  noise.marking_disparity_sigma_px = 1.63;
  noise.intersection_disparity_sigma_px = 0.65;
  noise.row_offset_sigma_px = 1.49;
  noise.marking_slide_residual_sigma_px = 0.9;  // above the stated disparity sigma, sqrt(0.5)
  noise.marking_slide_residual_per_gain_px = 0.3;
  noise.marking_feature_offset_sigma_px = 0.6;
  noise.intersection_slide_residual_sigma_px = 0.28;
  noise.intersection_feature_offset_sigma_px = 0.32;
  const ObservationModelConfig model{ObservationModel::PixelColumns, rig, 0.0, noise};
  Landmark corner, goal, crossing;
  corner.type = LandmarkType::MarkingCorner;
  goal.type = LandmarkType::GoalCorner;
  crossing.type = LandmarkType::Intersection;
  const double stated = o.pixel_covariance(0, 0) + o.pixel_covariance(2, 2) - 2 * o.pixel_covariance(0, 2);
  ASSERT_NEAR(stated, 0.5, 1e-12);
  const Eigen::Matrix4d white = calibratedPixelCovariance(o, corner, model, false, false);
  const Eigen::Matrix4d slid = calibratedPixelCovariance(o, corner, model, false, true);
  const Eigen::Matrix4d offset = calibratedPixelCovariance(o, corner, model, false, true, true);
  EXPECT_NEAR(white(2, 2) - o.pixel_covariance(2, 2), 1.63 * 1.63, 1e-9);
  EXPECT_NEAR(offset(2, 2) - o.pixel_covariance(2, 2), (0.81 - 0.5) + 0.6 * 0.6, 1e-9);
  EXPECT_NEAR(slid(2, 2) - offset(2, 2), 0.36, 1e-9);
  Eigen::Matrix4d diff = white - slid;
  diff(2, 2) = 0;
  EXPECT_LT(diff.cwiseAbs().maxCoeff(), 1e-12);
  // A floor below the stated noise adds nothing of its own.
  ObservationModelConfig low = model;
  low.unmodelled.marking_slide_residual_sigma_px = 0.5;
  EXPECT_NEAR(calibratedPixelCovariance(o, corner, low, false, true, true)(2, 2) - o.pixel_covariance(2, 2), 0.36, 1e-9);
  EXPECT_NEAR(calibratedPixelCovariance(o, crossing, model, false, true)(2, 2) - o.pixel_covariance(2, 2),
              0.28 * 0.28 + 0.32 * 0.32, 1e-9);
  EXPECT_NEAR(calibratedPixelCovariance(o, crossing, model, false, true, true)(2, 2) - o.pixel_covariance(2, 2),
              0.28 * 0.28, 1e-9);
  EXPECT_TRUE(calibratedPixelCovariance(o, goal, model, false, true).isApprox(calibratedPixelCovariance(o, goal, model, false, false)));
  EXPECT_EQ(featureOffsetSigma(LandmarkType::Junction, noise).disparity, 0.6);
  EXPECT_EQ(featureOffsetSigma(LandmarkType::Intersection, noise).disparity, 0.32);
  EXPECT_EQ(featureOffsetSigma(LandmarkType::GoalCorner, noise).disparity, 0.0);
  // A column constant, not estimated, is white noise on both columns alike (the disparity keeps
  // its variance); estimated, it leaves the covariance.
  ObservationModelConfig column = model;
  column.unmodelled.goal_feature_column_sigma_px = 0.12;
  Observation g = o;
  g.type = LandmarkType::GoalCorner;
  const Eigen::Matrix4d g_white = calibratedPixelCovariance(g, goal, column, false, true);
  const Eigen::Matrix4d g_plain = calibratedPixelCovariance(g, goal, model, false, true);
  for (int i : {0, 2})
    for (int j : {0, 2}) EXPECT_NEAR(g_white(i, j) - g_plain(i, j), 0.0144, 1e-12);
  EXPECT_TRUE(calibratedPixelCovariance(g, goal, column, false, true, true).isApprox(g_plain));
  EXPECT_EQ(featureOffsetSigma(LandmarkType::GoalCorner, column.unmodelled).column, 0.12);
}

// Feature offsets for the landmarks whose kind the noise model states a constant for, only with
// the row block.
TEST(SelfCalibration, FeatureOffsetsForTheStatedLandmarksWithTheRowBlock) {
  const FieldMap map = FieldMap::miroSot();
  UnmodelledNoise noise;
  noise.row_offset_sigma_px = 1.49;
  noise.marking_feature_offset_sigma_px = 0.58;
  noise.intersection_feature_offset_sigma_px = 0.32;
  const SelfCalibrationConfig stereo = SelfCalibrationConfig::parse("stereo");
  auto isMarking = [](LandmarkType t) {
    return t == LandmarkType::MarkingCorner || t == LandmarkType::Junction || t == LandmarkType::Intersection;
  };
  size_t markings = 0, goals = 0;
  for (const Landmark& l : map.landmarks()) {
    markings += isMarking(l.type);
    goals += l.type == LandmarkType::GoalCorner;
  }
  const auto sigmas = featureOffsetSigmas(map, stereo, noise);
  ASSERT_EQ(sigmas.size(), markings);
  for (const FeatureOffsetPrior& f : sigmas) {
    EXPECT_EQ(f.sigma.disparity, map.at(f.landmark_id).type == LandmarkType::Intersection ? 0.32 : 0.58) << f.landmark_id;
    EXPECT_EQ(f.sigma.column, 0.0);
  }
  UnmodelledNoise columns = noise;
  columns.goal_feature_column_sigma_px = 0.12;
  EXPECT_EQ(featureOffsetSigmas(map, stereo, columns).size(), markings + goals);
  SelfCalibrationConfig off = stereo;
  off.feature_offsets = false;
  EXPECT_TRUE(featureOffsetSigmas(map, off, noise).empty());
  off = stereo;
  off.row_offset = false;
  EXPECT_TRUE(featureOffsetSigmas(map, off, noise).empty());
  UnmodelledNoise none = noise;
  none.marking_feature_offset_sigma_px = none.intersection_feature_offset_sigma_px = 0;
  EXPECT_TRUE(featureOffsetSigmas(map, stereo, none).empty());
}

}  // namespace
}  // namespace stereoloc
