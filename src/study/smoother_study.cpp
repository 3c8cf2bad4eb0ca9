#include "src/study/smoother_study.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "solvers/crlb.h"
#include "src/core/atomic_file.h"
#include "src/core/gaussian.h"
#include "src/eval/evaluation.h"
#include "src/pipeline/methods.h"
#include "src/pipeline/usage_error.h"
#include "src/sim/simulator.h"
#include "src/study/study.h"
#include "src/study/text_format.h"

namespace stereoloc {
namespace {

enum class BoundKind { Smoothing, FixedLag, Filtering };

struct MethodSpec {
  std::string label;   // "batch", "window W=20", "ekf", "pf"
  std::string method;  // runMethod name
  int window = 0;
  BoundKind bound = BoundKind::Filtering;
};

// Sums over the estimates of one method on one scenario (all trials).
struct Accumulator {
  double se_position = 0, se_theta = 0, bound_position = 0, rb_bound_position = 0;
  long count = 0;
  double nees_sum = 0;
  long nees_count = 0, nees_in_interval = 0;
  std::map<long, std::pair<double, long>> nees_by_step;  // step -> (sum, count) over trials

  void add(const Accumulator& o) {
    se_position += o.se_position;
    se_theta += o.se_theta;
    bound_position += o.bound_position;
    rb_bound_position += o.rb_bound_position;
    count += o.count;
    nees_sum += o.nees_sum;
    nees_count += o.nees_count;
    nees_in_interval += o.nees_in_interval;
    for (const auto& [step, v] : o.nees_by_step) {
      auto& s = nees_by_step[step];
      s.first += v.first;
      s.second += v.second;
    }
  }
  double positionRmse() const { return count ? std::sqrt(se_position / count) : std::nan(""); }
  double thetaRmse() const { return count ? std::sqrt(se_theta / count) : std::nan(""); }
  double sqrtBound() const { return count ? std::sqrt(bound_position / count) : std::nan(""); }
  double sqrtRangeBearingBound() const { return count ? std::sqrt(rb_bound_position / count) : std::nan(""); }
  double meanNees() const { return nees_count ? nees_sum / nees_count : std::nan(""); }
  double inInterval() const { return nees_count ? static_cast<double>(nees_in_interval) / nees_count : std::nan(""); }
  // Fraction of steps whose NEES averaged over the trials lies in the 95 % band of that average.
  double stepsInBand() const {
    long in = 0, n = 0;
    for (const auto& [step, v] : nees_by_step) {
      (void)step;
      if (v.second < 1) continue;
      const NeesBand band = neesBand(3, static_cast<int>(v.second));
      const double mean = v.first / v.second;
      ++n;
      in += (mean >= band.lo && mean <= band.hi) ? 1 : 0;
    }
    return n ? static_cast<double>(in) / n : std::nan("");
  }
};

uint64_t mix(uint64_t x) {  // splitmix64: decorrelates the method seed from the simulation seed
  x += 0x9E3779B97F4A7C15ull;
  x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ull;
  x = (x ^ (x >> 27)) * 0x94D049BB133111EBull;
  return x ^ (x >> 31);
}

std::string boundName(const MethodSpec& m) {
  switch (m.bound) {
    case BoundKind::Smoothing: return "smoothing";
    case BoundKind::FixedLag: return "lag " + std::to_string(m.window - 1);
    case BoundKind::Filtering: return "filtering";
  }
  return "";
}

// One trial: every method on the same simulated data, each against its bound.
std::vector<Accumulator> runSmootherTrial(const std::string& scenario, int trial, const SmootherStudyConfig& a,
                                         const std::vector<MethodSpec>& methods, const MethodOptions& options) {
  const uint64_t seed = trialSeed(a.seed, scenario, trial);
  SimulationConfig sim;
  sim.pixel_noise = pixelNoiseModelFromString(a.pixel_noise);
  const Dataset d = simulate(scenario, trial % std::max(1, scenarioTrialCount(scenario)), sim, seed);
  const TruthByStep truth = truthByStep(d.steps, d.groundtruth);
  // The known start's P0 (section 6.5): the prior every method is given, and the CRLB's.
  const Eigen::Matrix3d P0 = options.init_config.known_sigma.cwiseAbs2().asDiagonal();
  // The bound of the data as the smoothers model them (options.observation_model), and the
  // bound of the range-bearing data (R as reported) for comparison.
  CrlbOptions crlb;
  crlb.observation_model = {options.observation_model, d.rig};
  const TrajectoryInformation info = trajectoryInformation(d, P0, crlb);
  const TrajectoryInformation rb_info = trajectoryInformation(d, P0);
  std::map<long, size_t> index;
  for (size_t k = 0; k < info.steps.size(); ++k) index[info.steps[k]] = k;
  const std::vector<Eigen::Matrix3d> smoothing = smoothingBound(info), filtering = filteringBound(info);
  const std::vector<Eigen::Matrix3d> rb_smoothing = smoothingBound(rb_info), rb_filtering = filteringBound(rb_info);
  std::map<int, std::vector<Eigen::Matrix3d>> lagged, rb_lagged;
  const double lo = chi2Quantile(0.025, 3), hi = chi2Quantile(0.975, 3);
  const uint64_t method_seed = mix(seed ^ 0x5A0071E5ull);  // shared: the same start noise for every method
  std::vector<Accumulator> out(methods.size());
  for (size_t m = 0; m < methods.size(); ++m) {
    const MethodSpec& spec = methods[m];
    MethodOptions o = options;
    if (spec.window > 0) o.window = spec.window;
    const MethodRun run = runMethod(spec.method, d, method_seed, o);
    const std::vector<Eigen::Matrix3d>* bound = &filtering;
    const std::vector<Eigen::Matrix3d>* rb_bound = &rb_filtering;
    if (spec.bound == BoundKind::Smoothing) {
      bound = &smoothing;
      rb_bound = &rb_smoothing;
    }
    if (spec.bound == BoundKind::FixedLag) {
      auto it = lagged.find(spec.window);
      if (it == lagged.end()) it = lagged.emplace(spec.window, fixedLagBound(info, spec.window - 1)).first;
      bound = &it->second;
      auto rb = rb_lagged.find(spec.window);
      if (rb == rb_lagged.end()) rb = rb_lagged.emplace(spec.window, fixedLagBound(rb_info, spec.window - 1)).first;
      rb_bound = &rb->second;
    }
    Accumulator& acc = out[m];
    for (const PoseError& e : poseErrors(run.estimates, truth)) {
      const auto k = index.find(e.step);
      if (k == index.end()) continue;
      acc.se_position += e.distance * e.distance;
      acc.se_theta += e.dtheta * e.dtheta;
      acc.bound_position += (*bound)[k->second].topLeftCorner<2, 2>().trace();
      acc.rb_bound_position += (*rb_bound)[k->second].topLeftCorner<2, 2>().trace();
      ++acc.count;
      if (e.nees) {
        acc.nees_sum += *e.nees;
        ++acc.nees_count;
        acc.nees_in_interval += (*e.nees >= lo && *e.nees <= hi) ? 1 : 0;
        auto& s = acc.nees_by_step[e.step];
        s.first += *e.nees;
        ++s.second;
      }
    }
  }
  return out;
}

std::string num(double v, const char* format) { return std::isfinite(v) ? formatText(format, v) : std::string("n/a"); }

}  // namespace

namespace {

std::vector<int> parseWindows(const std::string& list) {
  std::vector<int> windows;
  for (const std::string& w : splitCommaList(list)) {
    int v = 0;
    try {
      size_t used = 0;
      v = std::stoi(w, &used);
      if (used != w.size()) v = 0;
    } catch (const std::exception&) {
      v = 0;
    }
    if (v < 1) throw UsageError("--windows: '" + w + "' is not a window size >= 1");
    windows.push_back(v);
  }
  return windows;
}

// Every trial of every scenario on `threads` workers; the sums per scenario and method are
// added in task order, so the figures do not depend on the thread count.
std::vector<std::vector<Accumulator>> runSmootherTrials(const SmootherStudyConfig& a,
                                                        const std::vector<std::string>& scenarios,
                                                        const std::vector<MethodSpec>& methods,
                                                        const MethodOptions& options) {
  struct Task {
    size_t scenario;
    int trial;
  };
  std::vector<Task> tasks;
  for (size_t s = 0; s < scenarios.size(); ++s)
    for (int t = 0; t < a.trials; ++t) tasks.push_back({s, t});
  std::vector<std::vector<Accumulator>> results(tasks.size());
  std::vector<std::string> errors(tasks.size());
  std::atomic<size_t> next{0};
  const int threads = std::max(
      1, std::min(static_cast<int>(tasks.size()),
                  a.threads > 0 ? a.threads : static_cast<int>(std::max(1u, std::thread::hardware_concurrency()))));
  auto worker = [&] {
    for (size_t k = next++; k < tasks.size(); k = next++) {
      try {
        results[k] = runSmootherTrial(scenarios[tasks[k].scenario], tasks[k].trial, a, methods, options);
      } catch (const std::exception& e) {
        errors[k] = scenarios[tasks[k].scenario] + " trial " + std::to_string(tasks[k].trial) + ": " + e.what();
      }
    }
  };
  std::vector<std::thread> pool;
  for (int i = 0; i < threads; ++i) pool.emplace_back(worker);
  for (std::thread& t : pool) t.join();
  for (const std::string& e : errors)
    if (!e.empty()) throw Error("smoothers: " + e);

  // Sum in task order: the same numbers for any thread count.
  std::vector<std::vector<Accumulator>> acc(scenarios.size(), std::vector<Accumulator>(methods.size()));
  for (size_t k = 0; k < tasks.size(); ++k)
    for (size_t m = 0; m < methods.size(); ++m) acc[tasks[k].scenario][m].add(results[k][m]);
  return acc;
}

// The report: a table per scenario, the means over the scenarios and the smoothers' targets.
std::string formatReport(const SmootherStudyConfig& a, const std::vector<std::string>& scenarios,
                         const std::vector<MethodSpec>& methods, const MethodOptions& options,
                         const std::vector<std::vector<Accumulator>>& acc) {
  const bool pixel_model = options.observation_model != ObservationModel::RangeBearing;
  const size_t ekf = methods.size() - 2;
  const NeesBand band = neesBand(3, a.trials);
  std::string md;
  md += "# Smoothers against filters and the Cramér–Rao bound\n\n";
  md += formatText("Scenarios %s; %d trials each (seed %llu, the simulated pixel-observation datasets of `stereoloc study --frontend pixels` with the same seed); every "
            "method from the same known start (sigma %.0f mm, %.0f mm, %.1f deg; section 6.5); PF %d particles; simulated pixel noise %s.\n\n",
            a.scenarios.c_str(), a.trials, static_cast<unsigned long long>(a.seed), options.init_config.known_sigma(0),
            options.init_config.known_sigma(1), rad2deg(options.init_config.known_sigma(2)), a.particles,
            a.pixel_noise.c_str());
  md += "RMSE over all steps and trials. NEES: 3 dof; \"in 95 %\" is the fraction of estimates inside the two-sided "
        "95 % chi-square(3) interval (0.95 when consistent); \"steps in band\" the fraction of steps whose NEES "
        "averaged over the trials lies inside the 95 % band of that average (chi2(3N)/N). CRLB: the posterior "
        "Cramér–Rao bound at the true trajectory (solvers/crlb.h) of the output's information: smoothing (all data) "
        "for batch; fixed lag W-1 for the window (its output per pose: the estimate when the pose leaves the "
        "window, the final window smoothed); filtering (causal) for EKF and PF. RMSE/sqrt(CRLB): position RMSE over "
        "sqrt of the mean trace of the bound's position block; 1.0 is the physical limit.\n";
  md += formatText("\nObservation model of batch and window: %s (EKF and PF always use range-bearing). The bound is the "
            "information of the data in that model%s\n",
            a.observation_model.c_str(),
            pixel_model ? "; \"/sqrt(CRLB r-b)\" divides by the bound of the range-bearing data with R as reported."
                        : ".");
  for (size_t s = 0; s < scenarios.size(); ++s) {
    md += "\n## " + scenarios[s] + "\n\n";
    md += "| method | pos RMSE (mm) | x EKF | theta RMSE (deg) | mean NEES | NEES in 95 % | steps in band | CRLB | "
          "sqrt(CRLB) pos (mm) | RMSE/sqrt(CRLB) |" +
          std::string(pixel_model ? " RMSE/sqrt(CRLB r-b) |" : "") + "\n";
    md += "|---|---:|---:|---:|---:|---:|---:|---|---:|---:|" + std::string(pixel_model ? "---:|" : "") + "\n";
    const double ekf_rmse = acc[s][ekf].positionRmse();
    for (size_t m = 0; m < methods.size(); ++m) {
      const Accumulator& x = acc[s][m];
      md += "| " + methods[m].label + " | " + num(x.positionRmse(), "%.1f") + " | " +
            num(x.positionRmse() / ekf_rmse, "%.2f") + " | " + num(rad2deg(x.thetaRmse()), "%.2f") + " | " +
            num(x.meanNees(), "%.2f") + " | " + num(x.inInterval(), "%.2f") + " | " + num(x.stepsInBand(), "%.2f") +
            " | " + boundName(methods[m]) + " | " + num(x.sqrtBound(), "%.1f") + " | " +
            num(x.positionRmse() / x.sqrtBound(), "%.2f") + " |" +
            (pixel_model ? " " + num(x.positionRmse() / x.sqrtRangeBearingBound(), "%.2f") + " |" : std::string()) +
            "\n";
    }
  }
  // Averages over the scenarios of the per-scenario figures (each scenario weighs the same).
  std::vector<double> ratio(methods.size(), 0), crlb(methods.size(), 0), nees(methods.size(), 0);
  for (size_t m = 0; m < methods.size(); ++m) {
    for (size_t s = 0; s < scenarios.size(); ++s) {
      ratio[m] += acc[s][m].positionRmse() / acc[s][ekf].positionRmse() / scenarios.size();
      crlb[m] += acc[s][m].positionRmse() / acc[s][m].sqrtBound() / scenarios.size();
      nees[m] += acc[s][m].meanNees() / scenarios.size();
    }
  }
  md += "\n## Mean over the scenarios\n\n";
  md += "| method | pos RMSE x EKF | RMSE/sqrt(CRLB) | mean NEES |\n|---|---:|---:|---:|\n";
  for (size_t m = 0; m < methods.size(); ++m)
    md += "| " + methods[m].label + " | " + num(ratio[m], "%.2f") + " | " + num(crlb[m], "%.2f") + " | " +
          num(nees[m], "%.2f") + " |\n";

  // The accuracy targets of the smoothers (docs/estimators.md).
  md += "\n## Targets\n\n";
  const auto verdict = [](bool ok) { return ok ? "ok" : "MISSED"; };
  md += formatText("- batch position RMSE <= 0.6x EKF, mean over the scenarios: %.2f  %s\n", ratio[0], verdict(ratio[0] <= 0.6));
  for (size_t m = 0; m < methods.size(); ++m)
    if (methods[m].window == 20)
      md += formatText("- window W=20 position RMSE <= 0.8x EKF, mean over the scenarios: %.2f  %s\n", ratio[m],
                verdict(ratio[m] <= 0.8));
  for (size_t s = 0; s < scenarios.size(); ++s) {
    const double n = acc[s][0].meanNees();
    md += formatText("- batch mean NEES inside the 95 %% band of the average of %d runs [%.2f, %.2f], %s: %.2f  %s\n",
              a.trials, band.lo, band.hi, scenarios[s].c_str(), n, verdict(n >= band.lo && n <= band.hi));
  }
  for (size_t s = 0; s < scenarios.size(); ++s) {
    const double r = acc[s][0].positionRmse() / acc[s][0].sqrtBound();
    md += formatText("- batch RMSE/sqrt(CRLB) <= 1.15, %s: %.2f  %s\n", scenarios[s].c_str(), r, verdict(r <= 1.15));
  }
  return md;
}

}  // namespace

std::string runSmootherStudy(const SmootherStudyConfig& a) {
  if (a.trials < 1) throw UsageError("--trials must be at least 1");
  if (a.threads < 0) throw UsageError("--threads must be >= 0");
  if (a.particles < 100) throw UsageError("--particles must be at least 100");
  const std::vector<std::string> scenarios = splitCommaList(a.scenarios);
  if (scenarios.empty()) throw UsageError("--scenarios: no scenario given");
  const std::vector<std::string> drivable = {"circle", "line", "spin", "random-walk"};
  for (const std::string& s : scenarios)
    if (std::find(drivable.begin(), drivable.end(), s) == drivable.end())
      throw UsageError("--scenarios: '" + s +
                       "' is not a drivable scenario without a kidnap (expected circle, line, spin or random-walk; the "
                       "bound needs one continuous true trajectory)");
  const std::vector<int> windows = parseWindows(a.windows);
  std::vector<MethodSpec> methods;
  methods.push_back({"batch", "batch", 0, BoundKind::Smoothing});
  for (int w : windows) methods.push_back({"window W=" + std::to_string(w), "window", w, BoundKind::FixedLag});
  methods.push_back({"ekf", "ekf", 0, BoundKind::Filtering});
  methods.push_back({"pf", "pf", 0, BoundKind::Filtering});
  MethodOptions options;  // known start (section 6.5), no robust loss, gate on
  options.particles = a.particles;
  try {
    options.observation_model = observationModelFromString(a.observation_model);
  } catch (const Error& e) {
    throw UsageError(std::string("--observation-model: ") + e.what());
  }
  try {
    pixelNoiseModelFromString(a.pixel_noise);
  } catch (const Error& e) {
    throw UsageError(std::string("--pixel-noise: ") + e.what());
  }
  const std::string md =
      formatReport(a, scenarios, methods, options, runSmootherTrials(a, scenarios, methods, options));
  if (!a.out_dir.empty()) {
    std::error_code ec;
    std::filesystem::create_directories(a.out_dir, ec);
    if (ec) throw Error(a.out_dir + ": cannot create directory: " + ec.message());
    const std::string path = (std::filesystem::path(a.out_dir) / "smoothers.md").string();
    AtomicOutputFile file(path);
    file.stream() << md;
    file.commit();
  }
  return md;
}

}  // namespace stereoloc
