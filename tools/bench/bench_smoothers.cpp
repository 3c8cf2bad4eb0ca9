// Speed of the smoothers on an in-process random walk (solvers/smoother_common.h: 2D poses,
// odometry, at most 2 range-bearing observations per pose to 10 known landmarks) - the problem
// of the GTSAM 4.3 reference: batch LM on 10,000 poses 2.56 s; BatchFixedLagSmoother
// with lag 20: 1.67 ms median, 3.57 ms p99 per step.
//   BM_SlidingWindowStep/W   one process() call (add, gate, marginalise, solve, covariance);
//                            counters median_ms and p99_ms over all timed steps
//   BM_Batch/N/cov           process() of N steps (with the EKF pass that makes the initial
//                            guess) + finish(); cov = 0: no covariance, 1: chain marginals,
//                            2: ceres::Covariance (SPARSE_QR, O(N^2): 1k only)
//   BM_BatchCeres/N          the same problem solved by ceres::Solver (BatchSolver::Ceres)
// At the end a table prints the medians against the targets (batch with chain covariance:
// 100k <= 2 s, 1M <= 25 s) and the growth exponent of the batch time between 10k and 1M,
// log(t(1M) / t(10k)) / log(100) (target <= 1.1). Wall and CPU time of the benchmark thread:
// on a shared machine the wall time includes the other processes' share of the cores.
#include <benchmark/benchmark.h>
#include <time.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <map>
#include <string>
#include <vector>

#include "solvers/batch_smoother.h"
#include "solvers/sliding_window_smoother.h"
#include "solvers/smoother_common.h"
#include "tools/bench/bench_util.h"

