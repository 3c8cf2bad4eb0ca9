#pragma once
// `stereoloc fixstudy`: the global-localisation studies of thesis sections 6.3 (two landmarks,
// Tables 6.4-6.8) and 6.4 (one landmark + compass, Tables 6.9-6.13), reproduced with the
// simulator's pixel-level observations and printed in the thesis's format beside its numbers.
//
// Every step of every trial is an independent attempt (L1979: "the position at each step does
// not use information acquired at any other step"). fix2 ignores the compass; fix1 is repeated
// for compass noise 0..10 deg with the SAME observations (the thesis repeats "the experiment
// for varying level of noise in robot orientation"); the compass noise uses common random
// numbers across the levels (one N(0,1) draw per step, scaled by each sigma). Besides the
// thesis's error statistics we report the consistency of the covariances (NEES): the mean 3-dof
// and position-only (2-dof) NEES with the 95 % band of such a mean, split by the rule
// "linearisation holds" = GlobalFix::nonlinearity <= GlobalFixOptions::linear_max_nonlinearity
// (the sigma points' position bias in position sigmas; computed with FixCovariance::SigmaPoints
// whatever --covariance says, so that every model is judged on the same fixes) evaluated at the
// noise-free measurement (unbiased split; the per-fix split is printed too), by the range of the
// farthest landmark used, since the linearisation fails for distant landmarks (4.4), and for fix2
// by the angle between the landmarks. `--method multi` (or all) adds the least-squares fix
// (4.2.8) on the steps with >= 2 identified landmarks and a 3.5 deg compass, with the stereo
// observations as range-bearing and as pixels (GlobalFixOptions::rig), same steps, same draws.
// With images in a world other than the ideal one, Table 6.3 (goal-corner range error, absolute
// and normalised by the true range, pooled over the categories) is printed per world beside the
// thesis's, with the recall of the goal corners the simulator finds visible, and a self-calibrated
// column: the same raw pairs through the frontend with the rig the batch smoother's
// self-calibration (solvers/self_calibration.h) estimated on the trial's own sequence
// (solvers/self_calibrated_rig.h), with the world's profile as priors and noise model and the
// independent poses linked only loosely (their odometry does not describe the motion).
#include <cstdint>
#include <cstdio>
#include <string>
#include <vector>

namespace stereoloc {

struct FixStudyOptions {
  std::string category = "all";
  std::string method = "both";
  double pixel_sigma = 0.5;
  bool quantise = false;
  bool first_order = false;
  std::string covariance = "sigma_points";
  uint64_t seed = 1;
  int runs = 1;
  // Also write the tables here when set: fixstudy.txt, fixes.csv and, with images in a non-ideal
  // world, range_trials.csv (per trial and column: range bias, drawn camera errors, estimate).
  std::string out;
  std::string tables;                       // thesis_tables.yaml; "" = data/thesis_tables.yaml
  std::string frontend = "pixels";          // pixels | images | both
  std::string frontend_landmarks = "all";   // images: which frontend observations (fixes use goal corners only)
  double image_noise = 1.5;                 // images: sensor noise of the rendered pairs, grey levels
  // Worlds (src/sim/error_profile.h): "ideal", "realistic" or profile YAML files, each run on the
  // same trial seeds. A non-ideal world's simulated pixels are its true raw projections
  // undistorted with the given calibration, and its images are raw pairs of the true cameras,
  // which the frontend rectifies with the given calibration. Unless the list is exactly
  // {"ideal"}, the tables get one column per world and, with images, the goal-corner range
  // statistics of thesis Table 6.3 and the goal-corner recall are added.
  std::vector<std::string> profiles = {"ideal"};
  // Self-calibration parts (SelfCalibrationConfig::parse: stereo or odometry,stereo; none): with
  // images, each non-ideal world also gets a column of the same raw pairs through the frontend
  // with the rig the self-calibrating batch estimated on the trial's own image sequence.
  std::string calibrate = "stereo";
  int steps = 0;                            // poses per trial; 0 = the scenario's default (100)
  std::FILE* console = stdout;              // the tables
  std::FILE* log = stderr;                  // image frontend timings; null: none
};

// Runs the study: prints the tables beside the thesis's numbers to `console` and writes them (and
// fixes.csv) into the directory `out` names when set. Bad options throw UsageError.
void runFixStudy(const FixStudyOptions& options);

}  // namespace stereoloc
