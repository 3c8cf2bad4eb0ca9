// Sliding-window smoother: observations that arrive after the odometry of later steps
// (insertLate) give the in-order solution while their poses are in the window.
#include <gtest/gtest.h>

#include <Eigen/LU>
#include <algorithm>
#include <cmath>
#include <map>
#include <random>

#include "solvers/initialisation.h"
#include "solvers/sliding_window_smoother.h"
#include "solvers/smoother_common.h"
#include "src/core/error.h"
#include "test_util.h"

namespace stereoloc {
namespace {

using test::positionRmse;

const Eigen::Matrix3d kLateStartCovariance = Eigen::Vector3d(10.0, 10.0, 0.02).cwiseAbs2().asDiagonal();

// Observations on every 4th step only (the camera slower than the encoders).
SyntheticProblem cameraEveryFourthStep(int steps, uint64_t seed) {
  SyntheticProblemOptions o;
  o.steps = steps;
  o.max_observations = 2;
  SyntheticProblem p = makeRandomWalkProblem(o, seed);
  for (size_t k = 0; k < p.steps.size(); ++k)
    if (k % 4 != 0 || k == 0) p.steps[k].observations.clear();
  return p;
}

SlidingWindowConfig exactConfig(const SyntheticProblem& p, int window) {
  SlidingWindowConfig c;
  c.window = window;
  c.init = knownBelief(p.truth[0], kLateStartCovariance);
  // Solved to convergence at every step, so that the solution does not depend on the path.
  c.max_iterations = 100;
  c.function_tolerance = 1e-16;
  c.gradient_tolerance = 1e-16;
  c.parameter_tolerance = 1e-14;
  // Gated observations are judged once, as in the EKF: the re-test depends on when the window
  // holds which data, which is the difference these tests measure.
  c.retest_gated = false;
  return c;
}

// One delivery of late observations: those of `step`, handed over after the odometry of `arrival`.
struct Delivery {
  long step = 0;
  long arrival = 0;
  std::vector<Observation> observations;
};

// Each observation of each step is delivered alone, 1 to 5 steps late (two observations of a
// step usually on different steps, in either order); the deliveries of one arrival step are
// shuffled, so steps arrive out of order too.
// With `per_step`, the observations of a step travel together.
std::map<long, std::vector<Delivery>> delayEveryObservation(const SyntheticProblem& p, uint64_t seed,
                                                            bool per_step = false) {
  std::mt19937_64 rng(seed);
  std::uniform_int_distribution<int> delay(1, 5);
  std::map<long, std::vector<Delivery>> by_arrival;
  for (const Step& s : p.steps) {
    if (per_step && !s.observations.empty()) {
      Delivery d;
      d.step = s.step;
      d.arrival = s.step + delay(rng);
      d.observations = s.observations;
      by_arrival[d.arrival].push_back(d);
      continue;
    }
    for (const Observation& o : s.observations) {
      Delivery d;
      d.step = s.step;
      d.arrival = s.step + delay(rng);
      d.observations = {o};
      by_arrival[d.arrival].push_back(d);
    }
  }
  for (auto& kv : by_arrival) std::shuffle(kv.second.begin(), kv.second.end(), rng);
  return by_arrival;
}

struct DelayedRun {
  std::vector<Estimate> complete;  // current() at the steps with no observation outstanding
  std::vector<Estimate> finished;
  long inserted = 0;
};

DelayedRun runDelayed(const SyntheticProblem& p, const SlidingWindowConfig& c, uint64_t seed, bool per_step = false) {
  const auto deliveries = delayEveryObservation(p, seed, per_step);
  SlidingWindowSmoother win(p.map, p.odometry, c);
  DelayedRun run;
  long last = 0;
  auto deliver = [&](long arrival) {
    const auto it = deliveries.find(arrival);
    if (it == deliveries.end()) return;
    for (const Delivery& d : it->second) {
      const LateObservationResult r = win.insertLate(d.step, d.observations);
      EXPECT_EQ(toString(r.status), "inserted") << "step " << d.step;
      run.inserted += r.accepted;
    }
  };
  for (const Step& s : p.steps) {
    Step odometry_only = s;
    odometry_only.observations.clear();
    win.process(odometry_only);
    deliver(s.step);
    last = s.step;
    bool outstanding = false;
    for (const auto& kv : deliveries)
      for (const Delivery& d : kv.second) outstanding = outstanding || (d.step <= s.step && d.arrival > s.step);
    if (!outstanding) run.complete.push_back(win.current());
  }
  for (long a = last + 1; a <= last + 5; ++a) deliver(a);  // the tail, after the last odometry
  run.finished = win.finish();
  return run;
}

double maxPoseDifference(const Estimate& a, const Estimate& b) { return minus(a.pose, b.pose).cwiseAbs().maxCoeff(); }
double relCovDifference(const Estimate& a, const Estimate& b) {
  return (a.covariance - b.covariance).cwiseAbs().maxCoeff() / a.covariance.cwiseAbs().maxCoeff();
}

TEST(SlidingWindowLate, DelayedObservationsGiveTheInOrderEstimates) {
  const SyntheticProblem p = cameraEveryFourthStep(160, 31);
  // Nothing leaves the window (41 keyframes), so the two runs solve the same graph. Covariances
  // are evaluated at the current estimates: first estimates depend on the arrival order.
  SlidingWindowConfig c = exactConfig(p, 60);
  c.linearisation = WindowLinearisation::Current;
  SlidingWindowSmoother in_order(p.map, p.odometry, c);
  std::map<long, Estimate> reference;
  for (const Step& s : p.steps) reference[s.step] = in_order.process(s);
  const std::vector<Estimate> smoothed = in_order.finish();
  EXPECT_EQ(in_order.stats().marginalisations, 0);

  const DelayedRun run = runDelayed(p, c, 7);
  EXPECT_EQ(run.inserted, in_order.stats().accepted_observations);
  ASSERT_GT(run.complete.size(), 15u);
  double pose = 0, cov = 0;
  for (const Estimate& e : run.complete) {
    ASSERT_EQ(e.step, reference.at(e.step).step);
    EXPECT_EQ(toString(e.status), toString(reference.at(e.step).status)) << "step " << e.step;
    pose = std::max(pose, maxPoseDifference(e, reference.at(e.step)));
    cov = std::max(cov, relCovDifference(e, reference.at(e.step)));
  }
  EXPECT_LT(pose, 1e-6);
  EXPECT_LT(cov, 1e-6);
  ASSERT_EQ(run.finished.size(), smoothed.size());
  double fpose = 0, fcov = 0;
  for (size_t i = 0; i < smoothed.size(); ++i) {
    ASSERT_EQ(run.finished[i].step, smoothed[i].step);
    fpose = std::max(fpose, maxPoseDifference(run.finished[i], smoothed[i]));
    fcov = std::max(fcov, relCovDifference(run.finished[i], smoothed[i]));
  }
  EXPECT_LT(fpose, 1e-6);
  EXPECT_LT(fcov, 1e-6);
}

TEST(SlidingWindowLate, LateObservationsGiveTheFirstGlobalFix) {
  // A global start: the first fix comes from the late sightings of step 4, and the odometry
  // kept since then brings the window to the newest step as if they had come in time.
  const SyntheticProblem p = cameraEveryFourthStep(120, 35);
  SlidingWindowConfig c = exactConfig(p, 60);
  c.linearisation = WindowLinearisation::Current;
  c.init = InitialBelief();
  SlidingWindowSmoother in_order(p.map, p.odometry, c);
  std::map<long, Estimate> reference;
  for (const Step& s : p.steps) reference[s.step] = in_order.process(s);
  const std::vector<Estimate> smoothed = in_order.finish();
  ASSERT_EQ(in_order.stats().reinitialisations, 1);
  const DelayedRun run = runDelayed(p, c, 10, true);
  double pose = 0;
  int initialised = 0;
  for (const Estimate& e : run.complete) {
    EXPECT_EQ(toString(e.status), toString(reference.at(e.step).status)) << "step " << e.step;
    if (e.status == EstimateStatus::Uninitialised) continue;
    ++initialised;
    pose = std::max(pose, maxPoseDifference(e, reference.at(e.step)));
  }
  EXPECT_GT(initialised, 10);
  EXPECT_LT(pose, 1e-6);
  ASSERT_EQ(run.finished.size(), smoothed.size());
  for (size_t i = 0; i < smoothed.size(); ++i) {
    ASSERT_EQ(run.finished[i].step, smoothed[i].step);
    EXPECT_EQ(toString(run.finished[i].status), toString(smoothed[i].status)) << "step " << smoothed[i].step;
    if (smoothed[i].status != EstimateStatus::Uninitialised) {
      EXPECT_LT(maxPoseDifference(run.finished[i], smoothed[i]), 1e-6);
    }
  }
}

TEST(SlidingWindowLate, FirstEstimateJacobiansKeepTheInOrderPoses) {
  // With first estimates the covariances depend on when each factor was created; the poses,
  // the solution of the same least-squares problem, do not.
  const SyntheticProblem p = cameraEveryFourthStep(160, 32);
  SlidingWindowConfig c = exactConfig(p, 60);
  c.linearisation = WindowLinearisation::FirstEstimates;
  SlidingWindowSmoother in_order(p.map, p.odometry, c);
  for (const Step& s : p.steps) in_order.process(s);
  const std::vector<Estimate> smoothed = in_order.finish();
  const DelayedRun run = runDelayed(p, c, 8);
  ASSERT_EQ(run.finished.size(), smoothed.size());
  double pose = 0, cov = 0;
  for (size_t i = 0; i < smoothed.size(); ++i) {
    pose = std::max(pose, maxPoseDifference(run.finished[i], smoothed[i]));
    cov = std::max(cov, relCovDifference(run.finished[i], smoothed[i]));
  }
  EXPECT_LT(pose, 1e-6);
  EXPECT_LT(cov, 0.05);
  RecordProperty("max_relative_covariance_difference", std::to_string(cov));
}

TEST(SlidingWindowLate, MarginalisedWindowStaysCloseToInOrder) {
  // W = 8 keyframes: poses leave the window while observations of later steps are outstanding,
  // so their marginal priors are linearised at estimates without those observations, and a pose
  // keeps the estimate it had when it left. Measured on this run: real-time estimates with no
  // observation outstanding within 0.05 mm of the in-order run (position RMSE 3.1 mm).
  const SyntheticProblem p = cameraEveryFourthStep(400, 33);
  const SlidingWindowConfig c = exactConfig(p, 8);
  SlidingWindowSmoother in_order(p.map, p.odometry, c);
  std::map<long, Estimate> reference;
  for (const Step& s : p.steps) reference[s.step] = in_order.process(s);
  const std::vector<Estimate> smoothed = in_order.finish();
  EXPECT_GT(in_order.stats().marginalisations, 50);
  const DelayedRun run = runDelayed(p, c, 9);
  const double rmse = positionRmse(smoothed, p.truth);
  double pose = 0;
  for (const Estimate& e : run.complete)
    pose = std::max(pose, (e.pose.translation() - reference.at(e.step).pose.translation()).norm());
  EXPECT_GT(run.complete.size(), 50u);
  EXPECT_LT(pose, 0.03 * rmse);
  EXPECT_LT(positionRmse(run.finished, p.truth), 1.05 * rmse);
}

// The first camera step from step 40 on with two sightings (a two-landmark fix).
size_t twoLandmarkStep(const SyntheticProblem& p) {
  size_t k = 40;
  while (p.steps[k].observations.size() < 2) k += 4;
  return k;
}

// Steps 0..k-1 in time, step k's odometry, then one of its sightings late with its range 1.5
// times too long: with lost_after 1 the gate rejects it and the window is lost at step k.
// Returns how many the insertion rejected.
int loseTheWindowAt(SlidingWindowSmoother& win, const SyntheticProblem& p, size_t k) {
  for (size_t i = 0; i < k; ++i) win.process(p.steps[i]);
  Step blind = p.steps[k];
  blind.observations.clear();
  win.process(blind);
  std::vector<Observation> outlier = {p.steps[k].observations[0]};
  outlier[0].range *= 1.5;
  return win.insertLate(blind.step, outlier).rejected;
}

TEST(SlidingWindowLate, LateObservationsRestartALostWindow) {
  const SyntheticProblem p = cameraEveryFourthStep(60, 36);
  const size_t k = twoLandmarkStep(p);
  SlidingWindowConfig c = exactConfig(p, 10);
  c.gate.lost_after = 1;
  SlidingWindowSmoother win(p.map, p.odometry, c);
  EXPECT_EQ(loseTheWindowAt(win, p, k), 1);
  ASSERT_TRUE(win.lost());
  for (size_t i = k + 1; i < k + 3; ++i) {
    Step s = p.steps[i];
    s.observations.clear();
    EXPECT_EQ(toString(win.process(s).status), "lost");  // no in-time observation to restart from
  }
  const long before = win.stats().reinitialisations;
  const LateObservationResult r = win.insertLate(p.steps[k].step, p.steps[k].observations);
  EXPECT_EQ(toString(r.status), "inserted");
  EXPECT_FALSE(win.lost());
  EXPECT_EQ(win.stats().reinitialisations, before + 1);
  EXPECT_EQ(r.estimate.step, p.steps[k + 2].step);
  // The fix's pose carried by two steps of odometry: consistent with its covariance.
  const Eigen::Vector3d e = minus(p.truth[k + 2], r.estimate.pose);
  EXPECT_LT(e.dot(r.estimate.covariance.inverse() * e), 16.3);  // chi-square 3 dof, 0.999
  std::vector<Estimate> all = win.finish();
  ASSERT_EQ(all.size(), k + 3);
  for (size_t i = 0; i < all.size(); ++i) EXPECT_EQ(all[i].step, p.steps[i].step);
}

TEST(SlidingWindowLate, ALateRestartThatFailsKeepsTheProcessedSteps) {
  // The lost window of the test above, and the global fix its late sightings ask for fails: the
  // insertion throws, the window is given up with every processed step kept, and the next step
  // with a fix starts the next one.
  const SyntheticProblem p = cameraEveryFourthStep(60, 36);
  const size_t k = twoLandmarkStep(p);
  SlidingWindowConfig c = exactConfig(p, 10);
  c.gate.lost_after = 1;
  const GlobalFixFunction fix = defaultGlobalFix();
  bool failed_once = false;
  c.global_fix = [&](const Step& s, const FieldMap& map) -> std::optional<PoseFix> {
    if (s.step == p.steps[k].step && !s.observations.empty() && !failed_once) {
      failed_once = true;
      throw Error("map server: no answer");
    }
    return fix(s, map);
  };
  SlidingWindowSmoother win(p.map, p.odometry, c);
  EXPECT_EQ(loseTheWindowAt(win, p, k), 1);
  ASSERT_TRUE(win.lost());
  Step s = p.steps[k + 1];
  s.observations.clear();
  win.process(s);
  EXPECT_THROW(win.insertLate(p.steps[k].step, p.steps[k].observations), Error);
  EXPECT_TRUE(failed_once);
  EXPECT_FALSE(win.initialised());
  bool restarted = false;
  for (size_t i = k + 2; i < p.steps.size(); ++i) restarted |= win.process(p.steps[i]).status == EstimateStatus::Reinitialised;
  EXPECT_TRUE(restarted);
  const std::vector<Estimate> all = win.finish();
  ASSERT_EQ(all.size(), p.steps.size());
  for (size_t i = 0; i < all.size(); ++i) {
    EXPECT_EQ(all[i].step, p.steps[i].step);
    if (all[i].status == EstimateStatus::Uninitialised) continue;
    EXPECT_TRUE(all[i].pose.isFinite()) << "step " << all[i].step;
    EXPECT_GT(all[i].covariance.determinant(), 0.0) << "step " << all[i].step;
  }
}

TEST(SlidingWindowLate, TooLateNotTrackingAndErrors) {
  const SyntheticProblem p = cameraEveryFourthStep(80, 34);
  SlidingWindowConfig c = exactConfig(p, 4);
  SlidingWindowSmoother win(p.map, p.odometry, c);
  for (const Step& s : p.steps) win.process(s);
  const Estimate before = win.current();
  EXPECT_EQ(before.step, p.steps.back().step);
  const LateObservationResult r = win.insertLate(8, p.steps[8].observations);
  EXPECT_EQ(toString(r.status), "too_late");
  EXPECT_EQ(win.stats().late_too_late, 1);
  EXPECT_EQ(r.estimate.pose.x, before.pose.x);
  EXPECT_EQ(win.current().pose.x, before.pose.x);
  EXPECT_THROW(win.insertLate(p.steps.back().step + 1, p.steps[8].observations), Error);  // not processed yet
  std::vector<Observation> unknown = p.steps[76].observations;
  ASSERT_FALSE(unknown.empty());
  unknown[0].landmark_id = 999;
  EXPECT_THROW(win.insertLate(p.steps.back().step, unknown), Error);
  std::vector<Observation> bad = p.steps[76].observations;
  bad[0].range = std::nan("");
  EXPECT_THROW(win.insertLate(p.steps.back().step, bad), Error);

  SlidingWindowConfig g = c;
  g.init = InitialBelief();  // wait for a global fix, which blind steps never give
  g.restart_buffer_steps = 0;  // and no recent step a late sighting could start from
  SlidingWindowSmoother waiting(p.map, p.odometry, g);
  for (int k = 0; k < 3; ++k) {
    Step s = p.steps[static_cast<size_t>(k)];
    s.observations.clear();
    waiting.process(s);
  }
  EXPECT_EQ(toString(waiting.insertLate(1, p.steps[8].observations).status), "not_tracking");
}

}  // namespace
}  // namespace stereoloc