namespace stereoloc {
namespace {

const Eigen::Matrix3d kP0 = Eigen::Vector3d(10.0, 10.0, 0.02).cwiseAbs2().asDiagonal();

using bench::percentile;
using bench::threadCpuMs;

void BM_SlidingWindowStep(benchmark::State& state) {
  SyntheticProblemOptions o;
  o.steps = 5000;
  const SyntheticProblem p = makeRandomWalkProblem(o, 1);
  SlidingWindowConfig c;
  c.window = static_cast<int>(state.range(0));
  c.init = knownBelief(p.truth[0], kP0);
  c.keep_history = false;
  auto win = std::make_unique<SlidingWindowSmoother>(p.map, p.odometry, c);
  size_t k = 0;
  const size_t warmup = static_cast<size_t>(c.window) + 5;
  std::vector<double> ms, cpu;
  for (auto _ : state) {
    if (k == p.steps.size()) {  // start again: a fresh smoother, warmed up outside the timing
      state.PauseTiming();
      win = std::make_unique<SlidingWindowSmoother>(p.map, p.odometry, c);
      for (k = 0; k < warmup; ++k) win->process(p.steps[k]);
      state.ResumeTiming();
    }
    const double c0 = threadCpuMs();
    const auto t0 = std::chrono::steady_clock::now();
    benchmark::DoNotOptimize(win->process(p.steps[k]));
    const double dt = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    if (k >= warmup) {
      ms.push_back(dt);
      cpu.push_back(threadCpuMs() - c0);
    }
    ++k;
  }
  state.counters["median_ms"] = percentile(ms, 0.5);
  state.counters["p99_ms"] = percentile(ms, 0.99);
  state.counters["cpu_median_ms"] = percentile(cpu, 0.5);
  state.counters["cpu_p99_ms"] = percentile(cpu, 0.99);
  state.counters["obs_per_step"] =
      static_cast<double>(win->stats().accepted_observations + win->stats().rejected_observations) /
      static_cast<double>(std::max<long>(1, win->stats().steps));
}
BENCHMARK(BM_SlidingWindowStep)->Arg(5)->Arg(10)->Arg(20)->Arg(50)->Unit(benchmark::kMillisecond)->MinTime(2.0);

void runBatch(benchmark::State& state, const BatchSmootherConfig& config, int steps) {
  SyntheticProblemOptions o;
  o.steps = steps;
  const SyntheticProblem p = makeRandomWalkProblem(o, 2);
  BatchSmootherConfig c = config;
  c.init = knownBelief(p.truth[0], kP0);
  BatchSummary s;
  std::vector<double> cpu;
  for (auto _ : state) {
    const double c0 = threadCpuMs();
    BatchSmoother b(p.map, p.odometry, c);
    for (const Step& st : p.steps) b.process(st);
    benchmark::DoNotOptimize(b.finish());
    cpu.push_back(threadCpuMs() - c0);
    s = b.summary();
  }
  state.counters["cpu_s"] = 1e-3 * percentile(cpu, 0.5);
  state.counters["factors"] = 1 + s.odometry_factors + s.observation_factors;
  state.counters["iterations"] = s.iterations;
  state.counters["solve_s"] = s.solve_seconds;
  state.counters["covariance_s"] = s.covariance_seconds;
  state.counters["filter_s"] = s.filter_seconds;
  state.counters["cut_tests_s"] = s.cut_test_seconds;
  state.counters["cut_tests"] = static_cast<double>(s.cut_steps.size()) + s.withdrawn_cuts;
}

void BM_Batch(benchmark::State& state) {
  BatchSmootherConfig c;
  c.compute_covariance = state.range(1) != 0;
  c.covariance_method = state.range(1) == 2 ? CovarianceMethod::Ceres : CovarianceMethod::Chain;
  runBatch(state, c, static_cast<int>(state.range(0)));
}
BENCHMARK(BM_Batch)
    ->Args({1000, 0})
    ->Args({10000, 0})
    ->Args({100000, 0})
    ->Args({1000, 1})
    ->Args({10000, 1})
    ->Args({100000, 1})
    ->Args({1000, 2})
    ->Unit(benchmark::kMillisecond)
    ->Iterations(3);
// A million steps takes long enough to run once.
BENCHMARK(BM_Batch)->Args({1000000, 1})->Unit(benchmark::kMillisecond)->Iterations(1);

void BM_BatchCeres(benchmark::State& state) {
  BatchSmootherConfig c;
  c.solver = BatchSolver::Ceres;
  runBatch(state, c, static_cast<int>(state.range(0)));
}
BENCHMARK(BM_BatchCeres)->Arg(10000)->Arg(100000)->Unit(benchmark::kMillisecond)->Iterations(1);

// Collects the runs for the summary table printed after the console output.
class SummaryReporter : public benchmark::ConsoleReporter {
 public:
  void ReportRuns(const std::vector<Run>& runs) override {
    ConsoleReporter::ReportRuns(runs);
    for (const Run& r : runs) {
      if (r.run_type != Run::RT_Iteration) continue;
      Row row;
      const double unit = r.time_unit == benchmark::kSecond        ? 1.0
                          : r.time_unit == benchmark::kMillisecond ? 1e-3
                          : r.time_unit == benchmark::kMicrosecond ? 1e-6
                                                                   : 1e-9;
      row.seconds = r.GetAdjustedRealTime() * unit;
      for (const auto& [name, counter] : r.counters) row.counters[name] = counter.value;
      rows_[r.benchmark_name()] = row;
    }
  }
  void Finalize() override {
    ConsoleReporter::Finalize();
    std::printf("\n%-34s %12s %12s %12s %12s %12s %12s\n", "benchmark", "median", "p99", "cpu median",
                "cpu p99", "target", "GTSAM 4.3");
    for (int w : {5, 10, 20, 50}) {
      const auto it = rows_.find("BM_SlidingWindowStep/" + std::to_string(w) + "/min_time:2.000");
      if (it == rows_.end()) continue;
      std::printf("%-34s %9.3f ms %9.3f ms %9.3f ms %9.3f ms %12s %12s\n",
                  ("window W=" + std::to_string(w) + " step").c_str(), it->second.counters["median_ms"],
                  it->second.counters["p99_ms"], it->second.counters["cpu_median_ms"], it->second.counters["cpu_p99_ms"],
                  w == 20 ? "0.5 / 1 ms" : "", w == 20 ? "1.67/3.57 ms" : "");
    }
    std::map<int, double> t, cpu;
    for (int n : {1000, 10000, 100000, 1000000}) {
      const auto it = rows_.find("BM_Batch/" + std::to_string(n) + "/1/iterations:" + (n == 1000000 ? "1" : "3"));
      if (it == rows_.end()) continue;
      t[n] = it->second.seconds;
      cpu[n] = it->second.counters["cpu_s"];
      std::printf("%-34s %10.3f s %10.3f s cpu %12s  (%g iterations, %g cut tests)\n",
                  ("batch " + std::to_string(n) + " steps").c_str(), it->second.seconds, cpu[n],
                  n == 100000 ? "2 s" : n == 1000000 ? "25 s" : "", it->second.counters["iterations"],
                  it->second.counters["cut_tests"]);
    }
    for (int n : {1000, 10000, 100000}) {
      for (int m : {0, 2}) {
        const auto it = rows_.find("BM_Batch/" + std::to_string(n) + "/" + std::to_string(m) + "/iterations:3");
        if (it == rows_.end()) continue;
        std::printf("%-34s %10.3f s %10.3f s cpu (covariance %.3f s)\n",
                    ("batch " + std::to_string(n) + (m == 0 ? " no covariance" : " + ceres::Covariance")).c_str(),
                    it->second.seconds, it->second.counters["cpu_s"], it->second.counters["covariance_s"]);
      }
      const auto it = rows_.find("BM_BatchCeres/" + std::to_string(n) + "/iterations:1");
      if (it != rows_.end())
        std::printf("%-34s %10.3f s %10.3f s cpu\n", ("batch " + std::to_string(n) + " on ceres::Solver").c_str(),
                    it->second.seconds, it->second.counters["cpu_s"]);
    }
    if (t.count(10000) && t.count(1000000))
      std::printf("batch growth exponent (10k -> 1M): wall %.3f, cpu %.3f (target <= 1.1)\n",
                  std::log(t[1000000] / t[10000]) / std::log(100.0), std::log(cpu[1000000] / cpu[10000]) / std::log(100.0));
    else if (t.count(10000) && t.count(100000))
      std::printf("batch growth exponent (10k -> 100k): wall %.3f, cpu %.3f\n", std::log(t[100000] / t[10000]) / std::log(10.0),
                  std::log(cpu[100000] / cpu[10000]) / std::log(10.0));
  }

 private:
  struct Row {
    double seconds = 0;
    std::map<std::string, double> counters;
  };
  std::map<std::string, Row> rows_;
};

}  // namespace
}  // namespace stereoloc

int main(int argc, char** argv) {
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
  stereoloc::SummaryReporter reporter;
  benchmark::RunSpecifiedBenchmarks(&reporter);
  benchmark::Shutdown();
  return 0;
}
