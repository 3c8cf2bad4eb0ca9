#pragma once
// `stereoloc kidnap`: the kidnapped-robot study of thesis section 5.1.3 (Figs. 5.2-5.6).
//
// For every seed the simulator drives the `kidnap` scenario (line A -> B in 100 steps, carried
// back to A at step 100 without the odometry knowing, then A -> B again). The EKF tracks it
// with the validation gate (5.20) and the lost policy (GateConfig::lost_after consecutive
// gated observations), re-initialising from the global fixes (chapter 4) when lost (Fig. 5.6).
// Measured per seed:
//   detection   observation steps (steps with at least one observation) from the kidnap up to
//               and including the step the filter declares itself lost; target <= 3 in >= 95 %
//               of the seeds;
//   recovery    steps from the re-initialisation until the position error is below 100 mm;
//               target <= 10.
// With --out DIR it writes plot-ready CSV (units mm, rad):
//   kidnap_seeds.csv        one row per seed with the figures above;
//   kidnap_trace.csv        for the plot seed, per step and run (`nogate`: every observation
//                           fused, Figs. 5.3-5.5; `recovery`: gate + global fix, Fig. 5.6):
//                           truth, estimate, error, +-3 sigma, status, largest e^2 of the step;
//   kidnap_innovations.csv  for the plot seed, one row per update: innovation (range, bearing),
//                           its +-1 sigma from S (Fig. 5.4), e^2 (Fig. 5.5), gate threshold,
//                           accepted.
#include <cstdint>
#include <cstdio>
#include <string>

namespace stereoloc {

struct KidnapStudyOptions {
  int seeds = 100;
  uint64_t first_seed = 1;
  long plot_seed = -1;  // -1: the first seed
  std::string out_dir;
  double gate_probability = 0.99;
  int lost_after = 3;
  std::string landmarks = "goal_corners";
  int steps = 0;  // 0: the scenario's default (200)
  int detect_within = 3;
  int recover_within = 10;
  double recover_mm = 100.0;
  std::FILE* console = stdout;  // the summary
};

// Runs the study: prints the summary over the seeds to `console` and writes the CSV files into
// out_dir when set. Bad options throw UsageError.
void runKidnapStudy(const KidnapStudyOptions& options);

}  // namespace stereoloc
