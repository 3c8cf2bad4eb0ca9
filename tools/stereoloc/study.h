#pragma once
// `stereoloc study`: the accuracy comparison. For each scenario and trial: simulate with a
// deterministic per-trial seed, run every method on the same data, evaluate against the
// ground truth. Writes trials.csv (appended and flushed per trial, so an interrupted study
// keeps its completed rows), steps.csv (per-step errors and NEES, for the figures),
// trajectories/ (trial 0 of each scenario), then summary.csv, report.md and the figures.
// Sharded studies are merged by recomputing everything from trials.csv / steps.csv, so a
// merged study equals the unsharded one.
#include <cstdint>
#include <string>
#include <vector>

#include "src/pipeline/methods.h"

namespace stereoloc::cli {

// Trials per scenario of the default study (`make demo`): measured to finish within 2 minutes on
// a 2-core machine with the image frontend (see README).
constexpr int kDefaultStudyTrials = 40;

struct StudyConfig {
  std::vector<std::string> scenarios = {"circle", "line", "spin", "kidnap"};
  std::vector<std::string> methods = {"fix1", "fix2", "ekf", "ekf:random", "ekf:global", "pf", "window", "batch"};
  int trials = kDefaultStudyTrials;
  uint64_t seed = 1;
  int threads = 0;            // 0 = all cores
  int shard_index = 0;        // this shard runs trials shard_index, shard_index + shard_count, ...
  int shard_count = 1;
  // "images": every step's stereo pair is rendered (src/sim/renderer.h) and the vision frontend
  // finds the observations (src/pipeline/frontend_source.h); "pixels": the simulator's noisy
  // pixel projections of the visible goal corners.
  std::string frontend = "images";
  std::string frontend_landmarks = "all";  // images: all | goal_corners (frontend_source.h)
  double image_noise = 1.5;   // images: Gaussian sensor noise, grey levels (as bench_frontend's "good" set)
  MethodOptions method_options;
  std::string out_dir;
  bool force = false;
  bool progress = true;       // a progress bar when stderr is a terminal
};

// Deterministic seed of one trial, independent of thread count and sharding.
uint64_t trialSeed(uint64_t study_seed, const std::string& scenario, int trial);

// Runs the study; returns the process exit code.
void runStudy(const StudyConfig& config);

// Merges sharded study directories into `out_dir` (recomputes summary, report, figures).
void mergeStudies(const std::vector<std::string>& dirs, const std::string& out_dir, bool force);

}  // namespace stereoloc::cli
