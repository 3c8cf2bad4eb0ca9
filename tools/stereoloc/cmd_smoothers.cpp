// `stereoloc smoothers`: batch, sliding window, EKF and PF against the Cramer-Rao bound
// (src/study/smoother_study.h).
#include <CLI/CLI.hpp>
#include <cstdio>
#include <filesystem>
#include <memory>

#include "src/study/smoother_study.h"
#include "tools/stereoloc/cli_common.h"

namespace stereoloc::cli {

void add_smoothers_command(CLI::App& app) {
  auto a = std::make_shared<SmootherStudyConfig>();
  CLI::App* sub = app.add_subcommand(
      "smoothers",
      "Smoothers against filters: batch, sliding window (W = 5, 10, 20, 50), EKF and PF over many seeds: RMSE, NEES and "
      "RMSE / sqrt(CRLB) (posterior Cramer-Rao bound at the truth), side by side; a markdown table");
  sub->add_option("--scenarios", a->scenarios, "Comma-separated drivable scenarios: circle, line, spin, random-walk")
      ->capture_default_str();
  sub->add_option("--trials", a->trials, "Trials (seeds) per scenario")->capture_default_str()->check(positiveNumber());
  sub->add_option("--seed", a->seed, "Study seed (each trial's seed derives from it, as in `stereoloc study`)")
      ->capture_default_str();
  sub->add_option("--threads", a->threads, "Worker threads (0 = all cores); results do not depend on it")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber);
  sub->add_option("--windows", a->windows, "Comma-separated window sizes W of the sliding-window smoother")
      ->capture_default_str();
  sub->add_option("--observation-model", a->observation_model,
                  "How batch and window use the stereo observations, and whose information the bound is: "
                  "range_bearing, pixel_columns or pixels (see `localize --help`)")
      ->capture_default_str();
  sub->add_option("--pixel-noise", a->pixel_noise,
                  "The simulator's pixel noise: independent (0.5 px per coordinate, the thesis's) or per_kind (the "
                  "vision frontend's correlated (u, v, disparity) model per landmark kind)")
      ->capture_default_str();
  sub->add_option("--particles", a->particles, "Particles of the particle filter (at least 100)")
      ->capture_default_str()
      ->check(particleCount());
  sub->add_option("--out", a->out_dir, "Directory for smoothers.md (created if missing); the table is printed anyway");
  sub->callback([a] {
    std::fputs(runSmootherStudy(*a).c_str(), stdout);
    if (!a->out_dir.empty()) std::printf("\nwrote %s\n", (std::filesystem::path(a->out_dir) / "smoothers.md").string().c_str());
  });
}

}  // namespace stereoloc::cli
