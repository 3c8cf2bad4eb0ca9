#include "src/study/real_data_study.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <functional>
#include <iostream>
#include <map>
#include <memory>
#include <sstream>

#include "solvers/batch_smoother.h"
#include "solvers/ekf.h"
#include "solvers/initialisation.h"
#include "solvers/particle_filter.h"
#include "solvers/self_calibration.h"
#include "solvers/sliding_window_smoother.h"
#include "src/core/atomic_file.h"
#include "src/io/csv.h"
#include "src/io/dataset.h"
#include "src/eval/evaluation.h"
#include "src/core/odometry_delay.h"
#include "src/core/odometry_model.h"
#include "src/pipeline/usage_error.h"

namespace stereoloc {
namespace {

struct Row {
  std::string key, label;
  TrajectoryMetrics metrics;
  double ms_per_step = 0;
  size_t nonfinite = 0;     // estimates with a non-finite pose or covariance
  size_t reinitialised = 0; // steps with status Lost or Reinitialised
  double max_error = 0;     // mm
};

using Clock = std::chrono::steady_clock;
double msSince(Clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}

Row evaluate(const std::string& key, const std::string& label, const std::vector<Estimate>& estimates,
             const TruthByStep& truth, double total_ms, size_t steps) {
  Row r;
  r.key = key;
  r.label = label;
  r.ms_per_step = total_ms / static_cast<double>(std::max<size_t>(1, steps));
  for (const Estimate& e : estimates) {
    if (!e.pose.isFinite() || !e.covariance.allFinite()) ++r.nonfinite;
    if (e.status == EstimateStatus::Lost || e.status == EstimateStatus::Reinitialised) ++r.reinitialised;
  }
  std::vector<Estimate> finite;
  finite.reserve(estimates.size());
  for (const Estimate& e : estimates)
    if (e.pose.isFinite()) finite.push_back(e);
  const std::vector<PoseError> errors = poseErrors(finite, truth);
  r.metrics = trajectoryMetrics(errors);
  for (const PoseError& pe : errors) r.max_error = std::max(r.max_error, pe.distance);
  return r;
}

// Runs an estimator over the steps; `online` (optional) receives the process() outputs.
std::vector<Estimate> runEstimator(Estimator& est, const std::vector<Step>& steps, double* ms,
                                   std::vector<Estimate>* online = nullptr) {
  const Clock::time_point t0 = Clock::now();
  for (const Step& s : steps) {
    Estimate e = est.process(s);
    if (online) online->push_back(e);
  }
  std::vector<Estimate> out = est.finish();
  *ms = msSince(t0);
  return out;
}

std::vector<Estimate> deadReckoning(const std::vector<Step>& steps, const OdometryParams& odometry,
                                    const InitialBelief& init, double* ms) {
  const Clock::time_point t0 = Clock::now();
  std::vector<Estimate> out;
  out.reserve(steps.size());
  Pose2 pose = init.pose;
  Eigen::Matrix3d P = init.covariance;
  for (size_t i = 0; i < steps.size(); ++i) {
    if (i > 0) {  // the first step is the initial time (as for the estimators)
      const PosePrediction p = predictPose(pose, P, steps[i].d_left, steps[i].d_right, odometry);
      pose = p.pose;
      P = p.covariance;
    }
    Estimate e;
    e.step = steps[i].step;
    e.t = steps[i].t;
    e.pose = pose;
    e.covariance = P;
    e.status = EstimateStatus::Predicted;
    out.push_back(e);
  }
  *ms = msSince(t0);
  return out;
}

// The keys of --only, every comma splitting ("ekf," has an empty second key); none when empty.
std::vector<std::string> onlyKeys(const RealDataStudyOptions& o) {
  std::vector<std::string> keys;
  if (o.only.empty()) return keys;
  for (size_t start = 0;;) {
    const size_t comma = o.only.find(',', start);
    keys.push_back(o.only.substr(start, comma == std::string::npos ? std::string::npos : comma - start));
    if (comma == std::string::npos) return keys;
    start = comma + 1;
  }
}

bool wanted(const RealDataStudyOptions& o, const std::string& key) {
  const std::vector<std::string> keys = onlyKeys(o);
  return keys.empty() || std::find(keys.begin(), keys.end(), key) != keys.end();
}

}  // namespace

namespace {

// The dataset (cut to --max-steps) with an initial pose for every estimator.
Dataset loadRealDataset(const RealDataStudyOptions& o) {
  Dataset d = loadDataset(o.dataset_dir);
  if (o.max_steps > 0 && static_cast<size_t>(o.max_steps) < d.steps.size()) {
    d.steps.resize(static_cast<size_t>(o.max_steps));
    d.groundtruth.resize(static_cast<size_t>(o.max_steps));
  }
  if (d.steps.empty()) throw Error(o.dataset_dir + ": no steps");
  if (!d.initial_pose) {
    if (d.groundtruth.front()) {
      d.initial_pose = d.groundtruth.front();
    } else {
      throw Error(o.dataset_dir + ": no initial pose and no ground truth at step 0: cannot initialise alike");
    }
  }
  return d;
}

void printDataset(const RealDataStudyOptions& o, const Dataset& d, const TruthByStep& truth) {
  size_t observations = 0;
  for (const Step& s : d.steps) observations += s.observations.size();
  std::fprintf(o.console, "dataset %s: %zu steps (%.1f s), %zu with ground truth, %zu observations, %zu landmarks\n",
              d.name.c_str(), d.steps.size(), d.steps.back().t - d.steps.front().t, truth.size(), observations,
              d.map.landmarks().size());
  std::fprintf(o.console, "odometry model: wheel base %.0f mm, k %.3g / %.3g mm^2/mm, control floor (%.3g, %.3g, %.3g)\n",
              d.odometry.wheel_base_mm, d.odometry.k_left, d.odometry.k_right, d.odometry.control_variance_floor.x(),
              d.odometry.control_variance_floor.y(), d.odometry.control_variance_floor.z());
}

// What every estimator of the study runs on, and the table its rows go to.
struct StudyRun {
  const RealDataStudyOptions& o;
  const Dataset& d;
  const TruthByStep& truth;
  const InitialBelief& init;
  std::vector<Row> rows;
  void note(const Row& r) const {
    if (o.log) std::fprintf(o.log, "  %-24s done: position RMSE %.0f mm, %.3f ms/step\n", r.label.c_str(),
                 r.metrics.position_rmse, r.ms_per_step);
  }
  // Dead reckoning, the EKF (plain, calibrating the wheels, the wheels and the range sensor) and
  // the particle filter.
  void filters();
  // The window's rows: its smoothed (lag) and its real-time (online) estimates.
  void windows(const RobustLossConfig& robust);
  void batches(const RobustLossConfig& robust);
};

void StudyRun::filters() {
  double ms = 0;
  const size_t n = d.steps.size();
  if (wanted(o, "dead_reckoning")) {
    rows.push_back(evaluate("dead_reckoning", "dead reckoning", deadReckoning(d.steps, d.odometry, init, &ms), truth,
                            ms, n));
    note(rows.back());
  }
  // The EKF, and the EKF calibrating the wheels, and the wheels and the range sensor: what a
  // range-bearing dataset lets it calibrate (no pixels, no stereo head).
  struct EkfVariant {  // (also the particle filter's variants below)
    const char *key, *label, *calibration;
  };
  for (const EkfVariant& v : {EkfVariant{"ekf", "EKF", "none"},
                              EkfVariant{"ekf_calib", "EKF, calibrating odometry", "odometry"},
                              EkfVariant{"ekf_calib_range", "EKF, calibrating odometry and range", "odometry,range"}}) {
    const std::string key = v.key;
    if (!wanted(o, key)) continue;
    EkfConfig c;
    c.init = init;
    c.gate_enabled = o.gate;
    c.calibration = SelfCalibrationConfig::parse(v.calibration);
    Ekf ekf(d.map, d.odometry, c);
    const Clock::time_point t0 = Clock::now();
    size_t accepted = 0, gated = 0;
    for (const Step& s : d.steps) {
      ekf.process(s);
      for (const EkfUpdateRecord& u : ekf.lastUpdates()) (u.accepted ? accepted : gated) += u.compass ? 0 : 1;
    }
    const std::vector<Estimate> e = ekf.finish();
    ms = msSince(t0);
    if (o.log) std::fprintf(o.log, "  %s: %zu observations fused, %zu gated\n", key.c_str(), accepted, gated);
    rows.push_back(evaluate(key, v.label, e, truth, ms, n));
    note(rows.back());
  }
  // The particle filter, and the particle filter calibrating the wheels (a calibration per
  // particle; no stereo head on a range-bearing dataset).
  for (const EkfVariant& v : {EkfVariant{"pf", "", "none"}, EkfVariant{"pf_calib", ", calibrating odometry", "odometry"}}) {
    const std::string key = v.key;
    if (!wanted(o, key)) continue;
    ParticleFilterConfig c;
    c.init = init;
    c.particles = o.particles;
    c.calibration = SelfCalibrationConfig::parse(v.calibration);
    ParticleFilter pf(d.map, d.odometry, c, o.seed);
    const std::vector<Estimate> e = runEstimator(pf, d.steps, &ms);
    rows.push_back(evaluate(key, "PF (" + std::to_string(o.particles) + ")" + v.label, e, truth, ms, n));
    note(rows.back());
  }
}

// The window and the batch plain, with the robust loss, calibrating the odometry, and
// calibrating the odometry and the range sensor.
struct Variant {
  const char *suffix, *calibration;
  bool robust;
  std::string label;
};
std::vector<Variant> smootherVariants(const RealDataStudyOptions& o) {
  return {{"", "none", false, ""},
          {"_robust", "none", true, " " + o.robust},
          {"_calib", "odometry", false, ", calibrating odometry"},
          {"_calib_range", "odometry,range", false, ", calibrating odometry and range"}};
}

void StudyRun::windows(const RobustLossConfig& robust) {
  double ms = 0;
  const size_t n = d.steps.size();
  for (const Variant& variant : smootherVariants(o)) {
    const std::string key = std::string("window") + variant.suffix;
    if (!wanted(o, key) && !wanted(o, key + "_online")) continue;
    SlidingWindowConfig c;
    c.init = init;
    c.window = o.window;
    c.keyframe_max_steps = o.keyframe_max_steps;
    c.gate.lost_after = o.window_lost_after;
    c.gate_enabled = o.gate;
    if (variant.robust) c.robust_loss = robust;
    c.calibration = SelfCalibrationConfig::parse(variant.calibration);
    SlidingWindowSmoother sw(d.map, d.odometry, c);
    std::vector<Estimate> online;
    const std::vector<Estimate> e = runEstimator(sw, d.steps, &ms, &online);
    const SlidingWindowStats& wst = sw.stats();
    if (o.log) std::fprintf(o.log, "  %s: %ld keyframes, %ld observations fused, %ld gated, %ld re-initialisations\n",
                 key.c_str(), wst.keyframes, wst.accepted_observations, wst.rejected_observations, wst.reinitialisations);
    const std::string w = "W=" + std::to_string(o.window) + variant.label;
    if (wanted(o, key)) {
      rows.push_back(evaluate(key, "window " + w + " (lag)", e, truth, ms, n));
      note(rows.back());
    }
    if (wanted(o, key + "_online")) {
      rows.push_back(evaluate(key + "_online", "window " + w + " (online)", online, truth, ms, n));
      note(rows.back());
    }
  }
}

void StudyRun::batches(const RobustLossConfig& robust) {
  double ms = 0;
  const size_t n = d.steps.size();
  for (const Variant& variant : smootherVariants(o)) {
    const std::string key = std::string("batch") + variant.suffix;
    if (!wanted(o, key)) continue;
    BatchSmootherConfig c;
    c.init = init;
    if (variant.robust) c.loss = robust;
    c.calibration = SelfCalibrationConfig::parse(variant.calibration);
    c.initial_guess = initialGuessFromString(o.batch_guess);
    BatchSmoother batch(d.map, d.odometry, c);
    const std::vector<Estimate> e = runEstimator(batch, d.steps, &ms);
    const BatchSummary& s = batch.summary();
    if (o.log) std::fprintf(o.log, "  %s: %d iterations, cost %.4g -> %.4g, %s, covariance %s\n", key.c_str(),
                 s.iterations, s.initial_cost, s.final_cost, s.converged ? "converged" : "NOT converged",
                 toString(s.covariance_status).c_str());
    rows.push_back(evaluate(key, variant.robust ? "batch (" + o.robust + ")" : "batch" + variant.label, e,
                            truth, ms, n));
    note(rows.back());
  }
}

// Every estimator --only asks for, from the same initial belief: a row each.
std::vector<Row> runEstimators(const RealDataStudyOptions& o, const Dataset& d, const TruthByStep& truth,
                               const InitialBelief& init, const RobustLossConfig& robust) {
  StudyRun run{o, d, truth, init, {}};
  run.filters();
  run.windows(robust);
  run.batches(robust);
  return run.rows;
}

double ekfRmse(const std::vector<Row>& rows) {
  double ekf_rmse = 0;
  for (const Row& r : rows)
    if (r.key == "ekf") ekf_rmse = r.metrics.position_rmse;
  return ekf_rmse;
}

void printRows(const RealDataStudyOptions& o, const std::vector<Row>& rows) {
  const double ekf_rmse = ekfRmse(rows);
  // The label column is as wide as the longest label (the window's "W=<n>" grows with n).
  int width = 24;
  for (const Row& r : rows) width = std::max(width, static_cast<int>(r.label.size()));
  std::fprintf(o.console, "\n%-*s %10s %10s %8s %8s %8s %8s %9s %9s %9s %6s %6s\n", width, "estimator", "pos RMSE",
              "th RMSE", "mean", "NEES", "NEES", "NEES", "max err", "ms/step", "pos RMSE", "lost/", "non-");
  std::fprintf(o.console, "%-*s %10s %10s %8s %8s %8s %8s %9s %9s %9s %6s %6s\n", width, "", "[mm]", "[deg]", "NEES", "in 95%",
              "pos (2)", "head (1)", "[mm]", "", "/ EKF", "reinit", "finite");
  for (const Row& r : rows) {
    char ratio[32] = "-";
    if (ekf_rmse > 0) std::snprintf(ratio, sizeof ratio, "%.3f", r.metrics.position_rmse / ekf_rmse);
    std::fprintf(o.console, "%-*s %10.1f %10.2f %8.3g %7.0f%% %8.3g %8.3g %9.0f %9.3f %9s %6zu %6zu\n", width,
                r.label.c_str(), r.metrics.position_rmse, rad2deg(r.metrics.theta_rmse), r.metrics.mean_nees,
                100.0 * r.metrics.nees_in_band, r.metrics.mean_position_nees, r.metrics.mean_heading_nees, r.max_error,
                r.ms_per_step, ratio, r.reinitialised, r.nonfinite);
  }
  std::fprintf(o.console, "(RMSE over %zu steps with ground truth; NEES of the 3-dof pose error, 3 is honest; the 95%% column is "
              "the share of steps inside the chi-square(3) 95%% band; its position and heading parts, 2 and 1 honest)\n",
              rows.empty() ? size_t(0) : rows.front().metrics.count);
}

void writeRowsCsv(const std::string& path, const std::vector<Row>& rows) {
  const double ekf_rmse = ekfRmse(rows);
  std::ostringstream os;
  os << "estimator,position_rmse_mm,theta_rmse_rad,mean_nees,nees_in_band,max_error_mm,ms_per_step,"
        "ratio_to_ekf,reinitialised,nonfinite,count,nees_position,nees_heading\n";
  for (const Row& r : rows) {
    os << r.key << "," << formatDouble(r.metrics.position_rmse) << "," << formatDouble(r.metrics.theta_rmse) << ","
       << formatDouble(r.metrics.mean_nees) << "," << formatDouble(r.metrics.nees_in_band) << ","
       << formatDouble(r.max_error) << "," << formatDouble(r.ms_per_step) << ","
       << formatDouble(ekf_rmse > 0 ? r.metrics.position_rmse / ekf_rmse : 0.0) << "," << r.reinitialised << ","
       << r.nonfinite << "," << r.metrics.count << "," << formatDouble(r.metrics.mean_position_nees) << ","
       << formatDouble(r.metrics.mean_heading_nees) << "\n";
  }
  writeFileAtomically(path, os.str());
}

}  // namespace

const std::vector<std::string>& realDataEstimatorKeys() {
  static const std::vector<std::string> keys = {
      "dead_reckoning", "ekf", "ekf_calib", "ekf_calib_range", "pf", "pf_calib", "window", "window_online", "window_robust",
      "window_robust_online", "window_calib", "window_calib_online", "window_calib_range", "window_calib_range_online",
      "batch", "batch_robust", "batch_calib", "batch_calib_range"};
  return keys;
}

bool realDataRunsAny(const RealDataStudyOptions& o, const std::vector<std::string>& prefixes) {
  for (const std::string& key : realDataEstimatorKeys())
    for (const std::string& prefix : prefixes)
      if (key.compare(0, prefix.size(), prefix) == 0 && wanted(o, key)) return true;
  return false;
}

void checkRealDataStudyOptions(const RealDataStudyOptions& o) {
  const std::vector<std::string>& known = realDataEstimatorKeys();
  for (const std::string& k : onlyKeys(o))
    if (std::find(known.begin(), known.end(), k) == known.end()) throw UsageError("--only: unknown estimator '" + k + "'");
  if (o.batch_guess != "filter" && o.batch_guess != "odometry")
    throw UsageError("--batch-guess: expected 'filter' or 'odometry', got '" + o.batch_guess + "'");
  if (o.robust != "huber" && o.robust != "cauchy")
    throw UsageError("--robust: expected 'huber' or 'cauchy', got '" + o.robust + "'");
}

void runRealDataStudy(const RealDataStudyOptions& o) {
  checkRealDataStudyOptions(o);
  Dataset d = loadRealDataset(o);
  RobustLossConfig robust;
  robust.type = robustLossFromString(o.robust);
  robust.scale = o.robust_scale;

  const TruthByStep truth = truthByStep(d.steps, d.groundtruth);
  printDataset(o, d, truth);
  // The same initial belief for every estimator: the true pose at step 0 with a small covariance.
  const double st = deg2rad(o.init_sigma_theta_deg);
  const InitialBelief init =
      knownBelief(*d.initial_pose, Eigen::Vector3d(o.init_sigma_xy * o.init_sigma_xy, o.init_sigma_xy * o.init_sigma_xy,
                                                   st * st)
                                       .asDiagonal());
  std::fprintf(o.console, "initial belief: ground truth at step 0, sigma (%.0f mm, %.0f mm, %.1f deg)\n", o.init_sigma_xy,
              o.init_sigma_xy, o.init_sigma_theta_deg);
  if (o.odometry_delay == OdometryDelayMode::Given) {
    std::fprintf(o.console, "odometry delay (given): %.3f s\n", o.given_odometry_delay_s);
    d.steps = delayOdometry(d.steps, o.given_odometry_delay_s);
  } else if (o.odometry_delay == OdometryDelayMode::Fit) {
    BatchSmootherConfig c;
    c.init = init;
    c.calibration = SelfCalibrationConfig::parse("odometry,range");
    c.initial_guess = initialGuessFromString(o.batch_guess);
    const OdometryDelayEstimate e = estimateOdometryDelay(d.map, d.odometry, c, d.steps, o.odometry_delay_search);
    std::fprintf(o.console,
                 "odometry delay (fitted by the batch calibrating odometry and range): %.3f +- %.3f s (profile %.3f s, "
                 "the steps' resolution %.3f s)\n",
                 e.delay_s, e.sigma_s, e.profile_sigma_s, e.resolution_s);
    d.steps = delayOdometry(d.steps, e.delay_s);
  }
  std::fflush(o.console);
  const std::vector<Row> rows = runEstimators(o, d, truth, init, robust);
  printRows(o, rows);
  if (!o.csv_path.empty()) writeRowsCsv(o.csv_path, rows);
  size_t bad = 0;
  for (const Row& r : rows) bad += r.nonfinite;
  if (bad > 0) throw Error("realdata: " + std::to_string(bad) + " non-finite estimates (see the table)");
}

}  // namespace stereoloc
