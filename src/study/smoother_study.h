#pragma once
// The smoother study (`stereoloc smoothers`): the batch smoother, the sliding window (W = 5, 10,
// 20, 50), the EKF and the particle filter side by side, each against its posterior Cramér–Rao
// bound.
//
// For every scenario and trial the simulator drives the scenario with the trial's seed (the
// seed `stereoloc study --frontend pixels` uses for the same scenario and trial: the same datasets),
// and every method runs on the same data from the same known start (common random numbers:
// one method seed per trial, so the initial-belief noise is shared and the ratios to the EKF
// are paired). Per method and scenario, over all steps and trials:
//   position RMSE (mm), theta RMSE, mean NEES (3 dof), the fraction of per-estimate NEES inside
//   the two-sided 95 % chi-square(3) interval, the fraction of steps whose NEES averaged over
//   the trials lies inside the 95 % band of that average (chi2(3N)/N, Bar-Shalom's test), and
//   RMSE / sqrt(CRLB): the position RMSE divided by the square root of the mean trace of the
//   position block of the bound (solvers/crlb.h), computed per trial at the true trajectory
//   with the known start's P0.
// The bound of each output: smoothing for batch; fixed lag W - 1 for the window (what
// runMethod returns is its history: a pose leaves the window, with its estimate from the data
// up to W - 1 steps later, and the final window is smoothed); filtering for EKF and PF (causal).
//
// Deterministic for a seed whatever --threads: trials run in parallel, results are summed in
// trial order.
#include <cstdint>
#include <string>

namespace stereoloc {

struct SmootherStudyConfig {
  std::string scenarios = "circle,line,spin";  // comma-separated drivable scenarios
  int trials = 100;
  uint64_t seed = 1;
  int threads = 0;  // 0 = all cores
  std::string windows = "5,10,20,50";           // comma-separated window sizes W
  std::string observation_model = "pixel_columns";  // batch and window: range_bearing | pixel_columns | pixels
  // The simulator's pixel noise (src/sim/simulator.h): independent (0.5 px per coordinate, the
  // thesis's) or per_kind (the frontend's correlated (u, v, d) model); the observations carry it.
  std::string pixel_noise = "independent";
  int particles = 3000;                         // particle filter
  std::string out_dir;  // when set: out_dir/smoothers.md (created atomically)
};

// Runs the study and returns its markdown report (also written to out_dir/smoothers.md when
// out_dir is set). Bad options throw UsageError; a failed trial throws Error.
std::string runSmootherStudy(const SmootherStudyConfig& config);

}  // namespace stereoloc
