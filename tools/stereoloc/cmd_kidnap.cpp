// `stereoloc kidnap`: the kidnapped-robot study of thesis section 5.1.3 (src/study/kidnap_study.h).
#include <CLI/CLI.hpp>
#include <memory>

#include "src/study/kidnap_study.h"
#include "tools/stereoloc/cli_common.h"

namespace stereoloc::cli {

void add_kidnap_command(CLI::App& app) {
  auto o = std::make_shared<KidnapStudyOptions>();
  CLI::App* sub = app.add_subcommand(
      "kidnap", "Kidnapped-robot study (thesis 5.1.3): EKF gate detection and global-fix recovery over many seeds");
  sub->add_option("--seeds", o->seeds, "Number of seeds (simulated trials)")->capture_default_str()->check(CLI::Range(1, 1000000));
  sub->add_option("--seed", o->first_seed, "First seed")->capture_default_str();
  sub->add_option("--plot-seed", o->plot_seed, "Seed whose trace is written (default: the first)");
  sub->add_option("--out", o->out_dir, "Directory for kidnap_seeds.csv, kidnap_trace.csv, kidnap_innovations.csv");
  sub->add_option("--gate-probability", o->gate_probability, "Chi-square probability of the gate (5.20)")
      ->capture_default_str();
  sub->add_option("--lost-after", o->lost_after, "Consecutive gated observations that declare the robot lost")
      ->capture_default_str()->check(CLI::Range(1, 1000));
  sub->add_option("--landmarks", o->landmarks, "Simulated landmarks: goal_corners or all")->capture_default_str();
  sub->add_option("--steps", o->steps, "Scenario length in steps (0: the default 200, kidnap at the half)")
      ->capture_default_str()->check(CLI::Range(0, 1000000));
  sub->callback([o, sub] {
    refuseUnused(*sub, "--plot-seed", !o->out_dir.empty(), "--out");
    runKidnapStudy(*o);
  });
}

}  // namespace stereoloc::cli
