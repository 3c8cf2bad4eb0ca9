#include "solvers/batch_smoother.h"

#include <ceres/covariance.h>
#include <ceres/solver.h>

#include <algorithm>
#include <Eigen/Cholesky>
#include <chrono>
#include <cmath>
#include <memory>
#include <utility>

#include "factors/compass_factor.h"
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
      steps_.push_back(step);
      raw_observations_.emplace_back();
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
      steps_.push_back(step);
      raw_observations_.emplace_back();
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
  raw_observations_.emplace_back();
  if (needs_association) {
    raw_observations_.back() = step.observations;  // re-associated if a kidnap cut moves this pose
    step.observations = associateObservations(step.observations, e.pose, guess_covariance_, map_, config_.association);
  }
  steps_.push_back(std::move(step));
  guess_.push_back(e);
  return e;
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
    const Step& s = j == index ? step : steps_[j];
    const PosePrediction pp = predictPose(pred, P, s.d_left, s.d_right, odometry_);  // (5.7), (5.9)
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
    const Step& next = j + 1 == index ? step : steps_[j + 1];
    const Eigen::Vector3d u = controlVector(next.d_left, next.d_right, odometry_.wheel_base_mm);
    Matrix3d J_inv, J1, J2;
    const Pose2 u_inv = inverse(Pose2(u.x(), u.y(), u.z()), &J_inv);
    p = compose(p, u_inv, &J1, &J2);
    const Eigen::Matrix3d Ju = J2 * J_inv;
    P = J1 * P * J1.transpose() + Ju * controlCovariance(next.d_left, next.d_right, odometry_) * Ju.transpose();
    P = 0.5 * (P + P.transpose());
    guess_[j].pose = p;
    guess_[j].covariance = P;
    guess_[j].status = EstimateStatus::Predicted;
    if (!raw_observations_[j].empty())
      steps_[j].observations = associateObservations(raw_observations_[j], p, P, map_, config_.association);
  }
  return true;
}

std::vector<Estimate> BatchSmoother::finish() {
  if (!solved_) solve();
  return result_;
}

