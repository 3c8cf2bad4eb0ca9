#pragma once
// A robot whose odometry runs late against its camera: the drive carries out a velocity
// command some time after the command's timestamp, or the odometry clock runs ahead of the
// camera's. delayOdometry re-times a step stream's wheel readings by such a delay; the batch
// smoother estimates the delay from the data (solvers/odometry_delay_profile.h).
#include <vector>

#include "src/core/types.h"

namespace stereoloc {

// The steps with each reading replaced by the travel the readings give over the step's interval
// moved delay_s earlier, [t_{k-1} - delay, t_k - delay]: the motion of a robot that does what
// its readings say delay_s later. Between step times the cumulative reading of each wheel is
// linear in time (each step's travel at a constant speed over its interval); before the second
// step nothing moves, after the last the robot stands. The first step keeps its reading (no
// interval), the step times, indices and observations stay. delay_s = 0 returns the readings
// unchanged; a negative delay moves them later. Throws stereoloc::Error for a non-finite delay
// or step times that go backwards (naming the step).
std::vector<Step> delayOdometry(const std::vector<Step>& steps, double delay_s);

}  // namespace stereoloc
