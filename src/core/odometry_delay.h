#pragma once
// A robot whose odometry runs late against its camera: the drive carries out a velocity
// command some time after the command's timestamp, or the odometry clock runs ahead of the
// camera's. delayOdometry re-times a step stream's wheel readings by such a delay (offline, any
// sign), OdometryRetimer does the same step by step for a stream (a delay >= 0 needs only the
// steps before); the batch smoother estimates the delay from the data
// (solvers/odometry_delay_profile.h).
#include <deque>
#include <vector>

#include "src/core/odometry_model.h"
#include "src/core/types.h"

namespace stereoloc {

// The steps with each reading replaced by the travel the readings give over the step's interval
// moved delay_s earlier, [t_{k-1} - delay, t_k - delay]: the motion of a robot that does what
// its readings say delay_s later. Between step times the cumulative reading of each wheel is
// linear in time (each step's travel at a constant speed over its interval); before the first
// step's time nothing moves, after the last the robot stands. The first step keeps its reading
// (no interval), the step times, indices and observations stay. delay_s = 0 returns the readings
// unchanged; a negative delay moves them later. Throws stereoloc::Error for a non-finite delay
// or step times that go backwards (naming the step).
std::vector<Step> delayOdometry(const std::vector<Step>& steps, double delay_s);

// delayOdometry for a stream, one step at a time, for a delay >= 0: next() returns exactly what
// delayOdometry gives that step, and keeps only the steps the next intervals can reach.
class OdometryRetimer {
 public:
  explicit OdometryRetimer(double delay_s);  // throws stereoloc::Error unless 0 <= delay_s <= 10 s
  // The motion (mm per wheel) for the reading of the step at time t (s); steps in time order
  // (with a delay, throws stereoloc::Error for a time before the previous step's, changing
  // nothing).
  WheelIncrements next(double t, double d_left, double d_right);
  double delay() const { return delay_s_; }

 private:
  struct Knot {
    double t, left, right;  // s; cumulative readings, mm
  };
  double delay_s_;
  std::deque<Knot> knots_;  // the first the stream's start while it is kept
};

}  // namespace stereoloc
