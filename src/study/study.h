#pragma once
// The accuracy study (`stereoloc study`, `make demo`): for each scenario and trial, simulate with
// a deterministic per-trial seed, optionally render the stereo pairs and run the vision frontend,
// run every method on the same data and evaluate it against the ground truth.
//
//   StudyConfig c;  c.scenarios = {"circle"};  c.methods = {"ekf", "batch"};  c.trials = 5;
//   c.frontend = "pixels";  c.out_dir = "out/study";
//   const StudyResult r = runStudy(c);   // r.summary: one row per scenario and method
//
// With several error profiles (StudyConfig::profiles) every trial runs in each world; the rows
// carry a profile column and the report puts the worlds side by side.
// Writes into out_dir: study.yaml (the config), trials.csv (appended and flushed per trial, so an
// interrupted study keeps its completed rows), steps.csv (per-step errors and NEES), summary.csv,
// report.md and PNG figures. Results depend only on the config (not on threads or shards);
// sharded studies are merged by recomputing everything from their trials.csv / steps.csv.
// The parts: study_trial.h (one trial), study_rows.h (rows, CSV, summary), study_report.h.
// To add a config field: StudyConfig, its check in runStudy, study.yaml (writeStudyYaml,
// readStudyYaml, the merge check); to add a per-method column: TrialRow, runTrial, the CSV
// header/writer/reader and SummaryRow.
#include <cstdint>
#include <cstdio>
#include <string>
#include <vector>

#include "src/pipeline/methods.h"
#include "src/study/study_rows.h"

namespace stereoloc {

// Trials per scenario of the default study (`make demo`): measured to finish within 2 minutes on
// a 2-core machine with the image frontend (docs/results.md).
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
  // Error profiles of the simulated world (src/sim/error_profile.h): "ideal", "realistic" or a
  // profile YAML file. Every method runs on every profile with the same trial seeds, so the
  // worlds are compared on the same noise draws; the rows carry the profile.
  std::vector<std::string> profiles = {"ideal"};
  std::string frontend_landmarks = "all";  // images: all | goal_corners (frontend_source.h)
  double image_noise = 1.5;   // images: Gaussian sensor noise, grey levels
  MethodOptions method_options;
  std::string out_dir;
  bool force = false;         // replace a non-empty out_dir
  bool progress = true;       // a progress bar on `log` when it is a terminal
  std::FILE* log = stderr;    // diagnostics (render cache, frontend timings, progress); null: none
};

struct StudyResult {
  std::vector<study::SummaryRow> summary;  // per scenario and method, in the config's order
  std::string report;                      // path of report.md
  size_t trial_rows = 0;                   // rows of trials.csv
};

// Deterministic seed of one trial, independent of thread count and sharding.
uint64_t trialSeed(uint64_t study_seed, const std::string& scenario, int trial);

// Runs the study. Bad options throw UsageError, bad data or a failed trial Error.
StudyResult runStudy(const StudyConfig& config);

// Merges sharded study directories into `out_dir` (recomputes summary, report, figures).
StudyResult mergeStudies(const std::vector<std::string>& dirs, const std::string& out_dir, bool force);

}  // namespace stereoloc
