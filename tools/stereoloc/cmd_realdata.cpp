// `stereoloc realdata DIR`: every estimator on a real dataset against its ground truth
// (src/study/real_data_study.h).
#include <CLI/CLI.hpp>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "src/study/real_data_study.h"
#include "tools/stereoloc/cli_common.h"
#include "tools/stereoloc/localize_common.h"

namespace stereoloc::cli {

void add_realdata_command(CLI::App& app) {
  auto o = std::make_shared<RealDataStudyOptions>();
  CLI::App* sub = app.add_subcommand(
      "realdata", "Run every estimator on a real dataset with ground truth and print RMSE, NEES and timing");
  sub->add_option("DATASET_DIR", o->dataset_dir, "Dataset directory (e.g. from `stereoloc import mrclam`)")
      ->required()
      ->check(CLI::ExistingDirectory);
  sub->add_option("--window", o->window, "Sliding-window size W (poses)")->capture_default_str()->check(CLI::Range(1, 10000));
  sub->add_option("--keyframe-max-steps", o->keyframe_max_steps,
                  "Sliding window: a step without observations becomes a window pose after this many steps "
                  "since the last one (1: every step is a window pose)")
      ->capture_default_str()
      ->check(CLI::Range(1, 1000000));
  sub->add_option("--window-lost-after", o->window_lost_after,
                  "Sliding window: consecutive gated observations that declare it lost")
      ->capture_default_str()
      ->check(CLI::Range(1, 1000000));
  sub->add_flag("!--no-gate", o->gate,
                "EKF and sliding window: no validation gate (every observation fused, never lost); the robust "
                "window runs without the gate anyway (SlidingWindowConfig::gate_with_robust_loss)");
  sub->add_option("--particles", o->particles, "Particle filter size (at least 100)")
      ->capture_default_str()
      ->check(particleCount());
  sub->add_option("--seed", o->seed, "Seed of the particle filter")->capture_default_str();
  sub->add_option("--robust", o->robust, "Robust loss of the second window and batch runs: huber or cauchy")->capture_default_str();
  sub->add_option("--robust-scale", o->robust_scale, "Robust loss scale (whitened units)")
      ->capture_default_str()
      ->check(positiveNumber());
  sub->add_option("--max-steps", o->max_steps, "Use only the first N steps (0: all)")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber);
  sub->add_option("--init-sigma-xy", o->init_sigma_xy, "Initial position sigma, mm")
      ->capture_default_str()
      ->check(positiveNumber());
  sub->add_option("--init-sigma-theta-deg", o->init_sigma_theta_deg, "Initial heading sigma, degrees")
      ->capture_default_str()
      ->check(positiveNumber());
  sub->add_option("--batch-guess", o->batch_guess,
                  "Initial guess of the batch smoother: filter (a forward EKF pass) or odometry")
      ->capture_default_str();
  std::string keys;
  for (const std::string& k : realDataEstimatorKeys()) keys += (keys.empty() ? "" : ",") + k;
  sub->add_option("--only", o->only,
                  "Comma-separated subset: " + keys +
                      " (_calib: self-calibrating the odometry; _calib_range: the odometry and the range sensor)");
  sub->add_option("--csv", o->csv_path, "Also write the table as CSV (units: mm, rad, ms)");
  auto delay = std::make_shared<std::optional<std::string>>();
  sub->add_option("--odometry-delay", *delay,
                  "Every estimator on the odometry re-timed by this delay, seconds within +-2; 'fit': the delay the "
                  "batch calibrating odometry and range finds (printed)");
  sub->callback([o, delay, sub] {
    RealDataStudyOptions run = *o;
    run.odometry_delay = parseOdometryDelay(*delay, &run.given_odometry_delay_s);
    checkRealDataStudyOptions(run);
    const auto refuse = [&](const char* option, const std::vector<std::string>& prefixes, const std::string& who) {
      refuseUnused(*sub, option, realDataRunsAny(run, prefixes), who, " (--only lists none)");
    };
    for (const char* option : {"--window", "--keyframe-max-steps", "--window-lost-after"})
      refuse(option, {"window"}, "the window's estimators");
    refuse("--no-gate", {"ekf", "window"}, "the EKF's and the window's estimators");
    for (const char* option : {"--particles", "--seed"}) refuse(option, {"pf"}, "the particle filter");
    for (const char* option : {"--robust", "--robust-scale"})
      refuse(option, {"window_robust", "batch_robust"}, "the robust window and batch");
    if (run.odometry_delay != OdometryDelayMode::Fit)
      refuse("--batch-guess", {"batch"}, "the batch's estimators and --odometry-delay fit");
    runRealDataStudy(run);
  });
}

}  // namespace stereoloc::cli
