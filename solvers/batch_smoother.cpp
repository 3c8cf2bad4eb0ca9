#include "solvers/batch_smoother.h"

#include <ceres/covariance.h>
#include <ceres/solver.h>

#include <algorithm>
#include <array>
#include <Eigen/Cholesky>
#include <chrono>
#include <cmath>
#include <limits>
#include <map>
#include <memory>
#include <unordered_map>
#include <utility>

#include "factors/calibration_prior_factor.h"
#include "factors/compass_factor.h"
#include "factors/joined_global_blocks.h"
#include "factors/odometry_calibration_factor.h"
#include "factors/stereo_pixel_calibration_factor.h"
#include "factors/stereo_pixel_feature_calibration_factor.h"
#include "factors/stereo_pixel_image_calibration_factor.h"
#include "factors/stereo_pixel_row_calibration_factor.h"
#include "solvers/chain_solver.h"
#include "factors/odometry_factor.h"
#include "factors/pose_manifold.h"
#include "factors/pose_prior_factor.h"
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
  const Estimate* given = nullptr;
  {
    auto it = std::lower_bound(given_.begin(), given_.end(), step.step,
                               [](const Estimate& a, long s) { return a.step < s; });
    if (it != given_.end() && it->step == step.step && it->status != EstimateStatus::Uninitialised &&
        it->pose.isFinite())
      given = &*it;
  }
  std::optional<Estimate> filtered;
  if (filter_) filtered = filter_->process(step);
  if (first_index_ < 0 && filtered) {
    if (filtered->status == EstimateStatus::Uninitialised) {
      e.status = EstimateStatus::Uninitialised;
      ++summary_.uninitialised_steps;
      step.observations.clear();
      buffer(step);
      guess_.push_back(e);
      return e;
    }
    if (config_.init.mode != InitMode::Global) {
      prior_pose_ = config_.init.pose;
      prior_covariance_ = config_.init.covariance;
      e.status = EstimateStatus::Tracking;
    } else {  // the filter's first estimate is the global fix (it fuses nothing at that step)
      prior_pose_ = filtered->pose;
      prior_covariance_ = filtered->covariance;
      step.observations.clear();
      step.compass.reset();
      e.status = EstimateStatus::Reinitialised;
    }
    first_index_ = static_cast<long>(steps_.size());
    e.pose = filtered->pose;
    guess_covariance_ = filtered->covariance;
  } else if (first_index_ >= 0 && filtered) {
    e.pose = filtered->pose;
    guess_covariance_ = filtered->covariance;
    e.status = EstimateStatus::Predicted;
    if (config_.cut_at_reinitialisation && filtered->status == EstimateStatus::Reinitialised &&
        cutAtReinitialisation(steps_.size(), *filtered, step))
      e.status = EstimateStatus::Reinitialised;
    trackRejections(steps_.size());
  } else if (first_index_ < 0) {
    if (config_.init.mode != InitMode::Global) {
      prior_pose_ = config_.init.pose;
      prior_covariance_ = config_.init.covariance;
      e.status = EstimateStatus::Tracking;
    } else if (const std::optional<PoseFix> fix = config_.global_fix(step, map_)) {
      prior_pose_ = fix->pose;
      prior_covariance_ = fix->covariance;
      // The fix came from this step's observations: fusing them again would count them twice.
      step.observations.clear();
      step.compass.reset();
      e.status = EstimateStatus::Reinitialised;
    } else {
      e.status = EstimateStatus::Uninitialised;
      ++summary_.uninitialised_steps;
      step.observations.clear();
      buffer(step);
      guess_.push_back(e);
      return e;
    }
    first_index_ = static_cast<long>(steps_.size());
    e.pose = prior_pose_;
    guess_covariance_ = 0.5 * (prior_covariance_ + prior_covariance_.transpose());
  } else {
    const PosePrediction pred =
        predictPose(guess_.back().pose, guess_covariance_, step.d_left, step.d_right, odometry_);
    e.pose = pred.pose;
    guess_covariance_ = pred.covariance;
    e.status = EstimateStatus::Predicted;
  }
  if (given) {
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

void BatchSmoother::buffer(const Step& step) {
  BufferedStep b;
  b.step = step.step;
  b.d_left = step.d_left;
  b.d_right = step.d_right;
  b.noise = noise_travel_.next(step.d_left, step.d_right);
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

namespace {

using Clock = std::chrono::steady_clock;

double secondsSince(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

// The factors touching poses [lo, hi) as a ceres::Problem over those poses, the neighbours
// lo-1 and hi held constant, and over the global blocks (held constant unless free_globals)
// (BatchSolver::Ceres, and ceres::Covariance).
std::unique_ptr<ceres::Problem> makeCeresProblem(const ChainFactorSource& source, ceres::LossFunction* loss,
                                                 const ceres::Manifold* manifold, size_t lo, size_t hi,
                                                 std::vector<double>* x, std::vector<double>* globals,
                                                 bool free_globals) {
  ceres::Problem::Options popts;
  popts.manifold_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  popts.loss_function_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  auto problem = std::make_unique<ceres::Problem>(popts);
  double* X = x->data();
  for (size_t i = lo; i < hi; ++i) problem->AddParameterBlock(X + 3 * i, 3, const_cast<ceres::Manifold*>(manifold));
  std::vector<double*> global_blocks;
  {
    int offset = 0;
    for (int size : source.globalBlockSizes()) {
      global_blocks.push_back(globals->data() + offset);
      problem->AddParameterBlock(global_blocks.back(), size);
      if (!free_globals) problem->SetParameterBlockConstant(global_blocks.back());
      offset += size;
    }
  }
  auto add = [&](ChainFactor& f, std::vector<double*> blocks) {
    if (f.global >= 0) blocks.push_back(global_blocks[static_cast<size_t>(f.global)]);
    problem->AddResidualBlock(f.cost.release(), f.robust ? loss : nullptr, blocks);
  };
  std::vector<ChainFactor> unary;
  auto addBinary = [&](size_t i) {
    ChainFactor b = source.binaryFactor(i);
    if (!b.cost) return;
    add(b, {X + 3 * (i - 1), X + 3 * i});
    for (size_t j : {i - 1, i})
      if (j < lo || j >= hi) problem->SetParameterBlockConstant(X + 3 * j);
  };
  for (size_t i = lo; i < hi; ++i) {
    unary.clear();
    source.unaryFactors(i, &unary);
    for (ChainFactor& f : unary) add(f, {X + 3 * i});
    if (i > 0) addBinary(i);
  }
  if (hi < source.size() && hi > lo) addBinary(hi);
  unary.clear();
  source.globalFactors(&unary);
  for (ChainFactor& f : unary) add(f, {});
  return problem;
}

}  // namespace

// The factors of the buffered steps, made on demand (a million-step problem does not hold
// millions of cost functions). Pose i is steps_[first + i].
class BatchSmoother::StepFactorSource final : public ChainFactorSource {
 public:
  StepFactorSource(const BatchSmoother& smoother, size_t first, size_t n)
      : b_(smoother), first_(first), n_(n),
        prior_covariance_(0.5 * (b_.prior_covariance_ + b_.prior_covariance_.transpose())), cut_(n, 0),
        left_out_(b_.observations_.size(), 0) {
    if (b_.config_.calibration.odometry) {
      odometry_block_ = static_cast<int>(sizes_.size());
      sizes_.push_back(3);
    }
    if (b_.config_.calibration.stereo) {
      stereo_block_ = static_cast<int>(sizes_.size());
      image_sigmas_ = imageErrorSigmas(b_.config_.calibration, b_.config_.observation_model.unmodelled);
      row_sigma_ = rowOffsetSigma(b_.config_.calibration, b_.config_.observation_model.unmodelled);
      features_ = featureOffsetSigmas(b_.map_, b_.config_.calibration, b_.config_.observation_model.unmodelled);
      // After (q, [e,] dv): per feature its column offset, then its u_r offset, where stated.
      int next = kStereo + (image_sigmas_ ? kImage : 0) + (row_sigma_ ? 1 : 0);
      for (const FeatureOffsetPrior& f : features_) {
        std::array<int, 2>& at = feature_index_[f.landmark_id];
        at[0] = f.sigma.column > 0 ? next++ : -1;
        at[1] = f.sigma.disparity > 0 ? next++ : -1;
      }
      sizes_.push_back(next);
    }
  }

  size_t size() const override { return n_; }
  void unaryFactors(size_t i, std::vector<ChainFactor>* out) const override {
    if (i == 0)
      out->push_back({std::unique_ptr<ceres::CostFunction>(PosePriorFactor::Create(b_.prior_pose_, prior_covariance_)), false});
    const size_t k = first_ + i;
    const BufferedStep& st = b_.steps_[k];
    if (st.compass_sigma > 0 && b_.config_.use_compass)
      out->push_back({std::unique_ptr<ceres::CostFunction>(CompassFactor::Create(st.compass, st.compass_sigma)), false});
    for (size_t o = b_.observationsBegin(k); o < st.observations_end; ++o)
      if (b_.observations_[o].landmark_id >= 0 && !left_out_[o]) out->push_back(observationFactor(o));
  }
  // The factor of observation o (index into observations_, identified), on its pose and, with
  // stereo self-calibration and pixels, the stereo block.
  ChainFactor observationFactor(size_t o) const {
    const ObservationModelConfig& model = b_.config_.observation_model;
    const Observation& obs = b_.observations_[o];
    const Landmark& landmark = b_.map_.at(obs.landmark_id);
    if (stereo_block_ >= 0 && obs.pixels) {
      const PixelResiduals residuals =
          model.model == ObservationModel::Pixels ? PixelResiduals::All : PixelResiduals::Columns;
      const auto feature = feature_index_.find(obs.landmark_id);
      const bool offset = row_sigma_ && feature != feature_index_.end();
      const Eigen::Matrix4d C =
          calibratedPixelCovariance(obs, landmark, model, image_sigmas_.has_value(), row_sigma_.has_value(), offset);
      const auto* image = image_sigmas_ ? &*image_sigmas_ : nullptr;
      const int joined = sizes_[static_cast<size_t>(stereo_block_)];
      if (offset) {
        // (q, [e,] dv, (b_c, b_d)) at their places in the joined block (globalFactors).
        const int m = image_sigmas_ ? kImage : 0;
        std::vector<std::vector<int>> indices;
        auto range = [](int from, int n) {
          std::vector<int> r(static_cast<size_t>(n));
          for (int i = 0; i < n; ++i) r[static_cast<size_t>(i)] = from + i;
          return r;
        };
        indices.push_back(range(0, kStereo));
        if (image_sigmas_) indices.push_back(range(kStereo, kImage));
        indices.push_back({kStereo + m});
        indices.push_back({feature->second[0], feature->second[1]});
        return {std::make_unique<JoinedGlobalBlocks>(
                    StereoPixelFeatureCalibrationFactor::Create(model.rig, landmark.position, *obs.pixels,
                                                                obs.slide_gain, obs.head_pan, C, residuals, image),
                    std::move(indices), joined),
                true, stereo_block_};
      }
      if (row_sigma_)
        return {std::make_unique<JoinedGlobalBlocks>(
                    StereoPixelRowCalibrationFactor::Create(model.rig, landmark.position, *obs.pixels, obs.slide_gain,
                                                            obs.head_pan, C, residuals, image),
                    std::vector<std::vector<int>>{}, joined),
                true, stereo_block_};
      if (image_sigmas_)
        return {std::make_unique<JoinedGlobalBlocks>(StereoPixelImageCalibrationFactor::Create(
                    model.rig, landmark.position, *obs.pixels, obs.head_pan, C, residuals, *image_sigmas_)),
                true, stereo_block_};
      return {std::unique_ptr<ceres::CostFunction>(StereoPixelCalibrationFactor::Create(
                  model.rig, landmark.position, *obs.pixels, obs.head_pan, C, residuals)),
              true, stereo_block_};
    }
    return {std::unique_ptr<ceres::CostFunction>(makeObservationFactor(obs, landmark, model)), true};
  }
  // Whether observation o's factor can be evaluated with pose i at `pose` and the global blocks
  // at `globals` (a pixel factor cannot when the landmark is behind the cameras).
  bool evaluable(size_t o, const double* pose, const std::vector<double>& globals) const {
    const ChainFactor f = observationFactor(o);
    const double* params[2] = {pose, nullptr};
    if (f.global >= 0) {
      size_t offset = 0;
      for (int k = 0; k < f.global; ++k) offset += static_cast<size_t>(sizes_[static_cast<size_t>(k)]);
      params[1] = globals.data() + offset;
    }
    const int m = f.cost->num_residuals();
    std::vector<double> r(static_cast<size_t>(m));
    if (!f.cost->Evaluate(params, r.data(), nullptr)) return false;
    return std::all_of(r.begin(), r.end(), [](double v) { return std::isfinite(v); });
  }
  // Observation o (index into observations_) is left out of the problem (true) or in it.
  void setLeftOut(size_t o, bool left_out) { left_out_[o] = left_out ? 1 : 0; }
  bool leftOut(size_t o) const { return left_out_[o] != 0; }
  ChainFactor binaryFactor(size_t i) const override {
    if (i == 0 || cut_[i]) return {};
    const BufferedStep& st = b_.steps_[first_ + i];
    if (odometry_block_ >= 0) {
      const OdometryParams at_noise = withSlip(b_.odometry_, st.noise.d_left, st.noise.d_right, b_.config_.slip_rel_sigma);
      return {std::unique_ptr<ceres::CostFunction>(
                  OdometryCalibrationFactor::Create(st.d_left, st.d_right, st.noise, at_noise)),
              false, odometry_block_};
    }
    const OdometryParams odometry = withSlip(b_.odometry_, st.d_left, st.d_right, b_.config_.slip_rel_sigma);
    return {std::unique_ptr<ceres::CostFunction>(OdometryFactor::Create(st.d_left, st.d_right, odometry)), false};
  }
  std::vector<int> globalBlockSizes() const override { return sizes_; }
  void globalFactors(std::vector<ChainFactor>* out) const override {
    const SelfCalibrationConfig& c = b_.config_.calibration;
    if (odometry_block_ >= 0) {
      const Eigen::Vector3d sigma(c.wheel_scale_sigma, c.wheel_scale_sigma, c.wheel_base_rel_sigma * b_.odometry_.wheel_base_mm);
      out->push_back({std::unique_ptr<ceres::CostFunction>(CalibrationPriorFactor<3>::Create(
                          nominalWheels(), sigma.cwiseAbs2().asDiagonal().toDenseMatrix())),
                      false, odometry_block_});
    }
    if (stereo_block_ >= 0) {
      CalibrationEstimate::StereoVector sigma;
      sigma << c.tilt_sigma_rad, c.baseline_scale_sigma, c.disparity_offset_sigma_px, c.column_offset_sigma_px,
          c.focal_ratio_sigma, c.focal_scale_sigma;
      if (row_sigma_) {
        // The joined block (q, [e,] dv, b_1..b_K): e whitened (prior the identity), dv and the
        // feature offsets with their stated sigmas.
        const int m = image_sigmas_ ? kImage : 0;
        const int size = sizes_[static_cast<size_t>(stereo_block_)];
        Eigen::VectorXd joined = Eigen::VectorXd::Zero(size), sd(size);
        joined.head<kStereo>() = nominalHead();
        sd.head<kStereo>() = sigma;
        sd.segment(kStereo, m).setOnes();
        sd[kStereo + m] = *row_sigma_;
        for (const FeatureOffsetPrior& f : features_) {
          const std::array<int, 2>& at = feature_index_.at(f.landmark_id);
          if (at[0] >= 0) sd[at[0]] = f.sigma.column;
          if (at[1] >= 0) sd[at[1]] = f.sigma.disparity;
        }
        out->push_back({std::make_unique<DiagonalPriorFactor>(joined, sd), false, stereo_block_});
      } else if (image_sigmas_) {
        // The image block is whitened (StereoPixelImageCalibrationFactor): its prior is the identity.
        Eigen::Matrix<double, kStereo + kImage, 1> joined;
        joined << nominalHead(), Eigen::Matrix<double, kImage, 1>::Zero();
        Eigen::Matrix<double, kStereo + kImage, 1> variance;
        variance << sigma.cwiseAbs2(), Eigen::Matrix<double, kImage, 1>::Ones();
        out->push_back({std::unique_ptr<ceres::CostFunction>(CalibrationPriorFactor<kStereo + kImage>::Create(
                            joined, variance.asDiagonal().toDenseMatrix())),
                        false, stereo_block_});
      } else {
        out->push_back({std::unique_ptr<ceres::CostFunction>(CalibrationPriorFactor<kStereo>::Create(
                            nominalHead(), sigma.cwiseAbs2().asDiagonal().toDenseMatrix())),
                        false, stereo_block_});
      }
    }
  }
  // The global blocks' nominal values, concatenated (the solver's start).
  std::vector<double> nominalGlobals() const {
    std::vector<double> g;
    const Eigen::Vector3d wheels = nominalWheels();
    const CalibrationEstimate::StereoVector head = nominalHead();
    if (odometry_block_ >= 0) g.insert(g.end(), wheels.data(), wheels.data() + 3);
    if (stereo_block_ >= 0) g.insert(g.end(), head.data(), head.data() + kStereo);
    if (image_sigmas_) g.insert(g.end(), static_cast<size_t>(kImage), 0.0);
    if (row_sigma_) g.push_back(0.0);
    if (stereo_block_ >= 0) g.resize(g.size() + static_cast<size_t>(sizes_[static_cast<size_t>(stereo_block_)]) -
                                     (kStereo + (image_sigmas_ ? kImage : 0) + (row_sigma_ ? 1 : 0)), 0.0);
    return g;
  }
  // The image block's sigmas (whitened parameter i is sigma_i e_i), when estimated.
  const std::optional<CalibrationEstimate::ImageVector>& imageSigmas() const { return image_sigmas_; }
  // The feature offsets' landmarks and prior sigmas (px), and where each sits in the stereo block
  // (column, u_r; -1 where not estimated).
  const std::vector<FeatureOffsetPrior>& features() const { return features_; }
  std::array<int, 2> featureIndices(int landmark_id) const { return feature_index_.at(landmark_id); }
  // The row block's prior sigma (px), when estimated.
  const std::optional<double>& rowSigma() const { return row_sigma_; }
  int odometryBlock() const { return odometry_block_; }
  int stereoBlock() const { return stereo_block_; }
  // The odometry factor into pose i is removed (true) or restored.
  void setCut(size_t i, bool cut) { cut_[i] = cut ? 1 : 0; }

 private:
  const BatchSmoother& b_;
  size_t first_, n_;
  Eigen::Matrix3d prior_covariance_;
  std::vector<uint8_t> cut_;
  std::vector<uint8_t> left_out_;  // per observation in observations_
  std::vector<int> sizes_;
  int odometry_block_ = -1, stereo_block_ = -1;
  std::optional<CalibrationEstimate::ImageVector> image_sigmas_;
  std::optional<double> row_sigma_;
  std::vector<FeatureOffsetPrior> features_;
  std::unordered_map<int, std::array<int, 2>> feature_index_;  // landmark id -> (column, u_r) index or -1
  Eigen::Vector3d nominalWheels() const { return Eigen::Vector3d(1.0, 1.0, b_.odometry_.wheel_base_mm); }
  static CalibrationEstimate::StereoVector nominalHead() { return CalibrationEstimate().head; }
  static constexpr int kStereo = StereoPixelCalibrationFactor::kCalibrationSize;
  static constexpr int kImage = StereoPixelImageCalibrationFactor::kImageErrorSize;
};

namespace {

// Poses either side of a cut in the windows that place and test it (a test grows its window
// fourfold until its decision is the full one).
constexpr size_t kCutWindowMargin = 256;

// Residual variance factor of the first solve above which the batch starts again, robust, from
// the filter pass's guess (BatchSmootherConfig::robust_start): whitened residuals three times
// their stated size. Calibrating solves of the realistic kidnap that found their basin have 1.6 to
// 2.6; those a lost filter's guess misled, 34 to 190.
constexpr double kRobustStartVarianceFactor = 10.0;

// Cauchy scale of the robust start: 95 % efficiency on unit-variance whitened residuals.
constexpr double kRobustStartCauchyScale = 2.3849;

// The largest whitened residual of the calibration blocks' priors at `globals`: how many prior
// sigmas the furthest calibration parameter lies from its nominal value.
double calibrationPriorZ(const ChainFactorSource& source, const std::vector<double>& globals) {
  std::vector<ChainFactor> priors;
  source.globalFactors(&priors);
  const std::vector<int> sizes = source.globalBlockSizes();
  std::vector<size_t> offset(sizes.size() + 1, 0);
  for (size_t b = 0; b < sizes.size(); ++b) offset[b + 1] = offset[b] + static_cast<size_t>(sizes[b]);
  double worst = 0;
  for (const ChainFactor& f : priors) {
    const double* block = globals.data() + offset[static_cast<size_t>(f.global)];
    Eigen::VectorXd r(f.cost->num_residuals());
    if (!f.cost->Evaluate(&block, r.data(), nullptr)) return std::numeric_limits<double>::infinity();
    worst = std::max(worst, r.cwiseAbs().maxCoeff());
  }
  return worst;
}

}  // namespace

void BatchSmoother::solve() {
  BatchSummary s;
  s.uninitialised_steps = summary_.uninitialised_steps;
  s.filter_seconds = summary_.filter_seconds;
  solved_ = true;
  if (first_index_ < 0) {
    result_ = guess_;
    s.message = "no initial pose (no global fix): nothing to estimate";
    summary_ = s;
    return;
  }
  const auto t_solve = Clock::now();
  observations_.shrink_to_fit();  // before the solver's workspace: the growth slack is not kept
  const size_t first = static_cast<size_t>(first_index_);
  const size_t n = steps_.size() - first;
  std::vector<double> x(3 * n);
  for (size_t i = 0; i < n; ++i) {
    const Pose2& p = guess_[first + i].pose;
    x[3 * i] = p.x;
    x[3 * i + 1] = p.y;
    x[3 * i + 2] = p.theta;
  }
  if (config_.initial_guess == InitialGuess::Filter && given_.empty()) smoothGuess(first, &x);
  // Pose i of x, and the odometry's motion u_i from pose i - 1 into pose i (B.16).
  auto poseAt = [&](size_t i) { return Pose2(x[3 * i], x[3 * i + 1], x[3 * i + 2]); };
  auto setPose = [&](size_t i, const Pose2& p) {
    x[3 * i] = p.x;
    x[3 * i + 1] = p.y;
    x[3 * i + 2] = p.theta;
  };
  auto motionInto = [&](size_t i) {
    const BufferedStep& st = steps_[first + i];
    const Eigen::Vector3d u = controlVector(st.d_left, st.d_right, odometry_.wheel_base_mm);
    return Pose2(u.x(), u.y(), u.z());
  };
  const PoseManifold manifold;
  const std::unique_ptr<ceres::LossFunction> loss = makeLossFunction(config_.loss);
  StepFactorSource source(*this, first, n);
  std::vector<double> globals = source.nominalGlobals();  // the calibration blocks, concatenated
  const ChainProblem chain(source, loss.get(), &globals);
  // The problem (and loss) the solves minimise: `chain`, or during the robust start
  // (BatchSmootherConfig::robust_start) the same factors under a Cauchy loss.
  std::unique_ptr<ceres::LossFunction> start_loss;
  std::unique_ptr<ChainProblem> start_chain;
  const ChainProblem* active = &chain;
  ceres::LossFunction* active_loss = loss.get();
  auto report = [&](const char* phase, long done, long total, int iteration, double cost) {
    if (!config_.progress) return;
    BatchProgress p;
    p.phase = phase;
    p.done = done;
    p.total = total;
    p.iteration = iteration;
    p.cost = cost;
    config_.progress(p);
  };

  // An observation whose factor cannot be evaluated at the initial guess (a pixel factor whose
  // landmark is behind the cameras: the guess is off by more than the view allows, e.g. after a
  // filter pass misled by a miscalibrated rig) would stop the solver before its first step. It
  // is left out of the first solve and tested again at each solution (admitLeftOut): the
  // problem is the same as from a better guess, provided the other factors bring the poses
  // to where the landmark is in view; one still behind the cameras at the solution contradicts
  // the estimate and stays out (summary().observations_left_out).
  auto forEachObservation = [&](auto&& f) {
    for (size_t i = 0; i < n; ++i)
      for (size_t o = observationsBegin(first + i); o < steps_[first + i].observations_end; ++o)
        if (observations_[o].landmark_id >= 0) f(i, o);
  };
  forEachObservation([&](size_t i, size_t o) {
    if (!source.evaluable(o, &x[3 * i], globals)) {
      source.setLeftOut(o, true);
      ++s.observations_left_out_at_guess;
    }
  });
  // Readmits the left-out observations evaluable at x; returns how many.
  auto admitLeftOut = [&] {
    int admitted = 0;
    if (s.observations_left_out_at_guess == 0) return admitted;
    forEachObservation([&](size_t i, size_t o) {
      if (source.leftOut(o) && source.evaluable(o, &x[3 * i], globals)) {
        source.setLeftOut(o, false);
        ++admitted;
      }
    });
    return admitted;
  };

  // Counts of the problem (for the summary and the model selection's BIC).
  long residuals = 3;  // the prior
  auto countFactors = [&] {
    residuals = 3;
    s.observation_factors = s.compass_factors = s.unassociated_observations = 0;
    std::vector<ChainFactor> unary;
    for (size_t i = 0; i < n; ++i) {
      unary.clear();
      source.unaryFactors(i, &unary);
      for (const ChainFactor& f : unary) {
        residuals += f.cost->num_residuals();
        if (f.robust) ++s.observation_factors;
      }
      if (steps_[first + i].compass_sigma > 0 && config_.use_compass) ++s.compass_factors;
      for (size_t o = observationsBegin(first + i); o < steps_[first + i].observations_end; ++o)
        s.unassociated_observations += observations_[o].landmark_id < 0 ? 1 : 0;
    }
    residuals -= 3;  // counted with the unary factors of pose 0
    s.observations_left_out = 0;
    forEachObservation([&](size_t, size_t o) { s.observations_left_out += source.leftOut(o) ? 1 : 0; });
  };
  s.poses = static_cast<int>(n);

  ChainSolverOptions lm;
  lm.max_iterations = config_.max_iterations;
  lm.function_tolerance = config_.function_tolerance;
  lm.gradient_tolerance = config_.gradient_tolerance;
  lm.parameter_tolerance = config_.parameter_tolerance;
  // Minimises over poses [lo, hi) with the cuts set in `source`; returns the cost of the factors
  // touching the range.
  // An unusable solve (a factor not evaluable at the start) throws, or with `may_fail` returns
  // +infinity and leaves x unchanged.
  auto solveRange = [&](size_t lo, size_t hi, bool full, bool may_fail = false) {
    ChainSolverSummary r;
    if (config_.solver == BatchSolver::Chain) {
      ChainSolverOptions o = lm;
      o.solve_globals = full;  // the cut tests' windows hold the calibration
      if (full) o.progress = [&](int it, double cost) { report("solve", it, config_.max_iterations, it, cost); };
      r = active->solve(lo, hi, &x, o);
    } else {
      const std::unique_ptr<ceres::Problem> problem =
          makeCeresProblem(source, active_loss, &manifold, lo, hi, &x, &globals, full);
      ceres::Solver::Options opts;
      opts.linear_solver_type = ceres::SPARSE_NORMAL_CHOLESKY;
      opts.sparse_linear_algebra_library_type = ceres::SUITE_SPARSE;
      opts.minimizer_type = ceres::TRUST_REGION;
      opts.trust_region_strategy_type = ceres::LEVENBERG_MARQUARDT;
      opts.max_num_iterations = config_.max_iterations;
      opts.function_tolerance = config_.function_tolerance;
      opts.gradient_tolerance = config_.gradient_tolerance;
      opts.parameter_tolerance = config_.parameter_tolerance;
      opts.num_threads = config_.num_threads;
      opts.logging_type = ceres::SILENT;
      ceres::Solver::Summary cs;
      ceres::Solve(opts, problem.get(), &cs);
      r.usable = cs.IsSolutionUsable();
      r.converged = cs.termination_type == ceres::CONVERGENCE;
      r.iterations = static_cast<int>(cs.iterations.size()) - 1;
      r.initial_cost = cs.initial_cost;
      r.final_cost = cs.final_cost;
      r.message = cs.message;
    }
    if (!r.usable && may_fail) return std::numeric_limits<double>::infinity();
    if (!r.usable) throw Error("batch smoother: the solver failed: " + r.message);
    if (full) {
      s.iterations += r.iterations;
      s.initial_cost = s.iterations == r.iterations ? r.initial_cost : s.initial_cost;
      s.final_cost = r.final_cost;
      s.solved = true;
      s.converged = r.converged;
      s.message = r.message;
    } else {
      s.cut_test_iterations += r.iterations;
    }
    return r.final_cost;
  };
  auto setCuts = [&](const std::vector<Cut>& cuts, bool cut) {
    for (const Cut& c : cuts)
      if (c.index > first) source.setCut(c.index - first, cut);
  };
  // Drops candidate cuts at the first pose (nothing to cut there).
  cuts_.erase(std::remove_if(cuts_.begin(), cuts_.end(), [&](const Cut& c) { return c.index <= first; }), cuts_.end());
  setCuts(cuts_, true);
  // What the robust start begins again from: the guess, its cuts and its left-out observations.
  const bool may_start_robust = config_.robust_start && config_.loss.type == RobustLoss::None && !cuts_.empty();
  std::vector<double> guess_x, guess_globals;
  std::vector<Cut> guess_cuts;
  std::vector<uint8_t> guess_left_out;
  if (may_start_robust) {
    guess_x = x;
    guess_globals = globals;
    guess_cuts = cuts_;
    guess_left_out.resize(observations_.size());
    for (size_t o = 0; o < observations_.size(); ++o) guess_left_out[o] = source.leftOut(o) ? 1 : 0;
  }
  // Solves the whole chain, readmitting the left-out observations its solution brings into view.
  auto solveAll = [&] {
    double c = solveRange(0, n, true);
    while (admitLeftOut() > 0) c = solveRange(0, n, true);
    return c;
  };
  double cost = solveAll();
  // Residual variance factor of the cut model at `cut_cost` (2 cost / (m - parameters), m the
  // residuals of every factor, odometry included; at least 1), with the factors as last counted:
  // on mismodelled (e.g. real) data whose whitened residuals are larger than unit, the filter
  // loses track without a kidnap, and unscaled tests would place and keep every such cut.
  auto varianceFactor = [&](double cut_cost) {
    const size_t odometry_factors = n - 1 - std::min(n - 1, cuts_.size());
    const double m = static_cast<double>(residuals) + 3.0 * static_cast<double>(odometry_factors);
    const double dof = m - 3.0 * static_cast<double>(n);
    return dof > 0 ? std::max(1.0, 2.0 * cut_cost / dof) : 1.0;
  };
  auto sighted = [&](size_t i) {  // pose i has an observation in the problem
    for (size_t o = observationsBegin(first + i); o < steps_[first + i].observations_end; ++o)
      if (observations_[o].landmark_id >= 0 && !source.leftOut(o)) return true;
    return false;
  };
  // A cut sits right after the last pose the filter confirmed, but the lost filter may have gated
  // out sightings that still came from before the kidnap: the poses up to the re-initialisation
  // that they place would otherwise be tied to the new segment (two goal corners 9e6 in 2 x cost
  // on the realistic kidnap, seed 7, trial 10, and a runaway calibration). Each later place up to
  // the re-initialisation is tried, the poses before it chained forward by the odometry from the
  // old segment, the window around solved with the calibration held; the cut moves to the best
  // place if that lowers 2 x cost by more than the gate's chi-square(3) quantile (times the
  // residual variance factor, as the cut tests). A pose without sightings fits either side, so
  // the cut stays as early as the sightings allow (a teleport changes the view at once).
  auto placeCuts = [&] {
    int moved = 0;
    const double threshold = chi2Quantile(config_.gate.probability, 3) * varianceFactor(cost);
    for (size_t k = 0; k < cuts_.size(); ++k) {
      const size_t c = cuts_[k].index - first;
      const size_t r = cuts_[k].reinit - first;
      const size_t seg_lo = k > 0 ? cuts_[k - 1].index - first : 0;
      const size_t seg_hi = k + 1 < cuts_.size() ? cuts_[k + 1].index - first : n;
      const size_t lo = c > seg_lo + kCutWindowMargin ? c - kCutWindowMargin : seg_lo;
      const size_t hi = std::min(seg_hi, r + kCutWindowMargin);
      double best = 0;
      if (r <= c || !active->cost(lo, hi, x, &best)) continue;
      const std::vector<double> at_cut(x.begin() + static_cast<long>(3 * lo), x.begin() + static_cast<long>(3 * hi));
      std::vector<double> best_x = at_cut;
      size_t best_place = c;
      for (size_t p = c + 1; p <= r && p < hi; ++p) {
        if (!sighted(p - 1)) continue;  // the same cost as at p - 1
        std::copy(at_cut.begin(), at_cut.end(), x.begin() + static_cast<long>(3 * lo));
        for (size_t j = c; j < p; ++j) setPose(j, compose(poseAt(j - 1), motionInto(j)));
        source.setCut(c, false);
        source.setCut(p, true);
        const double placed = solveRange(lo, hi, false, true);
        if (2.0 * (best - placed) > threshold) {
          best = placed;
          best_x.assign(x.begin() + static_cast<long>(3 * lo), x.begin() + static_cast<long>(3 * hi));
          best_place = p;
        }
        source.setCut(p, false);
        source.setCut(c, true);
      }
      std::copy(best_x.begin(), best_x.end(), x.begin() + static_cast<long>(3 * lo));
      if (best_place != c) {
        source.setCut(c, false);
        source.setCut(best_place, true);
        cuts_[k].index = first + best_place;
        ++moved;
      }
    }
    return moved;
  };
  if (!cuts_.empty()) countFactors();
  if (placeCuts() > 0) cost = solveAll();
  // A first solve that fits badly after a lost filter pass: the guess's gross errors misled it
  // (BatchSmootherConfig::robust_start). It begins again from the guess, robust.
  if (may_start_robust && varianceFactor(cost) > kRobustStartVarianceFactor) {
    x = guess_x;
    globals = guess_globals;
    setCuts(cuts_, false);
    cuts_ = guess_cuts;
    setCuts(cuts_, true);
    for (size_t o = 0; o < observations_.size(); ++o) source.setLeftOut(o, guess_left_out[o] != 0);
    start_loss = makeLossFunction({RobustLoss::Cauchy, kRobustStartCauchyScale});
    start_chain = std::make_unique<ChainProblem>(source, start_loss.get(), &globals);
    active = start_chain.get();
    active_loss = start_loss.get();
    cost = solveAll();
    if (placeCuts() > 0) cost = solveAll();
  }
  std::vector<double>().swap(guess_x);  // not needed any more: off the later phases' peak memory
  // With the stereo calibration estimated, the unidentified observations are associated again at
  // the solution: the filter pass associated them with the nominal calibration, whose errors
  // (a focal-length difference of 1.7 % moves the disparity by ~3 px at the image's edge) pair
  // floor markings with the wrong landmarks, and the solve, holding those pairings, settles on a
  // wrong calibration. Each pass takes the solved poses and calibration; it stops when no
  // pairing changes.
  std::map<size_t, std::vector<int>> filter_pairings;  // the filter pass's landmark ids per step index
  // Returns how many pairings changed.
  auto reassociate = [&] {
    const ObservationModelConfig& model = config_.observation_model;
    const double* q = globals.data() + (source.odometryBlock() >= 0 ? 3 : 0);  // (dbeta, k, dd, du, phi, psi)
    StereoRigParams params = model.rig.params();
    params.tilt_rad += q[0];
    const StereoRig rig = model.rig.calibration() ? StereoRig(params, *model.rig.calibration()) : StereoRig(params);
    const double ou = rig.principalU(), ov = rig.principalV(), scale = 1.0 + q[5];
    // The row offset dv, last in the stereo block when estimated (its slide s dv leaves u_r).
    const double dv = source.rowSigma() ? q[StereoPixelCalibrationFactor::kCalibrationSize +
                                            (source.imageSigmas() ? StereoPixelImageCalibrationFactor::kImageErrorSize : 0)]
                                        : 0.0;
    int changed = 0;
    for (const auto& [index, raw] : raw_observations_) {
      if (index < first) continue;
      const size_t i = index - first;
      // The pixels as the nominal rig would have seen them (the inverse of
      // factors/stereo_pixel_calibration_factor.h's columns and rows), as range and bearing.
      std::vector<Observation> corrected = raw;
      for (Observation& o : corrected) {
        if (o.landmark_id >= 0 || !o.pixels) continue;
        const double cl = (o.pixels->u_left - ou - q[3] - 0.5 * q[2]) / scale;
        const double cr = (o.pixels->u_right - o.slide_gain * dv - ou - q[3] + 0.5 * q[2]) / (scale * (1.0 + q[4]));
        const double mean = 0.5 * (cl + cr), disparity = (cl - cr) / q[1];
        const StereoPixels px{ou + mean + 0.5 * disparity, ov + (o.pixels->v_left - ov) / scale,
                              ou + mean - 0.5 * disparity, ov + (o.pixels->v_right - ov) / scale};
        Landmark kind;
        kind.type = o.type;
        try {
          const double gain = o.slide_gain;
          o = observationFromPixels(rig, -1, o.type, px, o.head_pan, pixelCovarianceFor(o, kind, model));
          o.slide_gain = gain;
        } catch (const Error&) {
          // Not triangulable with the calibration (disparity too small): keeps its nominal form.
        }
      }
      const Pose2 pose = poseAt(i);
      const std::vector<Observation> a = associateObservations(corrected, pose, guess_[index].covariance, map_, config_.association);
      const size_t begin = observationsBegin(index);
      const auto filtered = filter_pairings.find(index);
      for (size_t k = 0; k < a.size(); ++k) {
        Observation& target = observations_[begin + k];
        // An observation the solution cannot pair (outside every gate, or ambiguous) keeps the
        // filter pass's pairing.
        const int id = a[k].landmark_id >= 0 || filtered == filter_pairings.end() ? a[k].landmark_id : filtered->second[k];
        if (target.landmark_id == id) continue;
        target.landmark_id = id;
        ++changed;
        source.setLeftOut(begin + k, false);
        if (target.landmark_id >= 0 && !source.evaluable(begin + k, &x[3 * i], globals)) {
          source.setLeftOut(begin + k, true);
          ++s.observations_left_out_at_guess;
        }
      }
    }
    return changed;
  };
  constexpr int kReassociationPasses = 3;
  const bool reassociate_passes = config_.reassociate_with_calibration && source.stereoBlock() >= 0 && !raw_observations_.empty();
  // Drops the pairings of the unidentified observations, so that a solve places the chain with
  // the identified landmarks alone.
  auto unpairUnidentified = [&] {
    for (const auto& [index, raw] : raw_observations_) {
      if (index < first) continue;
      const size_t begin = observationsBegin(index);
      for (size_t k = 0; k < raw.size(); ++k)
        if (raw[k].landmark_id < 0) {
          observations_[begin + k].landmark_id = -1;
          source.setLeftOut(begin + k, false);
        }
    }
  };
  // Pairs the unidentified observations at the solution and solves again, until no pairing
  // changes (at most kReassociationPasses times); returns the cost, `c` if nothing changed.
  auto solveReassociating = [&](double c) {
    for (int pass = 0; pass < kReassociationPasses && reassociate_passes; ++pass) {
      if (reassociate() == 0) break;
      c = solveAll();
    }
    return c;
  };
  if (reassociate_passes) {
    // The first solve's calibration comes from the identified landmarks alone (the pairings of
    // the others are the nominal calibration's guesses); they are paired at its solution.
    for (const auto& [index, raw] : raw_observations_) {
      if (index < first) continue;
      const size_t begin = observationsBegin(index);
      std::vector<int>& ids = filter_pairings[index];
      for (size_t k = 0; k < raw.size(); ++k) ids.push_back(observations_[begin + k].landmark_id);
    }
    unpairUnidentified();
    cost = solveAll();
  }
  if (start_chain) {
    // The robust start ends: least squares from its solution, paired again there.
    active = &chain;
    active_loss = loss.get();
    if (reassociate_passes) reassociate();
    cost = solveAll();
  }
  cost = solveReassociating(cost);
  countFactors();
  int withdrawn = 0;
  const auto t_cuts = Clock::now();
  if (!cuts_.empty()) {
    // A segment the data do not determine cannot be verified, nor estimated on its own.
    std::vector<Eigen::Matrix3d> D, B, cov;
    std::vector<Eigen::Vector3d> g;
    double c0 = 0;
    if (!chain.linearise(0, n, x, &D, &B, &g, &c0) || !chainMarginalCovariances(D, B, &cov)) {
      withdrawn += static_cast<int>(cuts_.size());
      setCuts(cuts_, false);
      cuts_.clear();
      cost = solveAll();
    }
  }
  if (!cuts_.empty()) {
    // Model selection for each cut, in step order: a cut frees the 3 degrees of freedom of the
    // segment after it; by the Bayesian information criterion it is kept only if restoring its
    // odometry factor raises 2 x cost by more than 3 ln(m), m the number of residuals (and at
    // least the gate's chi-square(3) quantile). A rare kidnap thus needs strong evidence: one
    // outlier that a free pose can fit does not cut the chain.
    const double threshold = std::max({chi2Quantile(config_.gate.probability, 3),
                                       3.0 * std::log(std::max(2.0, static_cast<double>(residuals))),
                                       config_.cut_min_evidence});
    const double variance_factor = varianceFactor(cost);
    // Restoring a cut changes only the segments it joins (the others stay cut off), and within
    // them its effect decays along the chain: the test solves a window around the cut and its
    // unobserved stretch with the poses outside held at the cut solution. Holding them can only
    // raise the restored cost, so a rise below the threshold withdraws the cut exactly; a rise
    // above it is confirmed on a window that reaches the neighbouring cuts or whose edge poses
    // did not move, growing the window fourfold until then. Holding an edge that wanted to move
    // by d changes the restored cost by about (information) d^2: with d below 1e-3 mm and 1e-6 rad
    // that is far below the threshold (>= 1000 by default), so the decision is the full one.
    constexpr double kEdgeToleranceMm = 1e-3, kEdgeToleranceRad = 1e-6;
    const long total_cuts = static_cast<long>(cuts_.size());
    long tested = 0;
    // The re-initialisation of the last candidate withdrawn since the previous kept cut: see
    // moveCutToFix.
    long withdrawn_fix = -1;  // local index, -1: none
    int moved_cuts = 0;
    // A kept cut sits right after the last pose the filter confirmed before it lost track. When
    // the filter lost track earlier, a withdrawn candidate stretches back over that loss and the
    // kept cut can only follow the withdrawn candidate's re-initialisation a; but the global fix
    // at a is a pose the data place, and the robot may have been moved right before it (the filter
    // fixed itself at once, then lost track again). The cut at c therefore also tries a (the poses
    // a .. c-1 re-chained backwards from pose c by the odometry, as at the candidate's creation)
    // and moves there if that solves the window around both to a lower cost: the same number of
    // parameters, so the lower cost is the likelier place.
    auto moveCutToFix = [&](size_t c, size_t a, size_t seg_lo, size_t seg_hi, size_t r) {
      const size_t lo = a > seg_lo + kCutWindowMargin ? a - kCutWindowMargin : seg_lo;
      const size_t hi = std::min(seg_hi, r + kCutWindowMargin);
      double base = 0;
      if (!chain.cost(lo, hi, x, &base)) return false;
      const std::vector<double> keep(x.begin() + static_cast<long>(3 * lo), x.begin() + static_cast<long>(3 * hi));
      for (size_t j = c; j-- > a;) setPose(j, compose(poseAt(j + 1), inverse(motionInto(j + 1))));
      source.setCut(c, false);
      source.setCut(a, true);
      const double moved = solveRange(lo, hi, false, true);
      if (moved < base) return true;
      std::copy(keep.begin(), keep.end(), x.begin() + static_cast<long>(3 * lo));
      source.setCut(a, false);
      source.setCut(c, true);
      return false;
    };
    for (size_t k = 0; k < cuts_.size();) {
      report("cut test", tested++, total_cuts, 0, cost);
      const size_t c = cuts_[k].index - first;
      const size_t r = std::max(c, cuts_[k].reinit - first);
      const size_t seg_lo = k > 0 ? cuts_[k - 1].index - first : 0;
      const size_t seg_hi = k + 1 < cuts_.size() ? cuts_[k + 1].index - first : n;
      bool keep_cut = true;
      for (size_t margin = kCutWindowMargin;; margin *= 4) {
        const size_t lo = c > seg_lo + margin ? c - margin : seg_lo;
        const size_t hi = std::min(seg_hi, r + margin);
        const std::vector<double> keep(x.begin() + static_cast<long>(3 * lo), x.begin() + static_cast<long>(3 * hi));
        double base = 0;
        if (!chain.cost(lo, hi, x, &base)) throw Error("batch smoother: a factor cannot be evaluated at the solution");
        source.setCut(c, false);
        // Two starts: the cut solution, and the segment after the cut moved rigidly to continue
        // the odometry from the pose before it (a robust loss would otherwise keep a misplaced
        // segment); the better optimum counts, so a cut is kept only on the evidence. When the
        // first already withdraws the cut, the second cannot keep it.
        double restored = solveRange(lo, hi, false);
        if (2.0 * (restored - base) / variance_factor > threshold) {
          std::vector<double> best(x.begin() + static_cast<long>(3 * lo), x.begin() + static_cast<long>(3 * hi));
          std::copy(keep.begin(), keep.end(), x.begin() + static_cast<long>(3 * lo));
          const Pose2 target = compose(poseAt(c - 1), motionInto(c));
          const Pose2 start = poseAt(c);
          for (size_t j = c; j < hi; ++j) setPose(j, compose(target, between(start, poseAt(j))));
          const double restored_moved = solveRange(lo, hi, false, true);
          if (restored_moved < restored)
            restored = restored_moved;
          else
            std::copy(best.begin(), best.end(), x.begin() + static_cast<long>(3 * lo));
        }
        const double evidence = 2.0 * (restored - base) / variance_factor;
        auto edgeMoved = [&](size_t j) {
          const size_t o = 3 * (j - lo);
          return std::fabs(x[3 * j] - keep[o]) > kEdgeToleranceMm || std::fabs(x[3 * j + 1] - keep[o + 1]) > kEdgeToleranceMm ||
                 std::fabs(wrapAngle(x[3 * j + 2] - keep[o + 2])) > kEdgeToleranceRad;
        };
        const bool exact = (lo == seg_lo || !edgeMoved(lo)) && (hi == seg_hi || !edgeMoved(hi - 1));
        if (evidence <= threshold) {
          keep_cut = false;
          break;
        }
        std::copy(keep.begin(), keep.end(), x.begin() + static_cast<long>(3 * lo));
        source.setCut(c, true);
        if (exact) break;
      }
      if (keep_cut) {
        const size_t a = static_cast<size_t>(withdrawn_fix);
        if (withdrawn_fix >= 0 && a > seg_lo && a < c && moveCutToFix(c, a, seg_lo, seg_hi, r)) {
          cuts_[k].index = first + a;
          ++moved_cuts;
        }
        withdrawn_fix = -1;
        ++k;
      } else {
        withdrawn_fix = static_cast<long>(cuts_[k].reinit - first);
        cuts_.erase(cuts_.begin() + static_cast<long>(k));
        ++withdrawn;
      }
    }
    s.cut_test_seconds = secondsSince(t_cuts);
    // The final solve with the kept cuts, from the windows' solutions; a moved cut moved poses
    // whose unidentified observations were paired where they were.
    cost = solveAll();
    if (moved_cuts > 0) cost = solveReassociating(cost);
  }
  // A miscalibrated filter pass loses track without a kidnap, and a cut kept on its evidence
  // lets a segment and the calibration settle together on a wrong solution: a calibration
  // parameter far outside its prior (a baseline scale 28 sigma off, a wheel base at half) says
  // so. The chain is then solved whole, its pairings redone at that solution, and kept if its
  // calibration is plausible; a real kidnap's chain cannot be, and the cuts stay.
  if (!cuts_.empty() && !globals.empty() && calibrationPriorZ(source, globals) > kImplausiblePriorSigmas) {
    const std::vector<double> keep_x = x, keep_globals = globals;
    std::vector<int> keep_ids(observations_.size());
    std::vector<uint8_t> keep_left_out(observations_.size());
    for (size_t o = 0; o < observations_.size(); ++o) {
      keep_ids[o] = observations_[o].landmark_id;
      keep_left_out[o] = source.leftOut(o) ? 1 : 0;
    }
    setCuts(cuts_, false);
    // The pairings made on the cut segments are not trusted: as after the filter pass, the
    // identified landmarks alone place the whole chain first.
    if (reassociate_passes) unpairUnidentified();
    const double whole = solveReassociating(solveAll());
    if (calibrationPriorZ(source, globals) <= kImplausiblePriorSigmas) {
      cost = whole;
      withdrawn += static_cast<int>(cuts_.size());
      cuts_.clear();
    } else {
      x = keep_x;
      globals = keep_globals;
      for (size_t o = 0; o < observations_.size(); ++o) {
        observations_[o].landmark_id = keep_ids[o];
        source.setLeftOut(o, keep_left_out[o] != 0);
      }
      setCuts(cuts_, true);
    }
  }
  countFactors();
  s.solve_seconds = secondsSince(t_solve);
  s.withdrawn_cuts = withdrawn;
  s.segments = 1 + static_cast<int>(cuts_.size());
  s.odometry_factors = static_cast<int>(n) - 1 - static_cast<int>(cuts_.size());
  for (const Cut& c : cuts_) {
    s.cut_steps.push_back(steps_[c.index].step);
    s.reinit_steps.push_back(steps_[c.reinit].step);
  }

  // The chain marginals first, then the result: each phase holds one more copy of the
  // trajectory's size, not two (the peak memory of a long run).
  std::vector<Eigen::Matrix3d> chain_cov;
  Eigen::MatrixXd global_covariance = Eigen::MatrixXd::Zero(static_cast<Eigen::Index>(globals.size()),
                                                            static_cast<Eigen::Index>(globals.size()));
  const bool chain_covariance = config_.compute_covariance && config_.covariance_method == CovarianceMethod::Chain;
  if (config_.compute_covariance) report("covariance", 0, 1, 0, cost);
  if (chain_covariance) {
    const auto t1 = Clock::now();
    bool ok = false;
    double c0 = 0;
    if (globals.empty()) {
      std::vector<Eigen::Matrix3d> D, B;
      std::vector<Eigen::Vector3d> g;
      ok = chain.linearise(0, n, x, &D, &B, &g, &c0);
      g = std::vector<Eigen::Vector3d>();
      ok = ok && chainMarginalCovariances(D, B, &chain_cov);
    } else {
      BorderedSystem h;
      ok = chain.linearise(0, n, x, &h, &c0) && borderedMarginalCovariances(h, &chain_cov, &global_covariance);
    }
    if (ok) {
      s.covariance_status = CovarianceStatus::Ok;
    } else {
      chain_cov.clear();
      global_covariance.setZero();
      s.covariance_status = CovarianceStatus::RankDeficient;
      s.message += "; covariance: the information matrix is rank deficient, marginal covariances are not available";
    }
    s.covariance_seconds = secondsSince(t1);
  }
  result_ = guess_;
  for (size_t i = 0; i < n; ++i) {
    Estimate& e = result_[first + i];
    e.pose = Pose2(x[3 * i], x[3 * i + 1], x[3 * i + 2]);
    e.covariance = chain_cov.empty() ? Eigen::Matrix3d::Zero() : chain_cov[i];
    e.status = EstimateStatus::Tracking;
  }
  chain_cov = std::vector<Eigen::Matrix3d>();
  if (config_.compute_covariance && !chain_covariance) {
    const auto t1 = Clock::now();
    const std::unique_ptr<ceres::Problem> problem =
        makeCeresProblem(source, loss.get(), &manifold, 0, n, &x, &globals, true);
    ceres::Covariance::Options copts;
    copts.algorithm_type = ceres::SPARSE_QR;
    copts.sparse_linear_algebra_library_type = ceres::SUITE_SPARSE;
    copts.num_threads = config_.num_threads;
    copts.apply_loss_function = true;
    ceres::Covariance covariance(copts);
    std::vector<std::pair<const double*, const double*>> blocks;
    blocks.reserve(n);
    for (size_t i = 0; i < n; ++i) blocks.emplace_back(&x[3 * i], &x[3 * i]);
    const std::vector<int> sizes = source.globalBlockSizes();
    std::vector<double*> global_blocks;
    for (size_t k = 0, offset = 0; k < sizes.size(); offset += static_cast<size_t>(sizes[k]), ++k)
      global_blocks.push_back(globals.data() + offset);
    for (double* a : global_blocks)
      for (double* b : global_blocks) blocks.emplace_back(a, b);
    if (covariance.Compute(blocks, problem.get())) {
      s.covariance_status = CovarianceStatus::Ok;
      for (size_t a = 0, oa = 0; a < sizes.size(); oa += static_cast<size_t>(sizes[a]), ++a)
        for (size_t b = 0, ob = 0; b < sizes.size(); ob += static_cast<size_t>(sizes[b]), ++b) {
          Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor> C(sizes[a], sizes[b]);
          covariance.GetCovarianceBlock(global_blocks[a], global_blocks[b], C.data());
          global_covariance.block(static_cast<Eigen::Index>(oa), static_cast<Eigen::Index>(ob), sizes[a], sizes[b]) = C;
        }
      for (size_t i = 0; i < n; ++i) {
        Eigen::Matrix<double, 3, 3, Eigen::RowMajor> C;
        if (!covariance.GetCovarianceBlockInTangentSpace(&x[3 * i], &x[3 * i], C.data())) {
          s.covariance_status = CovarianceStatus::RankDeficient;
          break;
        }
        result_[first + i].covariance = 0.5 * (C + C.transpose());
      }
    } else {
      s.covariance_status = CovarianceStatus::RankDeficient;
    }
    if (s.covariance_status != CovarianceStatus::Ok) {
      for (size_t i = 0; i < n; ++i) result_[first + i].covariance.setZero();
      global_covariance.setZero();
      s.message += "; covariance: the Jacobian is rank deficient, marginal covariances are not available";
    }
    s.covariance_seconds = secondsSince(t1);
  }
  CalibrationEstimate& cal = calibration_;
  cal = CalibrationEstimate();
  cal.wheels.z() = odometry_.wheel_base_mm;
  cal.odometry = source.odometryBlock() >= 0;
  cal.stereo = source.stereoBlock() >= 0;
  {
    Eigen::Index offset = 0;
    const Eigen::Map<const Eigen::VectorXd> c(globals.data(), static_cast<Eigen::Index>(globals.size()));
    if (cal.odometry) {
      cal.wheels = c.segment<3>(offset);
      cal.wheels_covariance = global_covariance.block<3, 3>(offset, offset);
      offset += 3;
    }
    if (cal.stereo) {
      constexpr int k = StereoPixelCalibrationFactor::kCalibrationSize;
      cal.head = c.segment<k>(offset);
      cal.head_covariance = global_covariance.block<k, k>(offset, offset);
      if (const auto& sigmas = source.imageSigmas()) {
        // Back from the whitened block to its units.
        constexpr int m = StereoPixelImageCalibrationFactor::kImageErrorSize;
        cal.image = true;
        cal.image_errors = sigmas->cwiseProduct(c.segment<m>(offset + k));
        cal.image_covariance =
            sigmas->asDiagonal() * global_covariance.block<m, m>(offset + k, offset + k) * sigmas->asDiagonal();
      }
      if (source.rowSigma()) {
        const Eigen::Index r = offset + k + (source.imageSigmas() ? StereoPixelImageCalibrationFactor::kImageErrorSize : 0);
        cal.row = true;
        cal.row_offset_px = c[r];
        cal.row_offset_variance = global_covariance(r, r);
        for (const FeatureOffsetPrior& f : source.features()) {
          const std::array<int, 2> at = source.featureIndices(f.landmark_id);
          CalibrationEstimate::FeatureOffset e;
          e.landmark_id = f.landmark_id;
          if (at[0] >= 0) {
            e.column_px = c[offset + at[0]];
            e.column_variance = global_covariance(offset + at[0], offset + at[0]);
          }
          if (at[1] >= 0) {
            e.offset_px = c[offset + at[1]];
            e.variance = global_covariance(offset + at[1], offset + at[1]);
          }
          cal.feature_offsets.push_back(e);
        }
      }
    }
  }
  summary_ = s;
}

}  // namespace stereoloc
