// Sliding-window smoother against its fixed-lag Cramér–Rao bound (solvers/crlb.h) on the
// simulated line: a start belief far in the tail of its (honest) prior makes the gate reject the
// first sightings and declare the robot lost; the window then re-anchors on the global fix and
// smooths its first poses instead of restarting and leaving them at the prior.
#include <gtest/gtest.h>

#include <cmath>

#include "solvers/crlb.h"
#include "solvers/sliding_window_smoother.h"
#include "src/eval/evaluation.h"
#include "src/sim/simulator.h"

namespace stereoloc {
namespace {

// The known start's P0 (section 6.5).
const Eigen::Matrix3d kP0 = Eigen::Vector3d(30.0, 30.0, deg2rad(5.0)).cwiseAbs2().asDiagonal();

struct BoundRun {
  double se = 0, bound = 0;  // summed squared position error and bound trace (mm^2)
  long count = 0;
  long reanchorings = 0, reinitialisations = 0;
  double ratio() const { return std::sqrt(se / bound); }
};

// Line runs whose start belief is off by `offset` mm in x and y: (70, 70) is NEES 10.9, inside
// the 99 % of chi-square(3), so the prior is honest, but far enough out for the gate to reject
// three sightings in a row in most runs.
BoundRun runLine(double offset, double reanchor_probability) {
  BoundRun out;
  for (uint64_t seed = 1; seed <= 4; ++seed) {
    const Dataset d = simulate("line", 0, SimulationConfig(), seed);
    const Pose2 truth0 = *d.groundtruth.front();
    SlidingWindowConfig c;
    c.window = 20;
    c.init = knownBelief(Pose2(truth0.x + offset, truth0.y + offset, truth0.theta), kP0);
    c.observation_model = {ObservationModel::PixelColumns, d.rig};
    c.reanchor_probability = reanchor_probability;
    SlidingWindowSmoother win(d.map, d.odometry, c);
    for (const Step& s : d.steps) win.process(s);
    const std::vector<Estimate> est = win.finish();
    out.reanchorings += win.stats().reanchorings;
    out.reinitialisations += win.stats().reinitialisations;
    CrlbOptions crlb;
    crlb.observation_model = c.observation_model;
    const TrajectoryInformation info = trajectoryInformation(d, kP0, crlb);
    const std::vector<Eigen::Matrix3d> bound = fixedLagBound(info, c.window - 1);
    const std::vector<PoseError> errors = poseErrors(est, truthByStep(d.steps, d.groundtruth));
    EXPECT_EQ(errors.size(), info.steps.size());
    for (size_t k = 0; k < errors.size() && k < info.steps.size(); ++k) {
      EXPECT_EQ(errors[k].step, info.steps[k]);
      out.se += errors[k].distance * errors[k].distance;
      out.bound += bound[k].topLeftCorner<2, 2>().trace();
      ++out.count;
    }
  }
  return out;
}

TEST(SlidingWindowBound, StartInTheGatesTailStaysAtTheFixedLagBoundOnLine) {
  const double reanchor = SlidingWindowConfig().reanchor_probability;
  const BoundRun tail = runLine(70.0, reanchor);
  EXPECT_GE(tail.reanchorings, 3);  // lost at the start, and the fix agreed with the window
  EXPECT_EQ(tail.reinitialisations, 0);
  // As close to the bound as the same window started at the truth (never lost).
  const BoundRun exact = runLine(0.0, reanchor);
  EXPECT_EQ(exact.reanchorings + exact.reinitialisations, 0);
  EXPECT_LE(tail.ratio(), 1.05 * exact.ratio());
}

TEST(SlidingWindowBound, RestartingWhenLostLeavesTheFirstPosesAtThePrior) {
  // The EKF's policy, for comparison: the restart keeps the first poses where the prior put them.
  const BoundRun run = runLine(70.0, 0.0);
  EXPECT_EQ(run.reanchorings, 0);
  EXPECT_GE(run.reinitialisations, 3);
  EXPECT_GT(run.ratio(), 2.0);
}

}  // namespace
}  // namespace stereoloc
