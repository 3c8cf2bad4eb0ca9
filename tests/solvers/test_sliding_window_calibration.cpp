// Self-calibration in the sliding window: a window as long as the data is the self-calibrating
// batch (solvers/self_calibration.h), poses, calibration and covariances, with the row block and
// the per-feature offsets too; a short window carries the calibration's information through its
// marginal prior (it recovers the planted wheel and stereo errors on a realistic run, and its
// calibration covariance shrinks as data come) and estimates planted feature offsets; the block
// marginal prior factor against central differences; the gate sees a sighting with its kind's
// pixel noise.
#include <gtest/gtest.h>

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <algorithm>
#include <array>
#include <cmath>
#include <map>
#include <random>
#include <set>

#include "factors/block_marginal_prior_factor.h"
#include "factors/factor_check.h"
#include "factors/stereo_pixel_calibration_factor.h"
#include "src/core/measurement_model.h"
#include "solvers/batch_smoother.h"
#include "solvers/self_calibration.h"
#include "solvers/sliding_window_smoother.h"
#include "src/sim/simulator.h"
#include "planted_error_world.h"
#include "test_util.h"
#include "whole_data_window.h"

namespace stereoloc {
namespace {

const Eigen::Matrix3d kCalibrationStartCovariance = Eigen::Vector3d(30.0, 30.0, deg2rad(5.0)).cwiseAbs2().asDiagonal();

// A world whose only errors are the wheels' (1 % scales, 3 % wheel base), all landmarks seen.
SimulationConfig wheelErrorWorld(int steps) {
  SimulationConfig sc;
  sc.landmarks = LandmarkSet::All;
  sc.profile.name = "wheels";
  sc.profile.wheel_radius_rel_sigma = 0.01;
  sc.profile.wheel_base_rel_sigma = 0.03;
  sc.scenario.steps = steps;
  return sc;
}

// The wheel-error world's 400-step walk with sightings of identified landmarks at every fifth
// step but for a blind stretch from step 150 to 190, no compass, and the odometry noise stated
// three times too small (the prediction over-confident, as on real data).
Dataset blindStretchDrive(uint64_t seed, SimulationTrace* trace = nullptr) {
  Dataset d = simulate("random-walk", 0, wheelErrorWorld(400), seed, trace);
  for (size_t k = 0; k < d.steps.size(); ++k) {
    std::vector<Observation> kept;
    if (k % 5 == 0 && (k < 150 || k > 190))
      for (const Observation& o : d.steps[k].observations)
        if (o.landmark_id >= 0) kept.push_back(o);
    d.steps[k].observations = kept;
    d.steps[k].compass.reset();
  }
  d.odometry.k_left /= 3.0;
  d.odometry.k_right /= 3.0;
  return d;
}

Dataset realisticRun(uint64_t seed, const std::string& scenario, int steps) {
  SimulationConfig sc;
  sc.profile = ErrorProfile::realistic();
  sc.scenario.steps = steps;
  Dataset d = simulate(scenario, 0, sc, seed);
  test::keepIdentifiedSightings(d);  // the batch uses identified landmarks only
  return d;
}

SlidingWindowConfig calibratingWindow(const Dataset& d, int window) {
  SlidingWindowConfig c;
  c.window = window;
  c.init = knownBelief(*d.groundtruth.front(), kCalibrationStartCovariance);
  c.observation_model = {ObservationModel::PixelColumns, d.rig};
  c.calibration = SelfCalibrationConfig::parse("odometry,stereo");
  return c;
}

TEST(SlidingWindowCalibration, WindowAsLongAsTheDataIsTheSelfCalibratingBatch) {
  const Dataset d = realisticRun(3, "random-walk", 200);
  // Both solved to the limit of double precision, so that only the formulation could differ.
  BatchSmootherConfig bc;
  bc.init = knownBelief(*d.groundtruth.front(), kCalibrationStartCovariance);
  bc.observation_model = {ObservationModel::PixelColumns, d.rig};
  bc.calibration = SelfCalibrationConfig::parse("odometry,stereo");
  test::solveToTheLimit(bc);
  BatchSmoother b(d.map, d.odometry, bc);
  for (const Step& s : d.steps) b.process(s);
  SelfCalibrationResult batch;
  batch.trajectory = b.finish();
  batch.calibration = b.calibration();

  SlidingWindowConfig c = calibratingWindow(d, 1);
  test::solveAsTheBatch(c, d.steps.size());
  SlidingWindowSmoother win(d.map, d.odometry, c);
  for (const Step& s : d.steps) win.process(s);
  const test::SolutionGap gap = test::solutionGap(win.finish(), batch.trajectory);
  EXPECT_EQ(win.stats().marginalisations, 0);
  // mm and rad. 200 steps: on shorter walks the focal scale's correlation with the baseline scale
  // and the column offset leaves the normal equations so flat that both solvers stop some 1e-6 mm
  // apart at these tolerances.
  EXPECT_LT(gap.pose, 1e-6);
  EXPECT_LT(gap.covariance, 1e-6);
  const std::optional<CalibrationEstimate> cw = win.calibration();
  ASSERT_TRUE(cw.has_value());
  const CalibrationEstimate& cb = batch.calibration;
  EXPECT_LT((cw->wheels - cb.wheels).cwiseAbs().maxCoeff(), 1e-6);
  EXPECT_LT((cw->head - cb.head).cwiseAbs().maxCoeff(), 1e-6);
  EXPECT_LT(test::relativeDifference(cw->wheels_covariance, cb.wheels_covariance), 1e-6);
  EXPECT_LT(test::relativeDifference(cw->head_covariance, cb.head_covariance), 1e-6);
  // The estimate moved off the nominal calibration (the realistic profile plants errors).
  EXPECT_GT((cw->wheels - Eigen::Vector3d(1, 1, d.odometry.wheel_base_mm)).cwiseAbs().maxCoeff(), 1e-4);
}

// The self-calibrating batch and a window as long as the data (no gate, linearised at the
// estimate, tight tolerances) on `d` with the noise model `noise`: expects the same poses and
// covariances to 1e-6 and returns both calibrations (the batch's first).
std::pair<CalibrationEstimate, CalibrationEstimate> expectWholeDataWindowIsBatch(const Dataset& d,
                                                                                const UnmodelledNoise& noise) {
  // The image block (when the noise model states its errors) from the first step, as the batch;
  // the exposure offset's factors at the wheels' body rate, as the window in real time.
  BatchSmootherConfig bc;
  bc.exposure_rate = BodyRateSource::Odometry;
  bc.init = knownBelief(*d.groundtruth.front(), kCalibrationStartCovariance);
  bc.observation_model = {ObservationModel::PixelColumns, d.rig, 0.0, noise};
  bc.calibration = SelfCalibrationConfig::parse("odometry,stereo");
  test::solveToTheLimit(bc);
  BatchSmoother b(d.map, d.odometry, bc);
  for (const Step& s : d.steps) b.process(s);
  const std::vector<Estimate> eb = b.finish();

  SlidingWindowConfig c = calibratingWindow(d, 1);
  c.observation_model.unmodelled = noise;
  c.exposure_rate = BodyRateSource::Odometry;
  c.image_errors_after_steps = 0;
  test::solveAsTheBatch(c, d.steps.size());
  SlidingWindowSmoother win(d.map, d.odometry, c);
  for (const Step& s : d.steps) win.process(s);
  const test::SolutionGap gap = test::solutionGap(win.finish(), eb);
  EXPECT_LT(gap.pose, 1e-6);
  EXPECT_LT(gap.covariance, 1e-6);
  const std::optional<CalibrationEstimate> cw = win.calibration();
  EXPECT_TRUE(cw.has_value());
  return {b.calibration(), cw.value_or(CalibrationEstimate())};
}

// The same with the row block (the noise model states the rows' misalignment, the sightings
// slid by their slide gains times a planted one): the window's row offset and its variance are
// the batch's too.
TEST(SlidingWindowCalibration, WindowAsLongAsTheDataIsTheBatchWithTheRowBlock) {
  Dataset d = realisticRun(3, "random-walk", 200);
  std::mt19937_64 rng(9);
  std::uniform_real_distribution<double> U(-1.5, 1.5);
  for (Step& s : d.steps)
    for (Observation& o : s.observations) {
      o.slide_gain = U(rng);
      o.pixels->u_right += 1.2 * o.slide_gain;
    }
  UnmodelledNoise noise;
  noise.row_offset_sigma_px = 1.49;
  const auto [cb, calibration] = expectWholeDataWindowIsBatch(d, noise);
  const CalibrationEstimate* cw = &calibration;
  ASSERT_TRUE(cb.row);
  ASSERT_TRUE(cw->row);
  EXPECT_LT((cw->head - cb.head).cwiseAbs().maxCoeff(), 1e-6);
  EXPECT_NEAR(cw->row_offset_px, cb.row_offset_px, 1e-6);
  EXPECT_NEAR(cw->row_offset_variance, cb.row_offset_variance, 1e-6 * cb.row_offset_variance);
  EXPECT_LT(std::sqrt(cb.row_offset_variance), 0.5 * noise.row_offset_sigma_px);
  EXPECT_NEAR(cb.row_offset_px, 1.2, 3 * std::sqrt(cb.row_offset_variance));
}

// Constant offsets per feature planted into the pixels of `d` (identified sightings only, as the
// batch takes them): every goal corner's, marking corner's, junction's and intersection's column
// (both images) is off by its own b_c, a marking feature's u_r by its own b_d on top of its slide
// s dv along a row misalignment dv (s uniform in +-1.5). The noise model states them (sigmas
// column_sigma, offset_sigma, row_sigma 1.49 px) with nothing else unmodelled.
struct PlantedOffsets {
  std::map<int, std::array<double, 2>> b;  // landmark id -> (b_c, b_d) px
  UnmodelledNoise noise;
};
PlantedOffsets plantFeatureOffsets(Dataset& d, double dv, double column_sigma, double offset_sigma, uint64_t seed) {
  PlantedOffsets p;
  p.noise.row_offset_sigma_px = 1.49;
  p.noise.marking_feature_offset_sigma_px = p.noise.intersection_feature_offset_sigma_px = offset_sigma;
  p.noise.goal_feature_column_sigma_px = p.noise.marking_feature_column_sigma_px =
      p.noise.intersection_feature_column_sigma_px = column_sigma;
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> N(0.0, 1.0);
  std::uniform_real_distribution<double> U(-1.5, 1.5);
  for (const Landmark& l : d.map.landmarks()) {
    const bool marking = l.type == LandmarkType::MarkingCorner || l.type == LandmarkType::Junction ||
                         l.type == LandmarkType::Intersection;
    if (marking || l.type == LandmarkType::GoalCorner)
      p.b[l.id] = {column_sigma * N(rng), marking ? offset_sigma * N(rng) : 0.0};
  }
  for (Step& s : d.steps) {
    std::vector<Observation> kept;
    for (Observation o : s.observations) {
      if (o.landmark_id < 0 || !o.pixels) continue;
      const auto b = p.b.find(o.landmark_id);
      if (b != p.b.end()) {
        if (o.type != LandmarkType::GoalCorner) o.slide_gain = U(rng);
        o.pixels->u_left += b->second[0];
        o.pixels->u_right += o.slide_gain * dv + b->second[0] + b->second[1];
      }
      kept.push_back(o);
    }
    s.observations = kept;
  }
  return p;
}

// With feature offsets: each landmark's (b_c, b_d), a global block of the window from its first
// sighting, is the batch's too, estimate and variance (goal corners: b_c alone).
// With `image_block`, the noise model also states the lens estimate's, the cameras' relative
// rotation and the exposure offset's errors of the realistic profile, which both then estimate
// as the image block.
void expectWindowIsBatchWithFeatureOffsets(bool image_block) {
  SimulationConfig sc;
  sc.profile = ErrorProfile::realistic();
  sc.scenario.steps = 200;
  sc.landmarks = LandmarkSet::All;
  Dataset d = simulate("random-walk", 0, sc, 3);
  PlantedOffsets planted = plantFeatureOffsets(d, 1.2, 0.3, 0.6, 9);
  if (image_block) {
    const ErrorProfile& r = sc.profile;
    planted.noise.k1_sigma = r.k1_estimate_sigma;
    planted.noise.k2_sigma = r.k2_estimate_sigma;
    planted.noise.tangential_sigma = r.tangential_estimate_sigma;
    planted.noise.relative_rotation_sigma_rad = r.relative_rotation_sigma_rad;
    // and the exposure offset's, whose factors take each step's body rate
    planted.noise.exposure_offset_sigma_s = r.exposure_offset_max_s / std::sqrt(3.0);
  }
  const auto [cb, calibration] = expectWholeDataWindowIsBatch(d, planted.noise);
  const CalibrationEstimate* cw = &calibration;
  ASSERT_TRUE(cb.row);
  ASSERT_FALSE(cb.feature_offsets.empty());
  ASSERT_TRUE(cw->row);
  EXPECT_LT((cw->wheels - cb.wheels).cwiseAbs().maxCoeff(), 1e-6);
  EXPECT_LT((cw->head - cb.head).cwiseAbs().maxCoeff(), 1e-6);
  EXPECT_LT(test::relativeDifference(cw->head_covariance, cb.head_covariance), 1e-6);
  EXPECT_NEAR(cw->row_offset_px, cb.row_offset_px, 1e-6);
  EXPECT_NEAR(cw->row_offset_variance, cb.row_offset_variance, 1e-6 * cb.row_offset_variance);
  ASSERT_EQ(cb.image, image_block);
  ASSERT_EQ(cw->image, image_block);
  if (image_block) {
    EXPECT_GT(cb.image_errors.cwiseAbs().maxCoeff(), 0.0);
    EXPECT_LT((cw->image_errors - cb.image_errors).cwiseAbs().maxCoeff(), 1e-6 * cb.image_errors.cwiseAbs().maxCoeff());
    EXPECT_LT(test::relativeDifference(cw->image_covariance, cb.image_covariance), 1e-6);
  }
  // The window lists the features it fused: those seen, each with the batch's estimate.
  std::set<int> seen;
  for (const Step& s : d.steps)
    for (const Observation& o : s.observations)
      if (planted.b.count(o.landmark_id)) seen.insert(o.landmark_id);
  ASSERT_EQ(cw->feature_offsets.size(), seen.size());
  ASSERT_GE(seen.size(), 6u);
  int marking = 0;
  double largest = 0;
  for (const CalibrationEstimate::FeatureOffset& f : cw->feature_offsets) {
    ASSERT_TRUE(seen.count(f.landmark_id)) << f.landmark_id;
    const auto it = std::find_if(cb.feature_offsets.begin(), cb.feature_offsets.end(),
                                 [&](const CalibrationEstimate::FeatureOffset& g) { return g.landmark_id == f.landmark_id; });
    ASSERT_NE(it, cb.feature_offsets.end()) << f.landmark_id;
    EXPECT_NEAR(f.column_px, it->column_px, 1e-6) << f.landmark_id;
    EXPECT_NEAR(f.offset_px, it->offset_px, 1e-6) << f.landmark_id;
    EXPECT_NEAR(f.column_variance, it->column_variance, 1e-6 * it->column_variance) << f.landmark_id;
    EXPECT_NEAR(f.variance, it->variance, 1e-6 * std::max(it->variance, 1e-12)) << f.landmark_id;
    EXPECT_GT(f.column_variance, 0.0) << f.landmark_id;
    if (d.map.at(f.landmark_id).type == LandmarkType::GoalCorner) {
      EXPECT_EQ(f.offset_px, 0.0) << "a goal corner has no u_r offset";
      EXPECT_EQ(f.variance, 0.0);
    } else {
      ++marking;
      EXPECT_LT(f.variance, 0.6 * 0.6) << f.landmark_id;
    }
    largest = std::max({largest, std::abs(f.column_px), std::abs(f.offset_px)});
  }
  EXPECT_GE(marking, 2);
  EXPECT_GT(largest, 0.1);  // the planted offsets moved the estimates off zero
}

TEST(SlidingWindowCalibration, WindowAsLongAsTheDataIsTheBatchWithTheFeatureOffsets) {
  expectWindowIsBatchWithFeatureOffsets(false);
}

TEST(SlidingWindowCalibration, WindowAsLongAsTheDataIsTheBatchWithTheImageBlock) {
  expectWindowIsBatchWithFeatureOffsets(true);
}

// The image block waits for image_errors_after_steps: until then it stays at its prior mean (its
// errors in the pixel noise), then the window estimates it; an invalid count is an error.
TEST(SlidingWindowCalibration, ImageBlockWaitsForItsSteps) {
  const Dataset d = realisticRun(5, "random-walk", 60);
  const ErrorProfile r = ErrorProfile::realistic();
  SlidingWindowConfig c = calibratingWindow(d, 20);
  c.observation_model.unmodelled.k1_sigma = r.k1_estimate_sigma;
  c.observation_model.unmodelled.k2_sigma = r.k2_estimate_sigma;
  c.observation_model.unmodelled.tangential_sigma = r.tangential_estimate_sigma;
  c.observation_model.unmodelled.relative_rotation_sigma_rad = r.relative_rotation_sigma_rad;
  c.image_errors_after_steps = 30;
  SlidingWindowSmoother win(d.map, d.odometry, c);
  size_t k = 0;
  for (; k < 30; ++k) win.process(d.steps[k]);
  std::optional<CalibrationEstimate> e = win.calibration();
  ASSERT_TRUE(e && e->image);
  EXPECT_EQ(e->image_errors.cwiseAbs().maxCoeff(), 0.0) << "estimated before its steps";
  for (; k < d.steps.size(); ++k) win.process(d.steps[k]);
  e = win.calibration();
  ASSERT_TRUE(e && e->image);
  EXPECT_GT(e->image_errors.cwiseAbs().maxCoeff(), 0.0) << "not estimated after its steps";
  c.image_errors_after_steps = -1;
  EXPECT_THROW(c.validate(), Error);
}

TEST(SlidingWindowCalibration, ShortWindowEstimatesPlantedFeatureOffsets) {
  // A world whose only errors are pixel noise, a row misalignment and the planted per-feature
  // offsets (so the true calibration is the nominal head with that dv), W = 20 on a long walk.
  // Each feature's offsets come out within 3 sigma of the planted ones. Folded into white pixel
  // noise instead, the feature's constant is averaged over its sightings as if it did not repeat:
  // the head and row estimates are over-confident (their normalised error against the truth far
  // above its 7 degrees of freedom) and the poses further from the truth.
  SimulationConfig sc;
  sc.scenario.steps = 600;
  sc.landmarks = LandmarkSet::All;
  Dataset d = simulate("random-walk", 0, sc, 11);
  const double dv = 1.2;
  const PlantedOffsets planted = plantFeatureOffsets(d, dv, 0.3, 0.6, 4);
  // A gross outlier, a sighting labelled with a landmark the run has not shown yet: the step's
  // joint test sets it aside and fuses the step again without it, and the block its first
  // fusion created keeps its prior (it is the block's only information then).
  std::set<int> shown;
  size_t outlier_step = 0;
  for (size_t k = 0; k < d.steps.size() && outlier_step == 0; ++k) {
    for (const Observation& o : d.steps[k].observations) shown.insert(o.landmark_id);
    if (k < 10 || d.steps[k].observations.empty()) continue;
    for (const auto& [id, b] : planted.b)
      if (!shown.count(id)) {
        Observation bad = d.steps[k].observations.front();
        bad.landmark_id = id;
        bad.type = d.map.at(id).type;
        d.steps[k].observations.push_back(bad);
        outlier_step = k;
        break;
      }
  }
  ASSERT_GT(outlier_step, 0u);
  const CalibrationEstimate::StereoVector truth = CalibrationEstimate().head;
  struct Run {
    CalibrationEstimate cal;
    double nees = 0, rmse = 0;
  };
  auto run = [&](bool offsets) {
    SlidingWindowConfig c = calibratingWindow(d, 20);
    c.calibration = SelfCalibrationConfig::parse("stereo");
    c.calibration.feature_offsets = offsets;
    c.observation_model.unmodelled = planted.noise;
    SlidingWindowSmoother win(d.map, d.odometry, c);
    for (const Step& s : d.steps) win.process(s);
    const std::vector<Estimate> est = win.finish();
    EXPECT_EQ(win.stats().reinitialisations, 0);
    EXPECT_GE(win.stats().rejected_observations, 1);
    Run r;
    r.cal = *win.calibration();
    Eigen::Matrix<double, 7, 1> e;
    e << r.cal.head - truth, r.cal.row_offset_px - dv;
    Eigen::Matrix<double, 7, 7> C = Eigen::Matrix<double, 7, 7>::Zero();
    C.topLeftCorner<6, 6>() = r.cal.head_covariance;
    C(6, 6) = r.cal.row_offset_variance;  // its correlation with the head is not returned
    r.nees = e.dot(C.ldlt().solve(e));
    double sse = 0;
    for (size_t i = 0; i < est.size(); ++i) sse += (est[i].pose.translation() - d.groundtruth[i]->translation()).squaredNorm();
    r.rmse = std::sqrt(sse / static_cast<double>(est.size()));
    return r;
  };
  const Run with = run(true), without = run(false);
  EXPECT_TRUE(without.cal.feature_offsets.empty());
  ASSERT_GE(with.cal.feature_offsets.size(), 10u);
  for (const CalibrationEstimate::FeatureOffset& f : with.cal.feature_offsets) {
    const std::array<double, 2>& b = planted.b.at(f.landmark_id);
    EXPECT_NEAR(f.column_px, b[0], 3 * std::sqrt(f.column_variance)) << f.landmark_id;
    if (f.variance > 0) {
      EXPECT_NEAR(f.offset_px, b[1], 3 * std::sqrt(f.variance)) << f.landmark_id;
    }
  }
  const double chi2_7 = 18.48;  // the 0.99 quantile of 7 degrees of freedom
  EXPECT_LT(with.nees, chi2_7) << "folded into white noise: " << without.nees;
  EXPECT_GT(without.nees, chi2_7) << "estimated: " << with.nees;
  EXPECT_LT(with.rmse, without.rmse) << "mm";
}

TEST(SlidingWindowCalibration, ShortWindowCarriesTheCalibrationThroughTheMarginalPrior) {
  // A random walk in a world with only the errors the blocks model (wheel radii and base, head
  // tilt, baseline), W = 20: the calibration stays in the window and the marginal prior carries
  // what the marginalised poses knew of it, so its uncertainty keeps shrinking long after the
  // first poses left and ends near the whole-data batch's (a window that dropped it would keep
  // a window's worth of information).
  SimulationConfig sc;
  sc.profile.name = "modelled";
  sc.profile.wheel_radius_rel_sigma = 0.005;
  sc.profile.wheel_base_rel_sigma = 0.02;
  sc.profile.baseline_rel_sigma = 0.01;
  sc.profile.tilt_sigma_rad = deg2rad(0.5);
  sc.scenario.steps = 400;
  const Dataset d = simulate("random-walk", 0, sc, 5);
  SlidingWindowConfig c = calibratingWindow(d, 20);
  SlidingWindowSmoother win(d.map, d.odometry, c);
  Eigen::VectorXd early;
  for (size_t k = 0; k < d.steps.size(); ++k) {
    win.process(d.steps[k]);
    if (k == 60) {
      const CalibrationEstimate e = *win.calibration();
      early.resize(3 + e.head.size());
      early << e.wheels_covariance.diagonal(), e.head_covariance.diagonal();
    }
  }
  win.finish();
  EXPECT_GT(win.stats().marginalisations, 300);
  EXPECT_EQ(win.stats().reinitialisations, 0);
  const CalibrationEstimate cw = *win.calibration();
  SelfCalibrationConfig bc = SelfCalibrationConfig::parse("odometry,stereo");
  bc.residuals = PixelResiduals::Columns;
  const SelfCalibrationResult batch = selfCalibratingBatch(d, c.init, bc);
  const CalibrationEstimate& cb = batch.calibration;
  const int n = 3 + static_cast<int>(cw.head.size());
  Eigen::VectorXd vw(n), vb(n), xw(n), xb(n);
  vw << cw.wheels_covariance.diagonal(), cw.head_covariance.diagonal();
  vb << cb.wheels_covariance.diagonal(), cb.head_covariance.diagonal();
  xw << cw.wheels, cw.head;
  xb << cb.wheels, cb.head;
  for (int i = 0; i < n; ++i) {
    if (i != 3) {  // pixel columns hardly see the tilt
      EXPECT_LT(vw(i), 0.5 * early(i)) << "parameter " << i;
    }
    EXPECT_LT(std::sqrt(vw(i)), 1.5 * std::sqrt(vb(i))) << "parameter " << i;
    EXPECT_LT(std::abs(xw(i) - xb(i)), 2.0 * std::sqrt(vw(i))) << "parameter " << i;
  }
}

TEST(SlidingWindowCalibration, SparseSightingsKeepTheKeyframeSpanAndRecoverTheWheels) {
  // Sightings at every sixth step only: the steps between keyframes are composed into one
  // calibrated odometry factor, so W = 20 keyframes span as many steps as without calibration,
  // and the window recovers the planted wheel scales and wheel base as the batch does.
  const SimulationConfig sc = wheelErrorWorld(900);
  SimulationTrace trace;
  Dataset d = simulate("random-walk", 0, sc, 22, &trace);
  for (size_t k = 0; k < d.steps.size(); ++k) {
    std::vector<Observation> kept;
    if (k % 6 == 0)
      for (const Observation& o : d.steps[k].observations)
        if (o.landmark_id >= 0) kept.push_back(o);
    d.steps[k].observations = kept;
    d.steps[k].compass.reset();
  }
  const Eigen::Vector3d truth = test::drawnWheels(trace);

  SlidingWindowConfig plain;
  plain.window = 20;
  plain.init = knownBelief(*d.groundtruth.front(), kCalibrationStartCovariance);
  SlidingWindowConfig calibrating = plain;
  calibrating.calibration = SelfCalibrationConfig::parse("odometry");
  SlidingWindowSmoother a(d.map, d.odometry, plain), b(d.map, d.odometry, calibrating);
  for (const Step& s : d.steps) {
    a.process(s);
    b.process(s);
  }
  b.finish();
  // Keyframes: the sighting steps, plus one per restart (the uncalibrated window, with the
  // planted wheel errors, loses the robot twice; the calibrating one at most that often).
  EXPECT_LE(b.stats().reinitialisations, a.stats().reinitialisations);
  EXPECT_LE(b.stats().keyframes - b.stats().reinitialisations, a.stats().keyframes - a.stats().reinitialisations);
  EXPECT_LT(b.stats().keyframes, static_cast<long>(d.steps.size()) / 5);
  const CalibrationEstimate cw = *b.calibration();
  const SelfCalibrationResult batch = selfCalibratingBatch(d, calibrating.init, SelfCalibrationConfig::parse("odometry"));
  ASSERT_TRUE(batch.converged);
  const CalibrationEstimate& cb = batch.calibration;
  const Eigen::Vector3d prior_sigma(0.01, 0.01, 0.04 * 75.0);
  for (int i = 0; i < 3; ++i) {
    const double sw = std::sqrt(cw.wheels_covariance(i, i)), sb = std::sqrt(cb.wheels_covariance(i, i));
    EXPECT_NEAR(cw.wheels(i), truth(i), 3.0 * sw) << "parameter " << i;
    EXPECT_NEAR(cw.wheels(i), cb.wheels(i), sb) << "parameter " << i;
    EXPECT_LT(sw, 0.5 * prior_sigma(i)) << "parameter " << i << " is not determined by the run";
    EXPECT_LT(sw, 1.5 * sb) << "parameter " << i;
  }
}

TEST(SlidingWindowCalibration, CalibratedObservationInvertsTheCalibratedPixelModel) {
  const StereoRig rig;
  const Pose2 pose(400.0, 300.0, deg2rad(20.0));
  const Eigen::Vector3d landmark(1300.0, 650.0, 0.0);
  const double pan = deg2rad(5.0);
  // Pixels the calibrated cameras see: the factor's residual with z = 0 and unit information.
  auto pixelsFor = [&](const CalibrationEstimate::StereoVector& q) {
    std::unique_ptr<ceres::CostFunction> f(StereoPixelCalibrationFactor::Create(
        rig, landmark, StereoPixels{}, pan, Eigen::Matrix4d::Identity(), PixelResiduals::All));
    const double* blocks[2] = {nullptr, q.data()};
    const double x[3] = {pose.x, pose.y, pose.theta};
    blocks[0] = x;
    Eigen::Vector4d r;
    EXPECT_TRUE(f->Evaluate(blocks, r.data(), nullptr));
    return StereoPixels{r(0), r(1), r(2), r(3)};
  };
  const Eigen::Vector2d truth = predictRangeBearing(pose, landmark.head<2>());
  const Eigen::Matrix4d C = isotropicPixelCovariance(0.5);
  // At the nominal calibration with no uncertainty: the rig's own triangulation (5.26, 5.32).
  const CalibrationEstimate nominal;
  const StereoPixels px0 = pixelsFor(nominal.head);
  const Observation o0 = observationFromPixels(rig, 3, LandmarkType::GoalCorner, px0, pan, C);
  const Observation c0 = calibratedObservation(o0, rig, nominal.head, CalibrationEstimate::StereoMatrix::Zero(), C);
  EXPECT_NEAR(c0.range, o0.range, 1e-9 * o0.range);
  EXPECT_NEAR(c0.bearing, o0.bearing, 1e-12);
  EXPECT_LT((c0.covariance - o0.covariance).cwiseAbs().maxCoeff(), 1e-5 * o0.covariance.cwiseAbs().maxCoeff());
  EXPECT_NEAR(c0.range, truth(0), 1e-6);
  // A planted calibration: the given rig's triangulation is biased, the calibrated one is not.
  CalibrationEstimate::StereoVector q;
  q << deg2rad(0.8), 1.015, -2.0, 0.7, 0.006, -0.004;
  const StereoPixels px = pixelsFor(q);
  const Observation o = observationFromPixels(rig, 3, LandmarkType::GoalCorner, px, pan, C);
  EXPECT_GT(std::abs(o.range - truth(0)), 100.0);
  const CalibrationEstimate::StereoVector sq = (CalibrationEstimate::StereoVector() << 0.01, 0.01, 1.0, 0.5, 0.005, 0.005).finished();
  const CalibrationEstimate::StereoMatrix Cq = sq.cwiseAbs2().asDiagonal();
  const Observation c = calibratedObservation(o, rig, q, Cq, C);
  EXPECT_NEAR(c.range, truth(0), 1e-6 * truth(0));
  EXPECT_NEAR(angleDiff(c.bearing, truth(1)), 0.0, 1e-9);
  // The calibration's uncertainty widens R: a 1 px disparity sigma at this range is more than
  // the pixels' own 0.5 px.
  const Observation exact = calibratedObservation(o, rig, q, CalibrationEstimate::StereoMatrix::Zero(), C);
  EXPECT_GT(c.covariance(0, 0), 2.0 * exact.covariance(0, 0));
  EXPECT_GT(c.covariance(1, 1), exact.covariance(1, 1));
  // A correction that leaves no disparity cannot be triangulated.
  CalibrationEstimate::StereoVector far = q;
  far(2) = px.u_left - px.u_right + 1.0;
  EXPECT_THROW(calibratedObservation(o, rig, far, Cq, C), GeometryError);
}

TEST(SlidingWindowCalibration, LearnsADisparityOffsetTheGivenCalibrationGatesOut) {
  // The given calibration's principal points are 5.2 px apart from the true ones' difference
  // (seed 4 of a 2 px profile): every goal corner's range is off by up to a third. Gated with
  // the given calibration, the first sightings look like outliers, the calibration learns from
  // the few near ones only and the window loses the robot (position RMSE 61 mm, disparity offset
  // 3 sigma off). Gated through the current calibration estimate, it keeps every sighting.
  SimulationConfig sc;
  sc.profile.name = "principal_points";
  sc.profile.principal_sigma_px = 2.0;
  sc.scenario.steps = 60;
  SimulationTrace trace;
  const Dataset d = simulate("circle", 0, sc, 4, &trace);
  const double dd = trace.errors.principal_px[0][0] - trace.errors.principal_px[1][0];
  ASSERT_LT(dd, -5.0);
  SlidingWindowConfig c = calibratingWindow(d, 20);
  SlidingWindowSmoother win(d.map, d.odometry, c);
  for (const Step& s : d.steps) win.process(s);
  const std::vector<Estimate> est = win.finish();
  EXPECT_EQ(win.stats().reinitialisations, 0);
  EXPECT_EQ(win.stats().reanchorings, 0);
  EXPECT_EQ(win.stats().rejected_observations, 0);
  const CalibrationEstimate cw = *win.calibration();
  EXPECT_LT(std::abs(cw.head(2) - dd), 2.0 * std::sqrt(cw.head_covariance(2, 2)));
  double sse = 0;
  for (size_t i = 0; i < est.size(); ++i) {
    const Pose2& t = *d.groundtruth[i];
    sse += std::pow(est[i].pose.x - t.x, 2) + std::pow(est[i].pose.y - t.y, 2);
  }
  EXPECT_LT(std::sqrt(sse / static_cast<double>(est.size())), 15.0);
}

// The number of a junction's sightings the window fuses, from a pose known to a millimetre on a
// rig known to a hundredth of a pixel, when the right image finds it `disparity_error_px` left
// of its true column and its kind's stated disparity noise is 3 px.
long fusedJunctionSightings(double disparity_error_px) {
  const FieldMap map = FieldMap::miroSot();
  const StereoRig rig;
  const auto junction = std::find_if(map.landmarks().begin(), map.landmarks().end(),
                                     [](const Landmark& l) { return l.type == LandmarkType::Junction; });
  EXPECT_NE(junction, map.landmarks().end());
  // 350 mm from it, facing it from the field's centre side.
  const Eigen::Vector2d towards = junction->xy().normalized();
  const Eigen::Vector2d at = junction->xy() - 350.0 * towards;
  const Pose2 pose(at.x(), at.y(), std::atan2(towards.y(), towards.x()));
  const Eigen::Vector2d local = transformToLocal(pose, junction->xy());
  std::optional<StereoPixels> px = rig.project(Eigen::Vector3d(local.x(), local.y(), junction->position.z()), 0.0);
  EXPECT_TRUE(px.has_value());
  if (!px) return -1;
  px->u_right -= disparity_error_px;
  SlidingWindowConfig c;
  c.window = 5;
  c.init = knownBelief(pose, Eigen::Vector3d(1.0, 1.0, 1e-3).cwiseAbs2().asDiagonal());
  c.observation_model = {ObservationModel::PixelColumns, rig};
  c.observation_model.unmodelled.marking_disparity_sigma_px = 3.0;
  c.calibration = SelfCalibrationConfig::parse("stereo");
  c.calibration.tilt_sigma_rad = 1e-5;
  c.calibration.baseline_scale_sigma = 1e-5;
  c.calibration.disparity_offset_sigma_px = 0.01;
  c.calibration.column_offset_sigma_px = 0.01;
  c.calibration.focal_ratio_sigma = 1e-5;
  c.calibration.focal_scale_sigma = 1e-5;
  SlidingWindowSmoother win(map, OdometryParams(), c);
  Step s;
  s.observations = {observationFromPixels(rig, -1, LandmarkType::Junction, *px, 0.0, 0.5)};
  win.process(s);
  return win.stats().accepted_observations;
}

TEST(SlidingWindowCalibration, GatesASightingWithTheDisparityNoiseOfItsKind) {
  // The gate and the association see a sighting with the pixel noise its factor states: a
  // marking's corner is found on the left's row and slides along the marking in the right
  // image, so 5 px off in disparity is within its noise (d^2 about 3), although 7 times the
  // 0.7 px the columns' own noise gives a disparity. 15 px off it is gated (d^2 about 24).
  EXPECT_EQ(fusedJunctionSightings(0.0), 1);
  EXPECT_EQ(fusedJunctionSightings(5.0), 1);
  EXPECT_EQ(fusedJunctionSightings(15.0), 0);
}

TEST(SlidingWindowCalibration, CalibratedStepJacobianMatchesCentralDifferences) {
  // A chain of steps through one wheel calibration: a curve, a straight step (alpha near 0, the
  // series branch), a turn on the spot (v = 0) and a reverse arc.
  const double steps[4][2] = {{12.0, 15.0}, {9.0, 9.0 + 1e-5}, {-6.0, 6.0}, {-10.0, -7.5}};
  OdometryParams p;
  const Eigen::Vector3d c0(1.02, 0.97, 81.0);
  auto chain = [&](const Eigen::Vector3d& c, Eigen::Matrix3d* J) {
    PosePrediction r{Pose2(), Eigen::Matrix3d::Zero()};
    for (const auto& s : steps) r = predictCalibratedStep(r.pose, r.covariance, s[0], s[1], c, p, J);
    return r;
  };
  Eigen::Matrix3d J = Eigen::Matrix3d::Zero();
  const PosePrediction r = chain(c0, &J);
  // The pose and covariance are predictPose's at the scaled increments and the calibrated base.
  OdometryParams pc = p;
  pc.wheel_base_mm = c0(2);
  PosePrediction q{Pose2(), Eigen::Matrix3d::Zero()};
  for (const auto& s : steps) q = predictPose(q.pose, q.covariance, c0(0) * s[0], c0(1) * s[1], pc);
  EXPECT_LT(minus(r.pose, q.pose).cwiseAbs().maxCoeff(), 1e-12);
  EXPECT_LT((r.covariance - q.covariance).cwiseAbs().maxCoeff(), 1e-12);
  const double h[3] = {1e-6, 1e-6, 1e-4};
  for (int i = 0; i < 3; ++i) {
    Eigen::Vector3d plus_c = c0, minus_c = c0;
    plus_c(i) += h[i];
    minus_c(i) -= h[i];
    const Eigen::Vector3d numeric = minus(chain(plus_c, nullptr).pose, chain(minus_c, nullptr).pose) / (2.0 * h[i]);
    EXPECT_LT((J.col(i) - numeric).norm(), 1e-6 * std::max(1.0, numeric.norm())) << "column " << i << ": "
                                                                                   << J.col(i).transpose() << " vs "
                                                                                   << numeric.transpose();
  }
}

TEST(SlidingWindowCalibration, PredictionAcrossABlindStretchIsTheWindowsMarginal) {
  // The gate tests a step's sightings against the prediction of its pose from the newest
  // keyframe. With the wheels self-calibrated that prediction goes through the estimated
  // calibration, so its covariance must hold the calibration's uncertainty and its correlation
  // with the keyframe: it is then the marginal of the predicted pose in the window, which is what
  // a window that makes the blind step a keyframe (no new information) reports. Without those
  // terms the prediction after a blind stretch is over-confident, and the gate rejects the
  // sightings that disagree with the current calibration estimate, those that would correct it.
  const SimulationConfig sc = wheelErrorWorld(160);
  Dataset d = simulate("random-walk", 0, sc, 22);
  d.odometry.readings = OdometryReadings::Commands;  // the factors' noise at the readings, as the prediction's
  const size_t blind_from = 100, blind = 40;
  for (size_t k = 0; k < d.steps.size(); ++k) {
    d.steps[k].compass.reset();
    if (k >= blind_from) d.steps[k].observations.clear();
  }
  SlidingWindowConfig predicting;
  predicting.window = 20;
  predicting.init = knownBelief(*d.groundtruth.front(), kCalibrationStartCovariance);
  predicting.calibration = SelfCalibrationConfig::parse("odometry");
  predicting.function_tolerance = predicting.parameter_tolerance = predicting.gradient_tolerance = 1e-14;
  SlidingWindowConfig keyframing = predicting;
  keyframing.keyframe_max_steps = static_cast<int>(blind);
  SlidingWindowSmoother a(d.map, d.odometry, predicting), b(d.map, d.odometry, keyframing);
  Estimate ea, eb;
  for (size_t k = 0; k < blind_from + blind; ++k) {
    ea = a.process(d.steps[k]);
    eb = b.process(d.steps[k]);
    if (k + 1 == blind_from) {
      ASSERT_EQ(a.stats().keyframes, b.stats().keyframes);
    }
  }
  ASSERT_EQ(b.stats().keyframes, a.stats().keyframes + 1);  // the blind step is b's keyframe only
  ASSERT_EQ(ea.status, EstimateStatus::Predicted);
  EXPECT_LT(minus(ea.pose, eb.pose).cwiseAbs().maxCoeff(), 1e-3);
  // The calibration's share of the marginal is large enough to matter...
  const Eigen::Matrix3d Pc = eb.covariance, Pa = ea.covariance;
  const CalibrationEstimate cal = *a.calibration();
  EXPECT_GT(std::sqrt(cal.wheels_covariance(2, 2)), 0.2);  // mm: the wheel base is not yet known
  // ...and the prediction holds it: equal to the marginal to within the noise models' difference
  // (the factor's wheel variance at c times the reading, the prediction's at the reading).
  const Eigen::LLT<Eigen::Matrix3d> L(Pc);
  const Eigen::Matrix3d M = L.matrixL().solve(L.matrixL().solve(Pa).transpose());  // Lc^-1 Pa Lc^-T
  const Eigen::Vector3d ev = Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(0.5 * (M + M.transpose())).eigenvalues();
  EXPECT_GT(ev.minCoeff(), 0.95) << "prediction " << Pa.diagonal().transpose() << ", marginal " << Pc.diagonal().transpose();
  EXPECT_LT(ev.maxCoeff(), 1.05) << "prediction " << Pa.diagonal().transpose() << ", marginal " << Pc.diagonal().transpose();
}

TEST(SlidingWindowCalibration, ALossThatIsNoKidnapKeepsTheOdometryAcrossIt) {
  // The odometry noise stated three times too small (the prediction over-confident, as on real
  // data) and a 40-step blind stretch: the gate rejects the first sightings after it, the robot
  // is declared lost, and the fix disagrees with the prediction by far less than a kidnap's d^2
  // (the restart_min_evidence). Restarting there (the chi-square test alone, restart_min_evidence = 0) cuts the
  // odometry and drops the sightings that disagreed with the odometry through the current wheel
  // estimate, the evidence that would correct it; re-anchoring keeps both.
  double se_restart = 0, se_default = 0;
  long n = 0, restarts_chi2 = 0;
  for (uint64_t seed = 1; seed <= 6; ++seed) {
    const Dataset d = blindStretchDrive(seed);
    for (const bool chi2_alone : {true, false}) {
      SlidingWindowConfig c;
      c.window = 20;
      c.init = knownBelief(*d.groundtruth.front(), kCalibrationStartCovariance);
      c.calibration = SelfCalibrationConfig::parse("odometry");
      if (chi2_alone) c.restart_min_evidence = 0.0;
      SlidingWindowSmoother w(d.map, d.odometry, c);
      for (const Step& s : d.steps) w.process(s);
      const std::vector<Estimate> est = w.finish();
      ASSERT_EQ(est.size(), d.groundtruth.size());
      double se = 0;
      for (size_t i = 0; i < est.size(); ++i) se += (est[i].pose.translation() - d.groundtruth[i]->translation()).squaredNorm();
      if (chi2_alone) {
        restarts_chi2 += w.stats().reinitialisations;
        se_restart += se;
      } else {
        EXPECT_EQ(w.stats().reinitialisations, 0) << "seed " << seed;
        EXPECT_GE(w.stats().reanchorings, 1) << "seed " << seed;
        se_default += se;
        n += static_cast<long>(est.size());
      }
    }
  }
  EXPECT_GE(restarts_chi2, 6);  // the chi-square test alone restarts at these losses
  const double rmse_restart = std::sqrt(se_restart / static_cast<double>(n));
  const double rmse_default = std::sqrt(se_default / static_cast<double>(n));
  EXPECT_LT(rmse_default, 3.0) << "mm; restarting: " << rmse_restart;
  EXPECT_LT(rmse_default, 0.5 * rmse_restart);
}

TEST(SlidingWindowCalibration, AStepThatFailsHalfwayHandsTheCalibrationToTheNextWindow) {
  // The loss of the test above, and the global fix fails on the first call (after the step's pose
  // and its calibrated odometry factor were added): the window is given up, and its wheel
  // calibration, as the step found it, is the prior of the window the next fix starts.
  SimulationTrace trace;
  const Dataset d = blindStretchDrive(1, &trace);
  const Eigen::Vector3d truth = test::drawnWheels(trace);
  SlidingWindowConfig c;
  c.window = 20;
  c.init = knownBelief(*d.groundtruth.front(), kCalibrationStartCovariance);
  c.calibration = SelfCalibrationConfig::parse("odometry");
  const GlobalFixFunction fix = defaultGlobalFix();
  int calls = 0;
  c.global_fix = [&](const Step& s, const FieldMap& map) -> std::optional<PoseFix> {
    if (++calls == 1) throw Error("map server: no answer");
    return fix(s, map);
  };
  SlidingWindowSmoother w(d.map, d.odometry, c);
  long failed = -1;
  for (const Step& s : d.steps) {
    const CalibrationEstimate before = *w.calibration();
    try {
      w.process(s);
    } catch (const Error&) {
      ASSERT_EQ(failed, -1);
      failed = s.step;
      const CalibrationEstimate kept = *w.calibration();
      EXPECT_EQ(kept.wheels, before.wheels);
      EXPECT_EQ(kept.wheels_covariance, before.wheels_covariance);
      // Learnt before the failure: far narrower than the prior.
      EXPECT_LT(std::sqrt(kept.wheels_covariance(2, 2)), 0.25 * 0.04 * 75.0);
    }
  }
  ASSERT_GT(failed, 190);
  EXPECT_GE(w.stats().reinitialisations, 1);
  const std::vector<Estimate> est = w.finish();
  ASSERT_EQ(est.size(), d.steps.size() - 1);
  double se = 0;
  long n = 0;
  for (size_t i = 0; i < est.size(); ++i) {
    const size_t k = i < static_cast<size_t>(failed) ? i : i + 1;
    ASSERT_EQ(est[i].step, d.steps[k].step);
    if (est[i].status == EstimateStatus::Uninitialised) continue;
    se += (est[i].pose.translation() - d.groundtruth[k]->translation()).squaredNorm();
    ++n;
  }
  EXPECT_GT(n, 380);
  EXPECT_LT(std::sqrt(se / static_cast<double>(n)), 5.0) << "mm";
  const CalibrationEstimate cw = *w.calibration();
  for (int i = 0; i < 3; ++i)
    EXPECT_NEAR(cw.wheels(i), truth(i), 3.0 * std::sqrt(cw.wheels_covariance(i, i))) << "parameter " << i;
}

TEST(SlidingWindowCalibration, BlockMarginalPriorJacobianMatchesCentralDifferences) {
  std::vector<BlockMarginalPriorFactor::Block> blocks = {{Eigen::Vector3d(100.0, -50.0, 3.1), true},
                                                         {Eigen::Vector3d(1.01, 0.99, 76.0), false},
                                                         {Eigen::Vector2d(0.01, 1.02), false}};
  Eigen::MatrixXd A = Eigen::MatrixXd::Random(8, 8);
  const Eigen::MatrixXd H = A * A.transpose() + 8.0 * Eigen::MatrixXd::Identity(8, 8);
  const Eigen::VectorXd g = Eigen::VectorXd::LinSpaced(8, -1.0, 1.0);
  std::unique_ptr<ceres::CostFunction> f(BlockMarginalPriorFactor::FromInformation(blocks, H, g));
  // Across the angle wrap of the pose block: the wrapped difference keeps the residual smooth.
  const double p[3] = {101.0, -49.0, -3.1}, w[3] = {1.0, 1.0, 75.0}, h[2] = {0.0, 1.0};
  const FactorCheck check = checkFactorJacobians(*f, {p, w, h});
  EXPECT_TRUE(check.ok) << check.message;
  EXPECT_LT(check.max_relative_error, 1e-6);
  // At x0 the residual is r0, and 1/2 |r|^2 has gradient g there.
  std::vector<std::vector<double>> x0 = {{100.0, -50.0, 3.1}, {1.01, 0.99, 76.0}, {0.01, 1.02}};
  std::vector<const double*> ptr;
  for (auto& v : x0) ptr.push_back(v.data());
  Eigen::VectorXd r(8);
  ASSERT_TRUE(f->Evaluate(ptr.data(), r.data(), nullptr));
  const auto* prior = static_cast<const BlockMarginalPriorFactor*>(f.get());
  EXPECT_LT((prior->sqrtInformation().transpose() * r - g).norm(), 1e-9);
  EXPECT_THROW(BlockMarginalPriorFactor::FromInformation(blocks, -H, g), Error);
  // Singular information (no information on the head block): the eigen square root keeps
  // S^T S = H and S^T r0 = g for g in the range of H.
  Eigen::MatrixXd Hsing = H;
  Hsing.rightCols<2>().setZero();
  Hsing.bottomRows<2>().setZero();
  Eigen::VectorXd gsing = g;
  gsing.tail<2>().setZero();
  std::unique_ptr<BlockMarginalPriorFactor> sing(BlockMarginalPriorFactor::FromInformation(blocks, Hsing, gsing));
  EXPECT_LT((sing->sqrtInformation().transpose() * sing->sqrtInformation() - Hsing).cwiseAbs().maxCoeff(), 1e-9 * H.norm());
  EXPECT_LT((sing->sqrtInformation().transpose() * sing->r0() - gsing).norm(), 1e-9);
}

}  // namespace
}  // namespace stereoloc