void BatchSmoother::solve() {
  using Clock = std::chrono::steady_clock;
  BatchSummary s;
  s.uninitialised_steps = summary_.uninitialised_steps;
  result_ = guess_;
  solved_ = true;
  if (first_index_ < 0) {
    s.message = "no initial pose (no global fix): nothing to estimate";
    summary_ = s;
    return;
  }
  const size_t first = static_cast<size_t>(first_index_);
  const size_t n = steps_.size() - first;
  std::vector<double> x(3 * n);
  for (size_t i = 0; i < n; ++i) {
    const Pose2& p = guess_[first + i].pose;
    x[3 * i] = p.x;
    x[3 * i + 1] = p.y;
    x[3 * i + 2] = p.theta;
  }
  PoseManifold manifold;
  const std::unique_ptr<ceres::LossFunction> loss = makeLossFunction(config_.loss);
  ceres::Problem::Options popts;
  popts.manifold_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  popts.loss_function_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  std::unique_ptr<ceres::Problem> problem_ptr;
  // Every factor with the poses it links (b = -1: unary), for the chain covariance.
  struct Link {
    const ceres::CostFunction* cost;
    long a, b;
    bool robust;
  };
  std::vector<Link> links;
  // The diagonal and super-diagonal 3x3 blocks of the Gauss-Newton information at x (robust
  // factors weighted by rho'(s) at the solution, no second-order term); false if a factor
  // cannot be evaluated.
  auto chainInformation = [&](std::vector<Eigen::Matrix3d>* D, std::vector<Eigen::Matrix3d>* B) {
    D->assign(n, Eigen::Matrix3d::Zero());
    B->assign(n, Eigen::Matrix3d::Zero());
    using RowMajor = Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor>;
    for (const Link& l : links) {
      const int m = l.cost->num_residuals();
      RowMajor Ja(m, 3), Jb(m, 3);
      Eigen::VectorXd r(m);
      const double* params[2] = {&x[3 * static_cast<size_t>(l.a)], l.b >= 0 ? &x[3 * static_cast<size_t>(l.b)] : nullptr};
      // A unary factor has one parameter block: Jb is neither written nor read (checking its
      // uninitialised contents made the result depend on the heap).
      const bool binary = l.b >= 0;
      double* jac[2] = {Ja.data(), binary ? Jb.data() : nullptr};
      if (!l.cost->Evaluate(params, r.data(), jac) || !Ja.allFinite() || (binary && !Jb.allFinite())) return false;
      if (l.robust) {
        double rho[3];
        loss->Evaluate(r.squaredNorm(), rho);
        const double w = std::sqrt(std::max(rho[1], 0.0));
        Ja *= w;
        if (binary) Jb *= w;
      }
      (*D)[static_cast<size_t>(l.a)] += Ja.transpose() * Ja;
      if (l.b >= 0) {
        (*D)[static_cast<size_t>(l.b)] += Jb.transpose() * Jb;
        (*B)[static_cast<size_t>(l.b)] += Ja.transpose() * Jb;  // the poses are consecutive: a = b - 1
      }
    }
    return true;
  };

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
  opts.minimizer_progress_to_stdout = false;
  const int uninitialised = s.uninitialised_steps;
  double solve_seconds = 0;
  // Builds and solves the problem with the odometry factors into the poses `cut` removed,
  // from the current x; returns the final cost.
  auto solveWith = [&](const std::vector<size_t>& cut) {
    s = BatchSummary();
    s.uninitialised_steps = uninitialised;
    problem_ptr = std::make_unique<ceres::Problem>(popts);
    ceres::Problem& problem = *problem_ptr;
    links.clear();
    for (size_t i = 0; i < n; ++i) problem.AddParameterBlock(&x[3 * i], 3, &manifold);
    auto add = [&](ceres::CostFunction* cost, ceres::LossFunction* lf, long a, long b) {
      if (b < 0)
        problem.AddResidualBlock(cost, lf, &x[3 * static_cast<size_t>(a)]);
      else
        problem.AddResidualBlock(cost, lf, &x[3 * static_cast<size_t>(a)], &x[3 * static_cast<size_t>(b)]);
      links.push_back(Link{cost, a, b, lf != nullptr});
    };
    add(PosePriorFactor::Create(prior_pose_, 0.5 * (prior_covariance_ + prior_covariance_.transpose())), nullptr, 0, -1);
    for (size_t i = 0; i < n; ++i) {
      const Step& st = steps_[first + i];
      const long li = static_cast<long>(i);
      if (i > 0 && std::find(cut.begin(), cut.end(), first + i) == cut.end()) {
        add(OdometryFactor::Create(st.d_left, st.d_right, odometry_), nullptr, li - 1, li);
        ++s.odometry_factors;
      }
      if (st.compass && config_.use_compass) {
        add(CompassFactor::Create(*st.compass, st.compass_sigma), nullptr, li, -1);
        ++s.compass_factors;
      }
      for (const Observation& o : st.observations) {
        if (o.landmark_id < 0) {
          ++s.unassociated_observations;
          continue;
        }
        add(makeObservationFactor(o, map_.at(o.landmark_id), config_.observation_model), loss.get(), li, -1);
        ++s.observation_factors;
      }
    }
    s.segments = 1 + static_cast<int>(cut.size());
    s.poses = static_cast<int>(n);
    ceres::Solver::Summary cs;
    const auto t0 = Clock::now();
    ceres::Solve(opts, &problem, &cs);
    solve_seconds += std::chrono::duration<double>(Clock::now() - t0).count();
    s.solve_seconds = solve_seconds;
    s.iterations = static_cast<int>(cs.iterations.size()) - 1;
    s.initial_cost = cs.initial_cost;
    s.final_cost = cs.final_cost;
    s.solved = cs.IsSolutionUsable();
    s.converged = cs.termination_type == ceres::CONVERGENCE;
    s.message = cs.message;
    if (!s.solved) throw Error("batch smoother: Ceres failed: " + cs.message);
    return cs.final_cost;
  };
  auto cutIndices = [&](const std::vector<Cut>& cuts) {
    std::vector<size_t> v;
    for (const Cut& c : cuts)
      if (c.index > first) v.push_back(c.index);
    return v;
  };
  double cost = solveWith(cutIndices(cuts_));
  int withdrawn = 0;
  if (!cuts_.empty()) {
    // A segment the data do not determine cannot be verified, nor estimated on its own.
    std::vector<Eigen::Matrix3d> D, B, cov;
    if (!chainInformation(&D, &B) || !chainMarginalCovariances(D, B, &cov)) {
      withdrawn += static_cast<int>(cuts_.size());
      cuts_.clear();
      cost = solveWith({});
    }
    // Model selection for each cut, in step order: a cut frees the 3 degrees of freedom of the
    // segment after it; by the Bayesian information criterion it is kept only if restoring its
    // odometry factor raises 2 x cost by more than 3 ln(m), m the number of residuals (and at
    // least the gate's chi-square(3) quantile). A rare kidnap thus needs strong evidence: one
    // outlier that a free pose can fit does not cut the chain. Each hypothesis starts from its
    // own guess: without the cut, the segment after it is moved rigidly to continue the odometry
    // from the pose before the cut (a robust loss would otherwise keep a misplaced segment).
    const double threshold = std::max({chi2Quantile(config_.gate.probability, 3),
                                       3.0 * std::log(std::max(2.0, static_cast<double>(problem_ptr->NumResiduals()))),
                                       config_.cut_min_evidence});
    // Residual variance factor of the cut model (2 cost / (m - parameters), at least 1): on
    // mismodelled (e.g. real) data whose whitened residuals are larger than unit, the filter
    // loses track without a kidnap and an unscaled test would keep every such cut.
    const double dof = static_cast<double>(problem_ptr->NumResiduals()) - 3.0 * static_cast<double>(n);
    const double variance_factor = dof > 0 ? std::max(1.0, 2.0 * cost / dof) : 1.0;
    bool current = true;  // the last solve was with cuts_
    for (size_t k = 0; k < cuts_.size();) {
      const std::vector<double> keep = x;
      const size_t c = cuts_[k].index - first;
      const size_t end = k + 1 < cuts_.size() ? cuts_[k + 1].index - first : n;
      const Step& st = steps_[cuts_[k].index];
      const Eigen::Vector3d u = controlVector(st.d_left, st.d_right, odometry_.wheel_base_mm);
      const Pose2 target = compose(Pose2(x[3 * c - 3], x[3 * c - 2], x[3 * c - 1]), Pose2(u.x(), u.y(), u.z()));
      const Pose2 start(x[3 * c], x[3 * c + 1], x[3 * c + 2]);
      for (size_t j = c; j < end; ++j) {
        const Pose2 moved = compose(target, between(start, Pose2(x[3 * j], x[3 * j + 1], x[3 * j + 2])));
        x[3 * j] = moved.x;
        x[3 * j + 1] = moved.y;
        x[3 * j + 2] = moved.theta;
      }
      std::vector<Cut> trial = cuts_;
      trial.erase(trial.begin() + static_cast<long>(k));
      double restored = solveWith(cutIndices(trial));
      // The rigid move can start the uncut problem far from its optimum when the filter lost
      // track on mismodelled (real) data rather than on a kidnap: also start it from the cut
      // solution and keep the better optimum, so a cut is kept only on the evidence.
      const std::vector<double> from_moved = x;
      x = keep;
      const double restored_from_cut = solveWith(cutIndices(trial));
      const bool moved_better = restored < restored_from_cut;
      if (moved_better) {
        x = from_moved;
      } else {
        restored = restored_from_cut;
      }
      if (2.0 * (restored - cost) / variance_factor <= threshold) {
        cuts_ = trial;
        cost = restored;
        ++withdrawn;
        current = !moved_better;  // the summary is of the last solve: redo it if that was not the kept one
      } else {
        x = keep;
        current = false;
        ++k;
      }
    }
    if (!current) solveWith(cutIndices(cuts_));
  }
  s.withdrawn_cuts = withdrawn;
  for (const Cut& c : cuts_) {
    s.cut_steps.push_back(steps_[c.index].step);
    s.reinit_steps.push_back(steps_[c.reinit].step);
  }

  for (size_t i = 0; i < n; ++i) {
    Estimate& e = result_[first + i];
    e.pose = Pose2(x[3 * i], x[3 * i + 1], x[3 * i + 2]);
    e.covariance.setZero();
    e.status = EstimateStatus::Tracking;
  }
  if (config_.compute_covariance && config_.covariance_method == CovarianceMethod::Chain) {
    const auto t1 = Clock::now();
    std::vector<Eigen::Matrix3d> D, B;
    const bool ok = chainInformation(&D, &B);
    std::vector<Eigen::Matrix3d> cov;
    if (ok && chainMarginalCovariances(D, B, &cov)) {
      s.covariance_status = CovarianceStatus::Ok;
      for (size_t i = 0; i < n; ++i) result_[first + i].covariance = cov[i];
    } else {
      s.covariance_status = CovarianceStatus::RankDeficient;
      s.message += "; covariance: the information matrix is rank deficient, marginal covariances are not available";
    }
    s.covariance_seconds = std::chrono::duration<double>(Clock::now() - t1).count();
  } else if (config_.compute_covariance) {
    const auto t1 = Clock::now();
    ceres::Covariance::Options copts;
    copts.algorithm_type = ceres::SPARSE_QR;
    copts.sparse_linear_algebra_library_type = ceres::SUITE_SPARSE;
    copts.num_threads = config_.num_threads;
    copts.apply_loss_function = true;
    ceres::Covariance covariance(copts);
    std::vector<std::pair<const double*, const double*>> blocks;
    blocks.reserve(n);
    for (size_t i = 0; i < n; ++i) blocks.emplace_back(&x[3 * i], &x[3 * i]);
    if (covariance.Compute(blocks, problem_ptr.get())) {
      s.covariance_status = CovarianceStatus::Ok;
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
      s.message += "; covariance: the Jacobian is rank deficient, marginal covariances are not available";
    }
    s.covariance_seconds = std::chrono::duration<double>(Clock::now() - t1).count();
  }
  summary_ = s;
}

}  // namespace stereoloc
