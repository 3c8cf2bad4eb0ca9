#include "tools/stereoloc/localize_common.h"

#include <CLI/CLI.hpp>
#include <cstdio>
#include <memory>

#include "src/dataset.h"
#include "src/estimate_io.h"
#include "src/evaluation.h"
#include "tools/stereoloc/cli_common.h"
#include "tools/stereoloc/methods.h"

namespace stereoloc::cli {

void runLocalize(const LocalizeArgs& a) {
  MethodOptions o = a.options;
  try {
    o.init = initModeFromString(a.init);
    o.loss = robustLossFromString(a.loss);
  } catch (const Error& e) {
    throw UsageError(e.what());
  }
  parseMethodSpec(a.method, o.init);  // usage errors before reading data
  const Dataset d = loadDataset(a.dataset);
  const MethodRun run = runMethod(a.method, d, a.seed, o);
  writeEstimatesCsv(a.out, run.estimates);
  if (!a.tum.empty()) writeEstimatesTum(a.tum, run.estimates);
  std::printf("%s: %zu estimates for %zu steps written to %s (%.3f ms/step)\n", a.method.c_str(), run.estimates.size(),
              d.steps.size(), a.out.c_str(), run.ms_per_step);
  const TrajectoryMetrics m = trajectoryMetrics(poseErrors(run.estimates, truthByStep(d.steps, d.groundtruth)));
  if (m.count > 0)
    std::printf("against ground truth (%zu poses): position RMSE %.1f mm, theta RMSE %.2f deg, mean NEES %.2f\n", m.count,
                m.position_rmse, rad2deg(m.theta_rmse), m.mean_nees);
}

void addLocalizeOptions(CLI::App* sub, const std::shared_ptr<LocalizeArgs>& a, bool method_option) {
  sub->add_option("dataset", a->dataset, "Dataset directory (see README: dataset format)")->required()->check(CLI::ExistingDirectory);
  if (method_option)
    sub->add_option("--method", a->method, "fix1, fix2, ekf, pf, window, batch or deadreckoning (optionally :known, :random, :global)")
        ->capture_default_str();
  sub->add_option("--init", a->init, "Start of the trackers: known (truth + noise), random, or global (first global fix)")
      ->capture_default_str();
  sub->add_option("--particles", a->options.particles, "Particles of the particle filter")->capture_default_str()->check(CLI::PositiveNumber);
  sub->add_option("--window", a->options.window, "Window size W of the sliding-window smoother")->capture_default_str()->check(CLI::PositiveNumber);
  sub->add_option("--loss", a->loss, "Robust loss of the batch smoother: none, huber or cauchy")->capture_default_str();
  sub->add_option("--loss-scale", a->options.loss_scale, "Robust loss scale in whitened units")->capture_default_str()->check(CLI::PositiveNumber);
  sub->add_option("--seed", a->seed, "Seed of the start noise and the particle filter")->capture_default_str();
  sub->add_option("--out", a->out, "Estimates CSV: step,t,x,y,theta,cov_xx,cov_xy,cov_xtheta,cov_yy,cov_ytheta,cov_thetatheta")->required();
  sub->add_option("--tum", a->tum, "Also write the trajectory in TUM format (metres), e.g. for evo");
}

}  // namespace stereoloc::cli
