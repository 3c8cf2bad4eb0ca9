// Sliding-window smoother: W = 1 with one Gauss-Newton iteration is the EKF; a window over the
// whole trajectory is the batch smoother; blind steps, long runs, lost tracking.
#include <gtest/gtest.h>

#include <Eigen/Cholesky>
#include <cmath>

#include "kidnapped_walk.h"
#include "solvers/batch_smoother.h"
#include "solvers/ekf.h"
#include "solvers/sliding_window_smoother.h"
#include "solvers/smoother_common.h"
#include "src/core/error.h"
#include "test_util.h"

namespace stereoloc {
namespace {

const Eigen::Matrix3d kWindowStartCovariance = Eigen::Vector3d(10.0, 10.0, 0.02).cwiseAbs2().asDiagonal();

using test::positionRmse;

TEST(SlidingWindow, WindowOneWithOneGaussNewtonStepIsTheEkf) {
  // At most one update per step (the EKF relinearises between sequential updates; a joint
  // Gauss-Newton step equals it only for a single update): one observation, or the compass.
  SyntheticProblemOptions o;
  o.steps = 200;
  o.max_observations = 1;
  o.compass_sigma = 0.05;
  SyntheticProblem p = makeRandomWalkProblem(o, 21);
  for (size_t k = 0; k < p.steps.size(); ++k) {
    if (k % 3 != 0) p.steps[k].compass.reset();
    if (k % 3 == 0 || k % 7 == 0) p.steps[k].observations.clear();  // compass-only and blind steps
  }
  // Keyframes (the default: blind steps are composed into the next keyframe's odometry
  // factor) and every step a keyframe (keyframe_max_steps = 1): both are the EKF.
  for (int keyframe_max_steps : {SlidingWindowConfig().keyframe_max_steps, 1}) {
    EkfConfig ec;
    ec.init = knownBelief(p.truth[0], kWindowStartCovariance);
    Ekf ekf(p.map, p.odometry, ec);
    SlidingWindowConfig wc;
    wc.window = 1;
    wc.max_iterations = 1;
    wc.gauss_newton = true;
    wc.linearisation = WindowLinearisation::FirstEstimates;  // the EKF's linearisation points
    wc.retest_gated = false;                                  // the EKF judges an observation once
    wc.init = ec.init;
    wc.keyframe_max_steps = keyframe_max_steps;
    SlidingWindowSmoother win(p.map, p.odometry, wc);
    int fused = 0;
    double max_pose = 0, max_cov = 0;
    for (const Step& s : p.steps) {
      const Estimate a = ekf.process(s), b = win.process(s);
      ASSERT_EQ(toString(a.status), toString(b.status)) << "step " << s.step;
      fused += a.status == EstimateStatus::Tracking;
      max_pose = std::max(max_pose, minus(a.pose, b.pose).cwiseAbs().maxCoeff());
      max_cov =
          std::max(max_cov, (a.covariance - b.covariance).cwiseAbs().maxCoeff() / a.covariance.cwiseAbs().maxCoeff());
    }
    EXPECT_GT(fused, 100);
    EXPECT_LT(max_pose, 1e-6) << "keyframe_max_steps " << keyframe_max_steps;
    EXPECT_LT(max_cov, 1e-6) << "keyframe_max_steps " << keyframe_max_steps;
    EXPECT_EQ(win.windowSize(), 1);
    if (keyframe_max_steps > 1) {
      EXPECT_LT(win.stats().keyframes, win.stats().steps);
    }
  }
}

TEST(SlidingWindow, GaussNewtonCheckCanFail) {
  // The same comparison with a step that carries two observations differs from the EKF (it
  // relinearises between them): guards the test above against comparing nothing.
  SyntheticProblemOptions o;
  o.steps = 60;
  o.max_observations = 2;
  o.sigma_bearing = 0.1;
  const SyntheticProblem p = makeRandomWalkProblem(o, 4);
  EkfConfig ec;
  ec.init = knownBelief(p.truth[0], Eigen::Vector3d(80.0, 80.0, 0.2).cwiseAbs2().asDiagonal());
  ec.gate_enabled = false;
  Ekf ekf(p.map, p.odometry, ec);
  SlidingWindowConfig wc;
  wc.window = 1;
  wc.max_iterations = 1;
  wc.gauss_newton = true;
  wc.linearisation = WindowLinearisation::FirstEstimates;
  wc.gate_enabled = false;
  wc.init = ec.init;
  SlidingWindowSmoother win(p.map, p.odometry, wc);
  double max_pose = 0;
  for (const Step& s : p.steps) max_pose = std::max(max_pose, minus(ekf.process(s).pose, win.process(s).pose).norm());
  EXPECT_GT(max_pose, 1e-3);
}

TEST(SlidingWindow, WholeTrajectoryWindowEqualsBatch) {
  SyntheticProblemOptions o;
  o.steps = 60;
  o.compass_sigma = 0.05;
  const SyntheticProblem p = makeRandomWalkProblem(o, 9);
  BatchSmootherConfig bc;
  bc.init = knownBelief(p.truth[0], kWindowStartCovariance);
  // Both solved to the limit of double precision, so that only the formulation could differ.
  bc.function_tolerance = 1e-16;
  bc.parameter_tolerance = 1e-16;
  bc.gradient_tolerance = 1e-16;
  BatchSmoother batch(p.map, p.odometry, bc);
  for (const Step& s : p.steps) batch.process(s);
  const std::vector<Estimate> eb = batch.finish();
  for (WindowLinearisation lin :
       {WindowLinearisation::PriorPoint, WindowLinearisation::FirstEstimates, WindowLinearisation::Current}) {
    SlidingWindowConfig wc;
    wc.window = o.steps;
    wc.init = bc.init;
    wc.gate_enabled = false;
    wc.linearisation = lin;
    wc.max_iterations = 5;
    wc.final_iterations = 100;
    wc.function_tolerance = wc.parameter_tolerance = wc.gradient_tolerance = 1e-16;
    // Every step a pose, as in the batch (keyframes replace blind poses by composed odometry,
    // equal to the batch only to first order: KeyframesSpanSparseObservations).
    wc.keyframe_max_steps = 1;
    SlidingWindowSmoother win(p.map, p.odometry, wc);
    for (const Step& s : p.steps) win.process(s);
    const std::vector<Estimate> ew = win.finish();
    ASSERT_EQ(ew.size(), eb.size());
    double max_pose = 0, max_cov = 0;
    for (size_t i = 0; i < ew.size(); ++i) {
      EXPECT_EQ(ew[i].step, eb[i].step);
      max_pose = std::max(max_pose, minus(ew[i].pose, eb[i].pose).cwiseAbs().maxCoeff());
      max_cov = std::max(max_cov, (ew[i].covariance - eb[i].covariance).cwiseAbs().maxCoeff() /
                                      eb[i].covariance.cwiseAbs().maxCoeff());
    }
    EXPECT_LT(max_pose, 1e-6) << toString(lin);
    // Linearised at the estimate the covariance is the batch's (nothing is marginalised, so
    // prior_point is the estimate too); with first estimates it is the information at the
    // creation points, close but not equal.
    if (lin != WindowLinearisation::FirstEstimates) {
      EXPECT_LT(max_cov, 1e-6);
    } else {
      EXPECT_LT(max_cov, 0.2);
    }
  }
}

TEST(SlidingWindow, SmoothsBetterThanFilteringAndMarginalisesConsistently) {
  double rt = 0, sm = 0, nees = 0;
  int count = 0;
  for (uint64_t seed = 1; seed <= 2; ++seed) {
    SyntheticProblemOptions o;
    o.steps = 300;
    const SyntheticProblem p = makeRandomWalkProblem(o, seed);
    SlidingWindowConfig wc;
    wc.init = knownBelief(p.truth[0], kWindowStartCovariance);
    SlidingWindowSmoother win(p.map, p.odometry, wc);
    std::vector<Estimate> realtime;
    for (const Step& s : p.steps) {
      realtime.push_back(win.process(s));
      EXPECT_LE(win.windowSize(), 20);
      const Eigen::Vector3d e = minus(realtime.back().pose, p.truth[static_cast<size_t>(s.step)]);
      nees += e.dot(realtime.back().covariance.ldlt().solve(e));
      ++count;
    }
    EXPECT_EQ(win.stats().marginalisations, win.stats().keyframes - 20);
    const std::vector<Estimate> smoothed = win.finish();
    ASSERT_EQ(smoothed.size(), p.steps.size());
    rt += positionRmse(realtime, p.truth);
    sm += positionRmse(smoothed, p.truth);
  }
  EXPECT_LT(sm, rt);
  nees /= count;
  EXPECT_GT(nees, 1.0);
  EXPECT_LT(nees, 6.0);
}

// Observations on one step in six: W = 10 keyframes span 60 steps. The full-length keyframe
// window is the batch to first order (the blind poses are marginalised at their predicted
// values), including the bridged estimates of the blind steps; a short keyframe window beats
// a short per-step window, and its covariances stay honest.
TEST(SlidingWindow, KeyframesSpanSparseObservations) {
  SyntheticProblemOptions o;
  o.steps = 240;
  const SyntheticProblem full = makeRandomWalkProblem(o, 41);
  SyntheticProblem p = full;
  for (size_t k = 0; k < p.steps.size(); ++k)
    if (k % 6 != 0) p.steps[k].observations.clear();
  BatchSmootherConfig bc;
  bc.init = knownBelief(p.truth[0], kWindowStartCovariance);
  BatchSmoother batch(p.map, p.odometry, bc);
  for (const Step& s : p.steps) batch.process(s);
  const std::vector<Estimate> eb = batch.finish();
  SlidingWindowConfig wc;
  wc.init = bc.init;
  wc.gate_enabled = false;
  wc.window = o.steps;
  wc.final_iterations = 100;
  SlidingWindowSmoother all(p.map, p.odometry, wc);
  for (const Step& s : p.steps) all.process(s);
  const std::vector<Estimate> ea = all.finish();
  ASSERT_EQ(ea.size(), eb.size());
  EXPECT_LE(all.stats().keyframes, o.steps / 6 + 2);
  double gap = 0, cov_gap = 0;
  for (size_t i = 0; i < ea.size(); ++i) {
    ASSERT_EQ(ea[i].step, eb[i].step);
    const Eigen::Vector3d d = minus(ea[i].pose, eb[i].pose);
    gap = std::max(gap, std::sqrt(d.dot(eb[i].covariance.ldlt().solve(d))));  // in batch sigmas
    cov_gap = std::max(cov_gap, (ea[i].covariance - eb[i].covariance).cwiseAbs().maxCoeff() /
                                    eb[i].covariance.cwiseAbs().maxCoeff());
  }
  EXPECT_LT(gap, 0.05);
  EXPECT_LT(cov_gap, 0.2);

  double rmse_key = 0, rmse_step = 0, nees = 0;
  int count = 0;
  for (int kf : {wc.keyframe_max_steps, 1}) {
    SlidingWindowConfig sc;
    sc.init = bc.init;
    sc.window = 10;
    sc.keyframe_max_steps = kf;
    SlidingWindowSmoother win(p.map, p.odometry, sc);
    for (const Step& s : p.steps) {
      const Estimate e = win.process(s);
      EXPECT_LE(win.windowSize(), 10);
      if (kf > 1) {
        const Eigen::Vector3d d = minus(e.pose, p.truth[static_cast<size_t>(s.step)]);
        nees += d.dot(e.covariance.ldlt().solve(d));
        ++count;
      }
    }
    const std::vector<Estimate> lag = win.finish();
    ASSERT_EQ(lag.size(), p.steps.size());
    (kf > 1 ? rmse_key : rmse_step) = positionRmse(lag, p.truth);
  }
  EXPECT_LT(rmse_key, rmse_step);
  nees /= count;
  EXPECT_GT(nees, 1.0);
  EXPECT_LT(nees, 6.0);
}

// Range outliers (1.5 x the range on 10 % of the observations) with the gate off: Huber and
// Cauchy in the window reduce the error against the plain least-squares window.
TEST(SlidingWindow, RobustLossResistsOutliers) {
  SyntheticProblemOptions o;
  o.steps = 300;
  o.outlier_fraction = 0.1;
  const SyntheticProblem p = makeRandomWalkProblem(o, 23);
  auto run = [&](RobustLoss type, double scale) {
    SlidingWindowConfig wc;
    wc.init = knownBelief(p.truth[0], kWindowStartCovariance);
    wc.gate_enabled = false;
    wc.robust_loss.type = type;
    wc.robust_loss.scale = scale;
    SlidingWindowSmoother win(p.map, p.odometry, wc);
    for (const Step& s : p.steps) win.process(s);
    return positionRmse(win.finish(), p.truth);
  };
  const double plain = run(RobustLoss::None, 1.0);
  const double huber = run(RobustLoss::Huber, 1.345);
  const double cauchy = run(RobustLoss::Cauchy, 2.3849);
  EXPECT_LT(huber, 0.8 * plain) << plain;
  EXPECT_LT(cauchy, 0.8 * plain) << plain;
  // With a robust loss the gate is off unless asked for (gate_with_robust_loss).
  for (bool keep_gate : {false, true}) {
    SlidingWindowConfig wc;
    wc.init = knownBelief(p.truth[0], kWindowStartCovariance);
    wc.robust_loss.type = RobustLoss::Huber;
    wc.gate_with_robust_loss = keep_gate;
    SlidingWindowSmoother win(p.map, p.odometry, wc);
    for (const Step& s : p.steps) win.process(s);
    if (keep_gate) {
      EXPECT_GT(win.stats().rejected_observations, 0);
    } else {
      EXPECT_EQ(win.stats().rejected_observations, 0);
    }
  }
  SlidingWindowConfig bad;
  bad.keyframe_max_steps = 0;
  EXPECT_THROW(SlidingWindowSmoother(p.map, p.odometry, bad), Error);
}

TEST(SlidingWindow, BlindStepsGrowTheCovarianceAndRecover) {
  SyntheticProblemOptions o;
  o.steps = 150;
  SyntheticProblem p = makeRandomWalkProblem(o, 13);
  for (int k = 50; k < 100; ++k) p.steps[static_cast<size_t>(k)].observations.clear();
  SlidingWindowConfig wc;
  wc.init = knownBelief(p.truth[0], kWindowStartCovariance);
  SlidingWindowSmoother win(p.map, p.odometry, wc);
  double last_trace = 0;
  for (const Step& s : p.steps) {
    const Estimate e = win.process(s);
    if (s.step >= 50 && s.step < 100) {
      EXPECT_EQ(e.status, EstimateStatus::Predicted);
      const double tr = e.covariance.topLeftCorner<2, 2>().trace();
      EXPECT_GT(tr, last_trace) << s.step;
    }
    last_trace = e.covariance.topLeftCorner<2, 2>().trace();
    if (s.step == 149) {
      EXPECT_LT((e.pose.translation() - p.truth[149].translation()).norm(), 50.0);
    }
  }
}

TEST(SlidingWindow, LongRunInBoundedWindow) {
  SyntheticProblemOptions o;
  o.steps = 3000;
  const SyntheticProblem p = makeRandomWalkProblem(o, 17);
  SlidingWindowConfig wc;
  wc.window = 10;
  wc.keep_history = false;
  wc.init = knownBelief(p.truth[0], kWindowStartCovariance);
  SlidingWindowSmoother win(p.map, p.odometry, wc);
  double worst = 0;
  for (const Step& s : p.steps) {
    const Estimate e = win.process(s);
    ASSERT_LE(win.windowSize(), 10);
    worst = std::max(worst, (e.pose.translation() - p.truth[static_cast<size_t>(s.step)].translation()).norm());
  }
  EXPECT_LT(worst, 100.0);
  EXPECT_EQ(win.finish().size(), 10u);  // only the final window without history
}

TEST(SlidingWindow, LostTrackingReinitialisesFromGlobalFix) {
  const SyntheticProblem p = test::kidnappedWalk();
  int fixes_asked = 0;
  SlidingWindowConfig wc;
  wc.init = knownBelief(p.truth[0], kWindowStartCovariance);
  wc.global_fix = [&](const Step& s, const FieldMap&) -> std::optional<PoseFix> {
    ++fixes_asked;
    if (s.observations.size() < 2) return std::nullopt;
    return PoseFix{p.truth[static_cast<size_t>(s.step)], Eigen::Vector3d(30.0, 30.0, 0.05).cwiseAbs2().asDiagonal()};
  };
  SlidingWindowSmoother win(p.map, p.odometry, wc);
  bool lost = false, reinit = false;
  for (const Step& s : p.steps) {
    const Estimate e = win.process(s);
    lost |= e.status == EstimateStatus::Lost;
    if (e.status == EstimateStatus::Reinitialised) {
      reinit = true;
      EXPECT_GE(s.step, 100);
    }
  }
  EXPECT_TRUE(reinit);
  EXPECT_GT(fixes_asked, 0);
  EXPECT_EQ(win.stats().reinitialisations, 1 + 0 * lost);
  const std::vector<Estimate> est = win.finish();
  ASSERT_EQ(est.size(), p.steps.size());
  for (size_t i = 0; i < est.size(); ++i) EXPECT_EQ(est[i].step, p.steps[i].step);
  EXPECT_LT((est.back().pose.translation() - p.truth.back().translation()).norm(), 40.0);
}

TEST(SlidingWindow, AStepThatFailsHalfwayGivesTheWindowUpUntilTheNextFix) {
  // The kidnap of the test above, and the global fix (a plug-in: a map server, say) fails on the
  // first call after it: the step that asked fails, after its pose and factors were added. The
  // window is given up there, its poses kept; the steps after it wait for a fix and go on.
  const SyntheticProblem p = test::kidnappedWalk();
  bool failed_once = false;
  SlidingWindowConfig wc;
  wc.init = knownBelief(p.truth[0], kWindowStartCovariance);
  wc.global_fix = [&](const Step& s, const FieldMap&) -> std::optional<PoseFix> {
    if (s.observations.size() < 2) return std::nullopt;
    if (!failed_once) {
      failed_once = true;
      throw Error("map server: no answer");
    }
    return PoseFix{p.truth[static_cast<size_t>(s.step)], Eigen::Vector3d(30.0, 30.0, 0.05).cwiseAbs2().asDiagonal()};
  };
  SlidingWindowSmoother win(p.map, p.odometry, wc);
  long failed = -1;
  std::vector<Estimate> after;
  for (const Step& s : p.steps) {
    try {
      const Estimate e = win.process(s);
      if (failed >= 0) after.push_back(e);
    } catch (const Error& e) {
      EXPECT_EQ(failed, -1) << "a second failure at step " << s.step;
      EXPECT_NE(std::string(e.what()).find("map server: no answer"), std::string::npos);
      failed = s.step;
      EXPECT_FALSE(win.initialised());
    }
  }
  ASSERT_GE(failed, 100);
  ASSERT_FALSE(after.empty());
  // Uninitialised until the next step with a fix, which starts the next window.
  size_t k = 0;
  while (k < after.size() && after[k].status == EstimateStatus::Uninitialised) ++k;
  ASSERT_LT(k, after.size());
  EXPECT_EQ(after[k].status, EstimateStatus::Reinitialised);
  EXPECT_GE(win.stats().reinitialisations, 1);
  const std::vector<Estimate> est = win.finish();
  ASSERT_EQ(est.size(), p.steps.size() - 1);  // every step but the failed one
  for (size_t i = 0; i < est.size(); ++i) {
    const long expected = p.steps[i < static_cast<size_t>(failed) ? i : i + 1].step;
    ASSERT_EQ(est[i].step, expected);
    if (est[i].status == EstimateStatus::Uninitialised) continue;
    EXPECT_TRUE(est[i].pose.isFinite()) << "step " << est[i].step;
    EXPECT_EQ(Eigen::LLT<Eigen::Matrix3d>(est[i].covariance).info(), Eigen::Success) << "step " << est[i].step;
  }
  // Before the kidnap the given-up window's poses are its smoothed ones.
  for (size_t i = 0; i < 90; ++i) EXPECT_LT((est[i].pose.translation() - p.truth[i].translation()).norm(), 40.0);
  EXPECT_LT((est.back().pose.translation() - p.truth.back().translation()).norm(), 40.0);
}

TEST(SlidingWindow, GlobalStartAndErrors) {
  SyntheticProblemOptions o;
  o.steps = 30;
  const SyntheticProblem p = makeRandomWalkProblem(o, 2);
  SlidingWindowConfig wc;
  wc.global_fix = [&](const Step& s, const FieldMap&) -> std::optional<PoseFix> {
    if (s.step < 5) return std::nullopt;
    return PoseFix{p.truth[static_cast<size_t>(s.step)], kWindowStartCovariance};
  };
  SlidingWindowSmoother win(p.map, p.odometry, wc);
  for (const Step& s : p.steps) {
    const Estimate e = win.process(s);
    if (s.step < 5) {
      EXPECT_EQ(e.status, EstimateStatus::Uninitialised);
    }
    if (s.step == 5) {
      EXPECT_EQ(e.status, EstimateStatus::Reinitialised);
    }
  }
  EXPECT_THROW(win.process(p.steps[3]), Error);
  EXPECT_EQ(win.finish().size(), p.steps.size());
  EXPECT_THROW(win.process(p.steps[29]), Error);
  SlidingWindowConfig bad;
  bad.window = 0;
  EXPECT_THROW(SlidingWindowSmoother(p.map, p.odometry, bad), Error);
}

TEST(SlidingWindow, Deterministic) {
  SyntheticProblemOptions o;
  o.steps = 150;
  const SyntheticProblem p = makeRandomWalkProblem(o, 6);
  SlidingWindowConfig wc;
  wc.window = 8;
  wc.init = knownBelief(p.truth[0], kWindowStartCovariance);
  SlidingWindowSmoother a(p.map, p.odometry, wc), b(p.map, p.odometry, wc);
  for (const Step& s : p.steps) {
    const Estimate ea = a.process(s), eb = b.process(s);
    ASSERT_EQ(ea.pose.x, eb.pose.x);
    ASSERT_EQ(ea.covariance, eb.covariance);
  }
}

}  // namespace
}  // namespace stereoloc
