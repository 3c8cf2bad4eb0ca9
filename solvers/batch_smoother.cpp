#include "solvers/batch_smoother.h"

#include <Eigen/Cholesky>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <memory>
#include <string>
#include <utility>

#include "src/core/error.h"
#include "src/core/gaussian.h"

namespace stereoloc {

std::string toString(CovarianceStatus status) {
  switch (status) {
    case CovarianceStatus::NotComputed: return "not_computed";
    case CovarianceStatus::Ok: return "ok";
    case CovarianceStatus::RankDeficient: return "rank_deficient";
  }
  return "not_computed";
}

std::string toString(InitialGuess guess) { return guess == InitialGuess::Odometry ? "odometry" : "filter"; }

InitialGuess initialGuessFromString(const std::string& name) {
  for (InitialGuess g : {InitialGuess::Odometry, InitialGuess::Filter})
    if (toString(g) == name) return g;
  throw Error("unknown initial guess '" + name + "' (expected odometry or filter)");
}

std::string toString(BatchSolver solver) { return solver == BatchSolver::Chain ? "chain" : "ceres"; }

BatchSolver batchSolverFromString(const std::string& name) {
  for (BatchSolver b : {BatchSolver::Chain, BatchSolver::Ceres})
    if (toString(b) == name) return b;
  throw Error("unknown batch solver '" + name + "' (expected chain or ceres)");
}

std::string toString(CovarianceMethod method) { return method == CovarianceMethod::Chain ? "chain" : "ceres"; }

CovarianceMethod covarianceMethodFromString(const std::string& name) {
  for (CovarianceMethod m : {CovarianceMethod::Chain, CovarianceMethod::Ceres})
    if (toString(m) == name) return m;
  throw Error("unknown covariance method '" + name + "' (expected chain or ceres)");
}

void BatchSmootherConfig::validate() const {
  if (max_iterations < 1) throw Error("batch smoother: max_iterations must be >= 1");
  if (num_threads < 1) throw Error("batch smoother: num_threads must be >= 1");
  if (!(function_tolerance >= 0 && gradient_tolerance >= 0 && parameter_tolerance >= 0))
    throw Error("batch smoother: tolerances must be >= 0");
  if (!(cut_min_evidence >= 0)) throw Error("batch smoother: cut_min_evidence must be >= 0");
  makeLossFunction(loss);  // validates the scale
  if (!(std::isfinite(observation_model.pixel_sigma) && observation_model.pixel_sigma >= 0))
    throw Error("batch smoother: observation_model.pixel_sigma must be >= 0 (0: the observations' own)");
  calibration.validate();
  if (calibration.consider)
    throw Error("batch smoother: calibration.consider is the EKF's (a Schmidt gain); the smoothers estimate the calibration");
  observation_model.unmodelled.validate();
  if (!(std::isfinite(slip_rel_sigma) && slip_rel_sigma >= 0))
    throw Error("batch smoother: slip_rel_sigma must be a finite number >= 0");
  if (calibration.stereo && observation_model.model == ObservationModel::RangeBearing)
    throw Error("batch smoother: stereo self-calibration needs a pixel observation model (pixel_columns or pixels)");
}

BatchSmoother::BatchSmoother(const FieldMap& map, const OdometryParams& odometry, BatchSmootherConfig config)
    : map_(map), odometry_(odometry), config_(std::move(config)) {
  odometry_.validate();
  config_.validate();
  if (!config_.global_fix) config_.global_fix = defaultGlobalFix();
  if (config_.init.mode != InitMode::Global &&
      (!config_.init.pose.isFinite() || !config_.init.covariance.allFinite()))
    throw Error("batch smoother: initial belief is not finite");
  if (config_.initial_guess == InitialGuess::Filter) {
    EkfConfig ec;
    ec.init = config_.init;
    ec.gate = config_.gate;
    ec.association = config_.association;
    ec.use_compass = config_.use_compass;
    ec.global_fix = config_.global_fix;
    filter_ = std::make_unique<Ekf>(map_, odometry_, ec);
  }
}

void BatchSmoother::setInitialEstimates(const std::vector<Estimate>& estimates) {
  if (!steps_.empty()) throw Error("batch smoother: setInitialEstimates must be called before process()");
  given_ = estimates;
  std::stable_sort(given_.begin(), given_.end(), [](const Estimate& a, const Estimate& b) { return a.step < b.step; });
}

Estimate BatchSmoother::process(const Step& in) {
  const auto t0 = std::chrono::steady_clock::now();
  Estimate e = processStep(in);
  summary_.filter_seconds += std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return e;
}

Estimate BatchSmoother::processStep(const Step& in) {
  if (!steps_.empty() && in.step <= steps_.back().step)
    throw Error("batch smoother: step " + std::to_string(in.step) + " does not follow step " +
                std::to_string(steps_.back().step));
  validateStep(in, "batch smoother");
  solved_ = false;
  Step step = in;
  Estimate e;
  e.step = step.step;
  e.t = step.t;
  std::optional<Estimate> filtered;
  if (filter_) filtered = filter_->process(step);
  const Estimate* filter_estimate = filtered ? &*filtered : nullptr;
  e.status = first_index_ < 0 ? startChain(step, filter_estimate, e.pose) : continueChain(step, filter_estimate, e.pose);
  if (e.status == EstimateStatus::Uninitialised) {
    ++summary_.uninitialised_steps;
    step.observations.clear();
    buffer(step);
    guess_.push_back(e);
    return e;
  }
  if (const Estimate* given = givenEstimate(step.step)) {
    e.pose = given->pose;
    if (given->covariance.allFinite() && given->covariance.trace() > 0) guess_covariance_ = given->covariance;
  }
  e.covariance = guess_covariance_;
  for (size_t i = 0; i < step.observations.size(); ++i) {
    const int id = step.observations[i].landmark_id;
    if (id >= 0 && !map_.find(id))
      throw Error("batch smoother: step " + std::to_string(step.step) + ": observation " + std::to_string(i) +
                  ": unknown landmark id " + std::to_string(id));
  }
  const bool needs_association = std::any_of(step.observations.begin(), step.observations.end(),
                                             [](const Observation& o) { return o.landmark_id < 0; });
  if (needs_association) {
    raw_observations_.emplace_back(steps_.size(), step.observations);
    step.observations = associateObservations(step.observations, e.pose, guess_covariance_, map_, config_.association);
  }
  buffer(step);
  guess_.push_back(e);
  return e;
}

const Estimate* BatchSmoother::givenEstimate(long step) const {
  auto it = std::lower_bound(given_.begin(), given_.end(), step, [](const Estimate& a, long s) { return a.step < s; });
  if (it != given_.end() && it->step == step && it->status != EstimateStatus::Uninitialised && it->pose.isFinite())
    return &*it;
  return nullptr;
}

EstimateStatus BatchSmoother::startChain(Step& step, const Estimate* filtered, Pose2& guess) {
  EstimateStatus status;
  if (filtered) {
    if (filtered->status == EstimateStatus::Uninitialised) return EstimateStatus::Uninitialised;
    if (config_.init.mode != InitMode::Global) {
      prior_pose_ = config_.init.pose;
      prior_covariance_ = config_.init.covariance;
      status = EstimateStatus::Tracking;
    } else {  // the filter's first estimate is the global fix (it fuses nothing at that step)
      prior_pose_ = filtered->pose;
      prior_covariance_ = filtered->covariance;
      step.observations.clear();
      step.compass.reset();
      status = EstimateStatus::Reinitialised;
    }
    first_index_ = static_cast<long>(steps_.size());
    guess = filtered->pose;
    guess_covariance_ = filtered->covariance;
    return status;
  }
  if (config_.init.mode != InitMode::Global) {
    prior_pose_ = config_.init.pose;
    prior_covariance_ = config_.init.covariance;
    status = EstimateStatus::Tracking;
  } else if (const std::optional<PoseFix> fix = config_.global_fix(step, map_)) {
    prior_pose_ = fix->pose;
    prior_covariance_ = fix->covariance;
    // The fix came from this step's observations: fusing them again would count them twice.
    step.observations.clear();
    step.compass.reset();
    status = EstimateStatus::Reinitialised;
  } else {
    return EstimateStatus::Uninitialised;
  }
  first_index_ = static_cast<long>(steps_.size());
  guess = prior_pose_;
  guess_covariance_ = 0.5 * (prior_covariance_ + prior_covariance_.transpose());
  return status;
}

EstimateStatus BatchSmoother::continueChain(Step& step, const Estimate* filtered, Pose2& guess) {
  if (filtered) {
    guess = filtered->pose;
    guess_covariance_ = filtered->covariance;
    EstimateStatus status = EstimateStatus::Predicted;
    if (config_.cut_at_reinitialisation && filtered->status == EstimateStatus::Reinitialised &&
        cutAtReinitialisation(steps_.size(), *filtered, step))
      status = EstimateStatus::Reinitialised;
    trackRejections(steps_.size());
    return status;
  }
  const PosePrediction pred = predictPose(guess_.back().pose, guess_covariance_, step.d_left, step.d_right, odometry_);
  guess = pred.pose;
  guess_covariance_ = pred.covariance;
  return EstimateStatus::Predicted;
}

void BatchSmoother::buffer(const Step& step) {
  BufferedStep b;
  b.step = step.step;
  b.t = step.t;
  b.d_left = step.d_left;
  b.d_right = step.d_right;
  b.noise = noise_travel_.next(step.d_left, step.d_right);
  if (config_.calibration.stereo)  // the image block's exposure offset is the rate's only reader
    b.rate = stepBodyRate(rate_tracker_, step, odometry_, config_.observation_model.unmodelled.slip_rel_sigma);
  if (step.compass) {
    b.compass = *step.compass;
    b.compass_sigma = step.compass_sigma;
  }
  observations_.insert(observations_.end(), step.observations.begin(), step.observations.end());
  b.observations_end = observations_.size();
  steps_.push_back(b);
}

void BatchSmoother::trackRejections(size_t index) {
  // The last step whose landmark observation passed the filter's gate (5.20): up to there the
  // odometry chain is confirmed by the map.
  for (const EkfUpdateRecord& r : filter_->lastUpdates())
    if (!r.compass && r.accepted) last_accepted_ = static_cast<long>(index);
}

bool BatchSmoother::cutAtReinitialisation(size_t index, const Estimate& fix, const Step& step) {
  // The filter declared itself lost and a global fix re-initialised it at `index`. Was the robot
  // moved (kidnap), or did outliers or a poor linearisation trip the gate? Chain the odometry
  // from the last confirmed pose (the filter's estimate at the last accepted observation, or
  // the current segment's first pose) to this step and test the fix against it with the gate's
  // probability (3 dof): consistent means a false alarm, and the chain stays whole.
  const size_t lowest = cuts_.empty() ? static_cast<size_t>(first_index_) + 1 : cuts_.back().reinit + 1;
  const size_t base = std::max(lowest - 1, last_accepted_ >= 0 ? static_cast<size_t>(last_accepted_) : size_t{0});
  if (base >= index) return false;
  Pose2 pred = guess_[base].pose;
  Eigen::Matrix3d P = guess_[base].covariance;
  for (size_t j = base + 1; j <= index; ++j) {
    const double d_left = j == index ? step.d_left : steps_[j].d_left;
    const double d_right = j == index ? step.d_right : steps_[j].d_right;
    const PosePrediction pp = predictPose(pred, P, d_left, d_right, odometry_);  // (5.7), (5.9)
    pred = pp.pose;
    P = pp.covariance;
  }
  const Eigen::Matrix3d fix_covariance = 0.5 * (fix.covariance + fix.covariance.transpose());
  const Eigen::Vector3d e = minus(fix.pose, pred);
  Eigen::LLT<Eigen::Matrix3d> llt(P + fix_covariance);
  if (llt.info() == Eigen::Success && e.dot(llt.solve(e)) <= chi2Quantile(config_.gate.probability, 3)) return false;
  // A kidnap candidate. Where in the unobserved stretch after the last confirmed pose the robot
  // was moved cannot be told from the data (the odometry fits either way); a teleport changes
  // the view at once, so the confirming observations end at the kidnap: the chain is cut right
  // after the last confirmed pose and every later pose joins the new segment. The solve
  // verifies the cut (likelihood-ratio test).
  const size_t cut = base + 1;
  cuts_.push_back(Cut{cut, index});
  // The poses from the cut to the fix belong to the new segment: chain the odometry backwards
  // from the fix, p_j = p_{j+1} (+) u_{j+1}^-1 (B.16), with the covariance (5.9) of that motion.
  Pose2 p = fix.pose;
  P = fix_covariance;
  for (size_t j = index; j-- > cut;) {
    const double d_left = j + 1 == index ? step.d_left : steps_[j + 1].d_left;
    const double d_right = j + 1 == index ? step.d_right : steps_[j + 1].d_right;
    const Eigen::Vector3d u = controlVector(d_left, d_right, odometry_.wheel_base_mm);
    Matrix3d J_inv, J1, J2;
    const Pose2 u_inv = inverse(Pose2(u.x(), u.y(), u.z()), &J_inv);
    p = compose(p, u_inv, &J1, &J2);
    const Eigen::Matrix3d Ju = J2 * J_inv;
    P = J1 * P * J1.transpose() + Ju * controlCovariance(d_left, d_right, odometry_) * Ju.transpose();
    P = 0.5 * (P + P.transpose());
    guess_[j].pose = p;
    guess_[j].covariance = P;
    guess_[j].status = EstimateStatus::Predicted;
    const auto raw = std::lower_bound(raw_observations_.begin(), raw_observations_.end(), j,
                                      [](const auto& r, size_t i) { return r.first < i; });
    if (raw != raw_observations_.end() && raw->first == j) {
      const std::vector<Observation> a = associateObservations(raw->second, p, P, map_, config_.association);
      std::copy(a.begin(), a.end(), observations_.begin() + static_cast<long>(observationsBegin(j)));
    }
  }
  return true;
}

void BatchSmoother::smoothGuess(size_t first, std::vector<double>* xp) const {
  // Rauch-Tung-Striebel backward pass over the filter's estimates: the linearised smoother, close
  // to the optimum, so Levenberg-Marquardt needs fewer iterations than from the filtered poses.
  //   m_k^s = m_k [+] G_k (m_{k+1}^s [-] m_{k+1|k}),  G_k = P_k F_k^T P_{k+1|k}^-1
  // with the prediction (5.7, 5.9) and F_k = J_1 of the compounding (B.18). The pass restarts
  // at a re-initialisation (the filter's pose there is a global fix, not a prediction) and at a
  // candidate cut.
  std::vector<double>& x = *xp;
  const size_t n = steps_.size() - first;
  std::vector<uint8_t> boundary(n, 0);
  for (const Cut& c : cuts_)
    if (c.index > first) boundary[c.index - first] = 1;
  for (size_t i = 1; i < n; ++i)
    if (guess_[first + i].status == EstimateStatus::Reinitialised) boundary[i] = 1;
  for (size_t i = n - 1; i-- > 0;) {
    if (boundary[i + 1]) continue;
    const Estimate& f = guess_[first + i];
    const BufferedStep& next = steps_[first + i + 1];
    const PosePrediction pred = predictPose(f.pose, f.covariance, next.d_left, next.d_right, odometry_);
    const Eigen::Vector3d u = controlVector(next.d_left, next.d_right, odometry_.wheel_base_mm);
    Matrix3d F;
    compose(f.pose, Pose2(u.x(), u.y(), u.z()), &F, nullptr);
    const Eigen::LDLT<Eigen::Matrix3d> ldlt(0.5 * (pred.covariance + pred.covariance.transpose()));
    if (ldlt.info() != Eigen::Success || !(ldlt.vectorD().minCoeff() > 0)) continue;
    const Eigen::Matrix3d G = (ldlt.solve(F * f.covariance)).transpose();  // P F^T P^-1 (P symmetric)
    const Eigen::Vector3d innovation = minus(Pose2(x[3 * i + 3], x[3 * i + 4], x[3 * i + 5]), pred.pose);
    const Eigen::Vector3d d = G * innovation;
    if (!d.allFinite()) continue;
    x[3 * i] = f.pose.x + d.x();
    x[3 * i + 1] = f.pose.y + d.y();
    x[3 * i + 2] = wrapAngle(f.pose.theta + d.z());
  }
}

std::vector<Estimate> BatchSmoother::finish() {
  if (!solved_) solve();
  return result_;
}

}  // namespace stereoloc
