#pragma once
// The thesis's simulated scenarios (chapter 6, section 5.1.3) as lists of true poses.
//
// Step numbering: the dataset step s (0-based) is the thesis's step s + 1. Step 0 is the
// initial pose; it has no odometry. So a thesis trial of "100 steps" is poses 0..99 and 99
// motions, and the thesis's heading rule theta_k = theta_1 - (k - 1) * rotation / 100
// (scenarios.md, verified against the reported visibility windows) becomes
// theta_s = theta_0 - s * rotation / 100.
//
// Drivable scenarios (circle, line, spin, kidnap, random-walk) are kinematic paths of a
// differential-drive robot: successive poses are joined by exact arcs. The global-fix
// scenarios (rect, spin-at, rect-spin, line-fixed, line-turn; thesis 6.3, 6.4) are lists of
// INDEPENDENT poses (L1979: "the position at each step does not use information acquired at
// any other step"); a fixed heading along a rectangle is not drivable, so the odometry the
// simulator writes for them is only the arc approximation (see simulator.h).
#include <cstdint>
#include <random>
#include <string>
#include <vector>

#include "src/core/pose2.h"

namespace stereoloc {

struct ScenarioOptions {
  int steps = 0;            // number of poses; 0 = the scenario's default (100, 200 for kidnap,
                            // 10000 for random-walk)
  bool head_scan = false;   // sweep the head pan (see head_scan_amplitude) instead of gamma = 0
  double head_scan_amplitude_rad = 0.5235987755982988;  // 30 deg: gamma = A sin(2 pi s / period)
  int head_scan_period_steps = 40;
};

struct Scenario {
  std::string name;
  int trial = 0;                  // 0-based trial index (thesis trial 'a' = 0)
  std::string description;        // human-readable, with the thesis section
  bool independent_poses = false; // true for the global-fix scenarios (not a drivable path)
  std::vector<Pose2> poses;       // true pose of every step (mm, rad)
  std::vector<double> head_pan;   // gamma of every step (rad)
  std::vector<bool> carried;      // carried[s]: the robot was carried (kidnapped) into pose s;
                                  // its wheels did not turn, so odometry reads 0
  double dt = 0.1;                // s between steps (the thesis gives none; 10 Hz assumed)
};

// All scenario names, in a fixed order.
std::vector<std::string> scenarioNames();
// Number of trials of a scenario (1 for circle, line, spin, kidnap, random-walk).
int scenarioTrialCount(const std::string& name);
// Builds a scenario. `rng` is used only by random-walk. Throws stereoloc::Error for an unknown
// name (listing the valid ones) or a trial out of range.
Scenario makeScenario(const std::string& name, int trial, const ScenarioOptions& options, std::mt19937_64& rng);

}  // namespace stereoloc
