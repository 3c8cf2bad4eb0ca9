#include "src/pipeline/methods.h"

#include <chrono>
#include <cmath>
#include <memory>

#include "solvers/batch_smoother.h"
#include "solvers/ekf.h"
#include "solvers/calibrated_models.h"
#include "solvers/considered_fix.h"
#include "solvers/global_fix.h"
#include "solvers/particle_filter.h"
#include "solvers/sliding_window_smoother.h"
#include "src/core/odometry_delay.h"
#include "src/core/odometry_model.h"
#include "src/pipeline/usage_error.h"

namespace stereoloc {
namespace {

// Disparity error of the frontend's features matched along floor markings per pixel of row
// misalignment of the rectified pair (applyErrorProfile): the RMS u_r error measured against the
// true rectified pixels on realistic images (docs/realistic_world.md, "Noise model": 1.63 px for
// marking corners and T-junctions) over the realistic profile's stated row misalignment,
// sqrt(2 (1 px)^2 + (277 px * 0.1 deg)^2) = 1.49 px. X-intersections get none of these terms:
// the frontend locates them on the right image as on the left, so they do not slide, and their
// disparity error about each trial's constant (0.07 px RMS, no constant per feature; 181
// sightings on 10 realistic spins) is within the frontend's stated sigma_d.
constexpr double kMarkingDisparityPerRowPx = 1.63 / 1.49;
// What remains with the rows' misalignment dv estimated (UnmodelledNoise::row_offset_sigma_px):
// the disparity error of each marking feature against the true rectified pixels, less s dv (s
// the frontend's slide gain, dv the trial's mean misalignment) and less the trial's constant
// (the goal corners' mean disparity error, which the disparity offset takes), fitted by maximum
// likelihood as a constant per feature and trial plus a white part sqrt(a^2 + (c s)^2)
// (docs/realistic_world.md, "Noise model"; study seed 7, 20 trials of circle, line and spin,
// 3053 sightings of marking corners and T-junctions): a 0.185 px, c 0.318 px, the constant's
// sigma 0.583 px.
constexpr double kMarkingSlideFloorPerRowPx = 0.185 / 1.49;
constexpr double kMarkingSlidePerGainPerRowPx = 0.318 / 1.49;
constexpr double kMarkingFeatureOffsetPerRowPx = 0.583 / 1.49;
// The features' column error common to both images (the bearing), about the goal corners' mean
// of each trial (which the column offset takes), has a constant per feature and trial too: fitted
// the same way (seed 7; goal corners 5927 sightings of 160 features, marking corners and
// T-junctions 3056 of 312): 0.12 and 0.19 px; X-intersections, located on the image, 0.01 px
// (10 realistic spins), none stated. The frontend makes them (its corners on aliased edges,
// docs/estimators.md "Errors that repeat"), not the calibration, so they do not scale with the
// misalignment.
constexpr double kGoalFeatureColumnPx = 0.12;
constexpr double kMarkingFeatureColumnPx = 0.19;

using Clock = std::chrono::steady_clock;

double msSince(Clock::time_point start, size_t steps) {
  const double ms = std::chrono::duration<double, std::milli>(Clock::now() - start).count();
  return steps > 0 ? ms / steps : 0.0;
}

InitialBelief beliefFor(InitMode mode, const Dataset& d, const MethodOptions& o, std::mt19937_64& rng) {
  std::optional<Pose2> truth = d.initial_pose;
  if (!truth && !d.groundtruth.empty()) truth = d.groundtruth.front();
  if (mode == InitMode::Known && !truth)
    throw UsageError("init 'known' needs the true initial pose, and dataset '" + d.name + "' has none (use :global)");
  return makeInitialBelief(mode, truth, d.map, o.init_config, rng);
}

MethodRun runEstimator(Estimator& est, const Dataset& d) {
  MethodRun run;
  const auto start = Clock::now();
  for (const Step& s : d.steps) est.process(s);
  run.estimates = est.finish();
  run.ms_per_step = msSince(start, d.steps.size());
  return run;
}

// Dead reckoning: the known start chained through the odometry model (B.16), covariance (5.9).
MethodRun runDeadReckoning(const Dataset& d, const InitialBelief& init) {
  MethodRun run;
  if (init.mode == InitMode::Global) throw UsageError("deadreckoning needs a known or random start");
  const auto start = Clock::now();
  Pose2 pose = init.pose;
  Eigen::Matrix3d P = init.covariance;
  for (size_t i = 0; i < d.steps.size(); ++i) {
    const Step& s = d.steps[i];
    if (i > 0) {
      const PosePrediction pred = predictPose(pose, P, s.d_left, s.d_right, d.odometry);
      pose = pred.pose;
      P = pred.covariance;
    }
    run.estimates.push_back(stepEstimate(s, pose, P, EstimateStatus::Predicted));
  }
  run.ms_per_step = msSince(start, d.steps.size());
  return run;
}

// Global fixes alone, every step on its own (thesis 6.3, 6.4).
// With calibration.consider the stereo block's priors enter each fix (solvers/considered_fix.h).
MethodRun runFixes(const Dataset& d, bool one_landmark, const SelfCalibrationConfig& calibration) {
  MethodRun run;
  CalibrationEstimate::StereoMatrix Cq = CalibrationEstimate::StereoMatrix::Zero();
  if (calibration.consider) Cq.diagonal() = stereoPriorSigma(calibration).cwiseAbs2();
  GlobalFixOptions fo;
  fo.allow_one_landmark = one_landmark;
  fo.allow_two_landmarks = !one_landmark;
  fo.allow_multi = false;
  const auto start = Clock::now();
  for (const Step& s : d.steps) {
    Step st = s;
    if (st.compass && st.compass_sigma <= 0) st.compass_sigma = d.compass_sigma;
    size_t identified = 0;
    for (const Observation& o : st.observations) identified += o.landmark_id >= 0 ? 1 : 0;
    if (identified == 0) continue;
    ++run.attempted_steps;
    GlobalFix fix = globalFix(st, d.map, fo);
    if (calibration.consider) fix = considerStereoCalibration(fix, st, d.map, fo, d.rig, Cq);
    if (fix.status != FixStatus::Ok) continue;
    ++run.fixed_steps;
    run.estimates.push_back(stepEstimate(s, fix.pose, fix.covariance, EstimateStatus::Tracking));
  }
  run.ms_per_step = msSince(start, d.steps.size());
  return run;
}

// The stereo calibration block enters through the pixel factors only.
void requirePixelModelForStereoCalibration(const MethodOptions& o) {
  if (o.calibration.stereo && o.observation_model == ObservationModel::RangeBearing)
    throw UsageError("--calibrate stereo: needs a pixel observation model (--observation-model pixel_columns or pixels)");
}

}  // namespace

bool selfCalibrates(const std::string& name) {
  return name == "batch" || name == "window" || name == "ekf" || name == "pf";
}

bool considers(const std::string& name) { return name == "ekf" || name == "fix1" || name == "fix2"; }

const std::vector<std::string>& methodNames() {
  static const std::vector<std::string> names = {"fix1", "fix2", "ekf", "iekf", "pf", "window", "batch", "deadreckoning"};
  return names;
}

std::string methodNamesText() {
  std::string text;
  for (const std::string& n : methodNames()) text += (text.empty() ? "" : ", ") + n;
  return text;
}

namespace {

bool endsWith(const std::string& s, const std::string& suffix) {
  return s.size() > suffix.size() && s.compare(s.size() - suffix.size(), suffix.size(), suffix) == 0;
}

const std::string kCalibSuffix = ":calib", kConsiderSuffix = ":consider", kFieldSuffix = ":calib-field";

}  // namespace

bool hasCalibrationSuffix(const std::string& spec) { return endsWith(spec, kCalibSuffix) || hasFieldSuffix(spec); }

bool hasFieldSuffix(const std::string& spec) { return endsWith(spec, kFieldSuffix); }

bool hasConsiderSuffix(const std::string& spec) { return endsWith(spec, kConsiderSuffix); }

std::string withoutCalibrationSuffix(const std::string& spec) {
  if (hasFieldSuffix(spec)) return spec.substr(0, spec.size() - kFieldSuffix.size());
  if (hasCalibrationSuffix(spec)) return spec.substr(0, spec.size() - kCalibSuffix.size());
  if (hasConsiderSuffix(spec)) return spec.substr(0, spec.size() - kConsiderSuffix.size());
  return spec;
}

std::pair<std::string, InitMode> parseMethodSpec(const std::string& full_spec, InitMode default_init) {
  const std::string spec = withoutCalibrationSuffix(full_spec);
  const size_t colon = spec.find(':');
  const std::string name = spec.substr(0, colon);
  bool known = false;
  for (const std::string& n : methodNames()) known |= n == name;
  if (!known) throw UsageError("unknown method '" + name + "' (expected one of " + methodNamesText() + ")");
  if (hasCalibrationSuffix(full_spec) && !selfCalibrates(name))
    throw UsageError("method '" + full_spec + "': only " + kSelfCalibratingText + " self-calibrate");
  if (hasFieldSuffix(full_spec) && name != "batch" && name != "window" && name != "ekf")
    throw UsageError("method '" + full_spec + "': only batch, window and ekf estimate the field's dimensions");
  if (hasConsiderSuffix(full_spec) && !considers(name))
    throw UsageError("method '" + full_spec + "': only " + kConsideringText + " consider their calibration");
  InitMode init = default_init;
  if (colon != std::string::npos) {
    try {
      init = initModeFromString(spec.substr(colon + 1));
    } catch (const Error&) {
      throw UsageError("method '" + spec + "': unknown init '" + spec.substr(colon + 1) + "' (expected known, random or global)");
    }
  }
  return {name, init};
}

BatchSmootherConfig batchConfigFor(const std::string& spec, const Dataset& d, uint64_t seed, const MethodOptions& o) {
  const InitMode init_mode = parseMethodSpec(spec, o.init).second;
  std::mt19937_64 rng(seed);
  BatchSmootherConfig c;
  c.init = beliefFor(init_mode, d, o, rng);
  c.loss.type = o.loss;
  c.loss.scale = o.loss_scale;
  c.observation_model = {o.observation_model, d.rig, o.pixel_sigma, o.noise};
  c.slip_rel_sigma = o.noise.slip_rel_sigma;
  c.calibration = o.calibration;
  requirePixelModelForStereoCalibration(o);
  return c;
}

void applyErrorProfile(const ErrorProfile& p, double focal_px, MethodOptions& o) {
  if (p.isIdeal()) return;
  UnmodelledNoise& n = o.noise;
  n.k1_sigma = p.k1_estimate_sigma;
  n.k2_sigma = p.k2_estimate_sigma;
  n.tangential_sigma = p.tangential_estimate_sigma;
  n.pitch_sigma_rad = p.pitch_sigma_rad;
  n.roll_sigma_rad = p.roll_sigma_rad;
  n.relative_rotation_sigma_rad = p.relative_rotation_sigma_rad;
  // Rows of the rectified pair misaligned by the principal points' v difference and f times the
  // relative pitch; the frontend's marking features slide along their markings with it.
  const double row = std::hypot(std::sqrt(2.0) * p.principal_sigma_px, focal_px * p.relative_rotation_sigma_rad);
  n.marking_disparity_sigma_px = kMarkingDisparityPerRowPx * row;
  n.row_offset_sigma_px = row;
  n.marking_slide_residual_sigma_px = kMarkingSlideFloorPerRowPx * row;
  n.marking_slide_residual_per_gain_px = kMarkingSlidePerGainPerRowPx * row;
  n.marking_feature_offset_sigma_px = kMarkingFeatureOffsetPerRowPx * row;
  n.goal_feature_column_sigma_px = kGoalFeatureColumnPx;
  n.marking_feature_column_sigma_px = kMarkingFeatureColumnPx;
  // One wheel at a time on a fraction p of the steps, s uniform in [a, b]: E[s^2] per wheel
  // p / 2 (a^2 + a b + b^2) / 3.
  const double a = p.slip_min, b = p.slip_max;
  n.slip_rel_sigma = std::sqrt(0.5 * p.slip_probability * (a * a + a * b + b * b) / 3.0);
  // A wheel scale is the radius's (1 + e): its walk is the radius's.
  n.wheel_scale_drift = p.wheel_radius_drift;
  n.wheel_base_drift = p.wheel_base_drift;
  // Priors: the calibration's stated uncertainty. The disparity offset is the principal points'
  // u difference and f times the cameras' relative yaw, the column offset their means; a
  // profile without an error keeps the default prior.
  SelfCalibrationConfig& k = o.calibration;
  auto set = [](double& prior, double sigma) {
    if (sigma > 0) prior = sigma;
  };
  const double pp = p.principal_sigma_px, rot = focal_px * p.relative_rotation_sigma_rad;
  set(k.wheel_scale_sigma, p.wheel_radius_rel_sigma);
  set(k.wheel_base_rel_sigma, p.wheel_base_rel_sigma);
  set(k.tilt_sigma_rad, p.tilt_sigma_rad);
  set(k.baseline_scale_sigma, p.baseline_rel_sigma);
  set(k.disparity_offset_sigma_px, std::sqrt(2 * pp * pp + rot * rot));
  set(k.column_offset_sigma_px, std::sqrt(0.5 * pp * pp + 0.25 * rot * rot));
  set(k.focal_ratio_sigma, std::sqrt(2.0) * p.focal_rel_sigma);
  set(k.focal_scale_sigma, p.focal_rel_sigma);
}

namespace {

MethodRun runMethodOnSteps(const std::string& spec, const Dataset& d, uint64_t seed, const MethodOptions& options);

}  // namespace

std::vector<Step> stepsWithOdometryDelay(const std::string& spec, const Dataset& d, uint64_t seed,
                                         const MethodOptions& options, std::optional<OdometryDelayEstimate>* fitted) {
  if (fitted) fitted->reset();
  if (options.odometry_delay == OdometryDelayMode::None) return d.steps;
  const InitMode init = parseMethodSpec(spec, options.init).second;  // an unknown method: before any solve
  double delay = options.given_odometry_delay_s;
  if (options.odometry_delay == OdometryDelayMode::Fit) {
    // The batch with the run's options, start and self-calibration (blocks the EKF would
    // consider, the batch estimates).
    MethodOptions o = options;
    if (hasCalibrationSuffix(spec) || hasConsiderSuffix(spec)) o.calibration.odometry = o.calibration.stereo = true;
    if (hasFieldSuffix(spec)) o.calibration.field = true;
    o.calibration.consider = false;
    const BatchSmootherConfig c = batchConfigFor("batch:" + toString(init), d, seed, o);
    const OdometryDelayEstimate e = estimateOdometryDelay(d.map, d.odometry, c, d.steps, options.odometry_delay_search);
    delay = e.delay_s;
    if (fitted) *fitted = e;
  }
  return delayOdometry(d.steps, delay);
}

MethodRun runMethod(const std::string& spec, const Dataset& d, uint64_t seed, const MethodOptions& options) {
  if (options.odometry_delay == OdometryDelayMode::None) return runMethodOnSteps(spec, d, seed, options);
  std::optional<OdometryDelayEstimate> fitted;
  Dataset delayed = d;
  delayed.steps = stepsWithOdometryDelay(spec, d, seed, options, &fitted);
  MethodRun run = runMethodOnSteps(spec, delayed, seed, options);
  run.odometry_delay = fitted;
  return run;
}

namespace {

MethodRun runMethodOnSteps(const std::string& spec, const Dataset& d, uint64_t seed, const MethodOptions& options) {
  const auto [name, init_mode] = parseMethodSpec(spec, options.init);
  MethodOptions o = options;
  const bool fix = name == "fix1" || name == "fix2";
  if (hasCalibrationSuffix(spec) || hasConsiderSuffix(spec)) o.calibration.odometry = o.calibration.stereo = true;
  if (hasFieldSuffix(spec)) o.calibration.field = true;
  if (hasConsiderSuffix(spec)) o.calibration.consider = true;
  if (fix && hasConsiderSuffix(spec)) o.calibration.odometry = false;  // a fix has no odometry
  std::mt19937_64 rng(seed);
  MethodRun run;
  if (o.calibration.any() && !o.calibration.consider && !selfCalibrates(name))
    throw UsageError("--calibrate: only " + kSelfCalibratingText + " self-calibrate (method '" + spec + "')");
  if (o.calibration.consider && !considers(name))
    throw UsageError("--consider: only " + kConsideringText + " consider their calibration (method '" + spec + "')");
  if (fix && o.calibration.consider &&
      (o.calibration.odometry || o.calibration.range || o.calibration.field || !o.calibration.stereo))
    throw UsageError("--consider: a fix considers the stereo block only (method '" + spec + "')");
  if (fix) {
    run = runFixes(d, name == "fix1", o.calibration);
  } else if (name == "deadreckoning") {
    run = runDeadReckoning(d, beliefFor(init_mode, d, o, rng));
  } else if (name == "ekf" || name == "iekf") {
    EkfConfig c;
    if (name == "iekf") c.max_iterations = kIteratedEkfIterations;
    c.init = beliefFor(init_mode, d, o, rng);
    c.gate_enabled = o.gate_enabled && init_mode != InitMode::Random;
    c.calibration = o.calibration;
    c.observation_model = {o.observation_model, d.rig, o.pixel_sigma, o.noise};
    Ekf ekf(d.map, d.odometry, c);
    run = runEstimator(ekf, d);
    if (!c.calibration.consider) run.calibration = ekf.calibration();  // considered: nothing estimated
  } else if (name == "pf") {
    if (o.calibration.range || o.calibration.field)
      throw UsageError("--calibrate: the particle filter self-calibrates odometry and stereo only (method '" + spec + "')");
    ParticleFilterConfig c;
    c.init = beliefFor(init_mode, d, o, rng);
    c.particles = o.particles;
    c.proposal = o.pf_proposal;
    c.kld.enabled = o.pf_kld;
    c.calibration = o.calibration;
    c.observation_model = {o.observation_model, d.rig, o.pixel_sigma, o.noise};
    if (c.calibration.any() && c.proposal != ParticleProposal::LinearisedOptimal)
      throw UsageError("--calibrate: the particle filter self-calibrates with --pf-proposal linearised_optimal only");
    ParticleFilter pf(d.map, d.odometry, c, rng());
    run = runEstimator(pf, d);
    run.calibration = pf.calibration();
  } else if (name == "window") {
    SlidingWindowConfig c;
    c.window = o.window;
    c.init = beliefFor(init_mode, d, o, rng);
    c.gate_enabled = o.gate_enabled && init_mode != InitMode::Random;
    c.robust_loss.type = o.loss;
    c.robust_loss.scale = o.loss_scale;
    c.observation_model = {o.observation_model, d.rig, o.pixel_sigma, o.noise};
    c.calibration = o.calibration;
    requirePixelModelForStereoCalibration(o);
    SlidingWindowSmoother w(d.map, d.odometry, c);
    run = runEstimator(w, d);
    run.calibration = w.calibration();
  } else {  // batch
    BatchSmoother b(d.map, d.odometry, batchConfigFor(spec, d, seed, o));
    run = runEstimator(b, d);
    if (o.calibration.any()) run.calibration = b.calibration();
  }
  run.method = spec;
  if (name != "fix1" && name != "fix2") {
    for (const Estimate& e : run.estimates) {
      if (!e.pose.isFinite() || !e.covariance.allFinite())
        throw Error("method '" + spec + "' produced a non-finite estimate at step " + std::to_string(e.step));
    }
  }
  return run;
}

}  // namespace

}  // namespace stereoloc
