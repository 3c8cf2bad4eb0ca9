// `stereoloc refine DIR --out est.csv`: offline trajectory refinement with the batch smoother,
// the same estimates as `localize --method batch`. On long logs it shows its progress on stderr
// (only when stderr is a terminal) and ends with the iterations and the time of each phase.
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <memory>
#include <optional>
#include <string>

#include "solvers/batch_smoother.h"
#include "src/eval/evaluation.h"
#include "src/io/estimate_io.h"
#include "tools/stereoloc/cli_common.h"
#include "tools/stereoloc/localize_common.h"

namespace stereoloc::cli {
namespace {

using Clock = std::chrono::steady_clock;
double secondsSince(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }
std::string fixed2(double v) {
  char b[32];
  std::snprintf(b, sizeof b, "%.2f", v);
  return b;
}

// One self-overwriting status line on stderr, at most a few times a second; silent when stderr
// is not a terminal (logs and pipes get the summary only).
class ProgressLine {
 public:
  ProgressLine() : enabled_(::isatty(::fileno(stderr)) != 0) {}
  ~ProgressLine() { clear(); }
  void show(const char* text) {
    if (!enabled_ || secondsSince(last_) < 0.25) return;
    last_ = Clock::now();
    std::fprintf(stderr, "\r%-72s", text);
    shown_ = true;
  }
  void clear() {
    if (shown_) std::fprintf(stderr, "\r%-72s\r", "");
    shown_ = false;
  }

 private:
  bool enabled_, shown_ = false;
  Clock::time_point last_ = Clock::now();
};

void runRefine(const LocalizeArgs& a) {
  MethodOptions o = parseMethodOptions(a);
  parseMethodSpec("batch", o.init);  // usage errors before reading data
  ProgressLine progress;
  const auto t_load = Clock::now();
  CalibrationHandover handover;
  Dataset d = loadRunDataset(a, o, handover);
  const double load_s = secondsSince(t_load);
  const auto t_delay = Clock::now();
  std::optional<OdometryDelayEstimate> fitted_delay;
  if (o.odometry_delay != OdometryDelayMode::None) {
    progress.show("refine: odometry delay");
    d.steps = stepsWithOdometryDelay("batch", d, a.seed, o, &fitted_delay);
  }
  const double delay_s = secondsSince(t_delay);
  BatchSmootherConfig c = batchConfigFor("batch", d, a.seed, o);
  char line[128];
  c.progress = [&](const BatchProgress& p) {
    if (p.phase == "solve")
      std::snprintf(line, sizeof(line), "refine: solve, iteration %ld, cost %.6g", p.done, p.cost);
    else if (p.phase == "cut test")
      std::snprintf(line, sizeof(line), "refine: testing kidnap cut %ld of %ld", p.done + 1, p.total);
    else
      std::snprintf(line, sizeof(line), "refine: %s", p.phase.c_str());
    progress.show(line);
  };
  auto smoother = std::make_unique<BatchSmoother>(d.map, d.odometry, c);
  const size_t steps = d.steps.size();
  for (size_t i = 0; i < steps; ++i) {
    smoother->process(d.steps[i]);
    if (i % 4096 == 0) {
      std::snprintf(line, sizeof(line), "refine: filter pass %zu / %zu steps", i, steps);
      progress.show(line);
    }
  }
  // The smoother holds what it needs: keep only the step numbers and the ground truth.
  std::vector<long> step_numbers(steps);
  for (size_t i = 0; i < steps; ++i) step_numbers[i] = d.steps[i].step;
  std::vector<Step>().swap(d.steps);
  const std::vector<Estimate> estimates = smoother->finish();
  const BatchSummary s = smoother->summary();
  CalibrationEstimate calibration = smoother->calibration();
  recordOdometryDelay(calibration, o, fitted_delay, handover);
  smoother.reset();  // its buffers are not needed for writing and the metrics
  for (const Estimate& e : estimates)
    if (!e.pose.isFinite() || !e.covariance.allFinite())
      throw Error("refine: the smoother produced a non-finite estimate at step " + std::to_string(e.step));
  progress.show("refine: writing");
  const auto t_write = Clock::now();
  writeEstimatesCsv(a.out, estimates);
  if (!a.tum.empty()) writeEstimatesTum(a.tum, estimates);
  noteConstantWheelsInTheBatch(o);
  reportCalibration(a.calibration_out, stdout, o.calibration.any() ? &calibration : nullptr, d.rig, o.calibration,
                    d.odometry.wheel_base_mm, handover);
  writeMeasuredField(a.field_out, d.map, o.calibration.any() ? &calibration : nullptr);
  const double write_s = secondsSince(t_write);
  progress.clear();
  printOdometryDelay(o, fitted_delay, handover);
  writeOdometryDelayProfile(a.odometry_delay_profile, fitted_delay);
  std::printf("batch: %zu estimates for %zu steps written to %s\n", estimates.size(), steps, a.out.c_str());
  std::printf("solve: %d iterations (%s)%s; %d kidnap cut%s kept, %d withdrawn (%d of them for one sighting left out; "
              "%d iterations)\n",
              s.iterations, s.converged ? "converged" : "not converged", s.message.empty() ? "" : (": " + s.message).c_str(),
              static_cast<int>(s.cut_steps.size()), s.cut_steps.size() == 1 ? "" : "s", s.withdrawn_cuts, s.cut_outliers,
              s.cut_test_iterations);
  std::printf("time: load %.2f s,%s filter pass %.2f s, solve %.2f s (cut tests %.2f s), covariance %.2f s, write %.2f s\n",
              load_s, fitted_delay ? (" odometry delay " + fixed2(delay_s) + " s,").c_str() : "", s.filter_seconds,
              s.solve_seconds, s.cut_test_seconds, s.covariance_seconds, write_s);
  TruthByStep truth_by_step;
  for (size_t i = 0; i < d.groundtruth.size(); ++i)
    if (d.groundtruth[i]) truth_by_step.emplace_hint(truth_by_step.end(), step_numbers[i], *d.groundtruth[i]);
  printAgainstTruth(trajectoryMetrics(poseErrors(estimates, truth_by_step)));
}

}  // namespace

void add_refine_command(CLI::App& app) {
  auto a = std::make_shared<LocalizeArgs>();
  a->method = "batch";
  CLI::App* sub = app.add_subcommand("refine", "Offline trajectory refinement with the batch smoother (= localize --method batch)");
  addLocalizeOptions(sub, a, false);
  sub->callback([a, sub] {
    checkMethodOptions(*a, *sub);
    runRefine(*a);
  });
}

}  // namespace stereoloc::cli
