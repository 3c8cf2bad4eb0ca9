// Speed of the recursive filters on the in-process random walk of
// solvers/smoother_common.h (at most 2 range-bearing observations per step, 10 landmarks):
//   BM_EkfPredictUpdate    predict + 2 range-bearing updates on a fixed belief (target <= 2 us)
//   BM_EkfStep             Ekf::process() of the walk's steps (gate, association check, bookkeeping)
//   BM_PfStep/N            ParticleFilter::process() with N particles (target <= 1 ms at 3000):
//                          linearised optimal proposal, estimate, systematic resampling, re-injection
//   BM_PfStepRoulette/N    the same with the thesis's sorted roulette
//   BM_PfStepUnregularised/N  the same without the regularisation after resampling (Algorithm 6
//                          as printed), for the cost of the regularisation in the same run
//   BM_PfStepPriorProposal/N  the odometry model as proposal (Algorithm 6), for the cost of the
//                          optimal proposal in the same run
//   BM_PfStepSelfCalibrating/N  the self-calibrating filter (odometry and stereo, pf:calib) on a
//                          simulated random walk whose sightings carry pixels (up to 4 per step)
//   BM_PfStepOnPixels/N    the plain filter on the same walk, for the calibration's cost
//   BM_HypothesisSpawn     the random start's multi-hypothesis bank (solvers/global_fix_hypotheses.h)
//                          spawned from a step with three unidentified sightings and the compass on
//                          the MiroSot field (one-landmark fixes over every landmark of each type)
//   BM_HypothesisStep      one step of a bank holding one hypothesis per marking corner (a single
//                          unidentified sighting, still ambiguous): what a wide filter pays per step
// At the end a table prints the per-step times against the targets and the PF/EKF ratio (the
// thesis claims the EKF is at least 10x cheaper than MCL).
#include <benchmark/benchmark.h>

#include <algorithm>
#include <cstdio>
#include <map>
#include <memory>
#include <string>

#include "solvers/ekf.h"
#include "solvers/global_fix_hypotheses.h"
#include "solvers/particle_filter.h"
#include "solvers/smoother_common.h"
#include "src/core/measurement_model.h"
#include "src/sim/simulator.h"

namespace stereoloc {
namespace {

const Eigen::Matrix3d kP0 = Eigen::Vector3d(30.0, 30.0, 0.05).cwiseAbs2().asDiagonal();

const SyntheticProblem& problem() {
  static const SyntheticProblem p = [] {
    SyntheticProblemOptions o;
    o.steps = 2000;
    return makeRandomWalkProblem(o, 7);
  }();
  return p;
}

void BM_EkfPredictUpdate(benchmark::State& state) {
  const SyntheticProblem& p = problem();
  EkfConfig c;
  c.init = knownBelief(p.truth[10], kP0);
  Ekf ekf(p.map, p.odometry, c);
  // Two landmarks ahead of the pose, observed without noise: the belief stays put when reset.
  const Pose2 pose = p.truth[10];
  const Eigen::Vector2d l1 = transformToWorld(pose, Eigen::Vector2d(500.0, 150.0));
  const Eigen::Vector2d l2 = transformToWorld(pose, Eigen::Vector2d(700.0, -250.0));
  auto observe = [&](const Eigen::Vector2d& l) {
    const Eigen::Vector2d z = predictRangeBearing(pose, l);
    return observationFromRangeBearing(0, LandmarkType::Point, z.x() + 5.0, z.y() + 0.01, 15.0, 0.02);
  };
  const Observation o1 = observe(l1), o2 = observe(l2);
  for (auto _ : state) {
    ekf.reset(pose, kP0);
    ekf.predict(20.0, 22.0);
    benchmark::DoNotOptimize(ekf.updateRangeBearing(o1, l1));
    benchmark::DoNotOptimize(ekf.updateRangeBearing(o2, l2));
    benchmark::DoNotOptimize(ekf.covariance().data());
  }
}
BENCHMARK(BM_EkfPredictUpdate);

// Filter::process() over `steps`, a fresh filter (built outside the timing) for every pass.
template <typename Filter, typename Make>
void runSteps(benchmark::State& state, const std::vector<Step>& steps, Make make) {
  std::unique_ptr<Filter> f = make();
  size_t k = 0;
  for (auto _ : state) {
    if (k == steps.size()) {
      state.PauseTiming();
      f = make();
      k = 0;
      state.ResumeTiming();
    }
    benchmark::DoNotOptimize(f->process(steps[k++]));
  }
  state.SetItemsProcessed(state.iterations());
}

void BM_EkfStep(benchmark::State& state) {
  const SyntheticProblem& p = problem();
  EkfConfig c;
  c.init = knownBelief(p.truth[0], kP0);
  runSteps<Ekf>(state, p.steps, [&] { return std::make_unique<Ekf>(p.map, p.odometry, c); });
}
BENCHMARK(BM_EkfStep);

void pfStep(benchmark::State& state, ResamplingScheme scheme, double bandwidth = -1.0,
            ParticleProposal proposal = ParticleProposal::LinearisedOptimal) {
  const SyntheticProblem& p = problem();
  ParticleFilterConfig c;
  c.init = knownBelief(p.truth[0], kP0);
  c.particles = static_cast<int>(state.range(0));
  c.reinjected = std::min(c.reinjected, c.particles / 10);
  c.resampling = scheme;
  c.regularisation_bandwidth = bandwidth;
  c.proposal = proposal;
  uint64_t seed = 1;
  runSteps<ParticleFilter>(state, p.steps,
                           [&] { return std::make_unique<ParticleFilter>(p.map, p.odometry, c, seed++); });
}
void BM_PfStep(benchmark::State& state) { pfStep(state, ResamplingScheme::Systematic); }
void BM_PfStepRoulette(benchmark::State& state) { pfStep(state, ResamplingScheme::SortedRoulette); }
void BM_PfStepUnregularised(benchmark::State& state) { pfStep(state, ResamplingScheme::Systematic, 0.0); }
void BM_PfStepPriorProposal(benchmark::State& state) {
  pfStep(state, ResamplingScheme::Systematic, -1.0, ParticleProposal::Prior);
}
BENCHMARK(BM_PfStep)->Arg(1000)->Arg(3000)->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_PfStepRoulette)->Arg(3000)->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_PfStepUnregularised)->Arg(3000)->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_PfStepPriorProposal)->Arg(3000)->Unit(benchmark::kMicrosecond);

// A simulated random walk whose sightings carry their pixels, the stereo block's input.
const Dataset& pixelWalk() {
  static const Dataset d = [] {
    SimulationConfig sc;
    sc.scenario.steps = 600;
    return simulate("random-walk", 0, sc, 5);
  }();
  return d;
}

void pfOnPixels(benchmark::State& state, const std::string& calibrate) {
  const Dataset& d = pixelWalk();
  ParticleFilterConfig c;
  c.init = knownBelief(*d.groundtruth.front(), kP0);
  c.particles = static_cast<int>(state.range(0));
  c.calibration = SelfCalibrationConfig::parse(calibrate);
  c.observation_model.rig = d.rig;
  uint64_t seed = 1;
  runSteps<ParticleFilter>(state, d.steps,
                           [&] { return std::make_unique<ParticleFilter>(d.map, d.odometry, c, seed++); });
}
void BM_PfStepSelfCalibrating(benchmark::State& state) { pfOnPixels(state, "odometry,stereo"); }
void BM_PfStepOnPixels(benchmark::State& state) { pfOnPixels(state, ""); }
BENCHMARK(BM_PfStepSelfCalibrating)->Arg(3000)->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_PfStepOnPixels)->Arg(3000)->Unit(benchmark::kMicrosecond);

// Unidentified sightings of the given MiroSot landmarks from `pose`, with an exact compass.
Step ambiguousStep(const FieldMap& map, const Pose2& pose, const std::vector<int>& ids) {
  Step s;
  s.compass = pose.theta;
  s.compass_sigma = deg2rad(3.5);
  for (int id : ids) {
    const Eigen::Vector2d z = predictRangeBearing(pose, map.at(id).xy());
    s.observations.push_back(observationFromRangeBearing(-1, map.at(id).type, z.x(), z.y(), 10.0, 0.002));
  }
  return s;
}

void BM_HypothesisSpawn(benchmark::State& state) {
  const FieldMap map = FieldMap::miroSot();
  HypothesisBank bank(map, OdometryParams());
  const Step s = ambiguousStep(map, Pose2(950.0, 650.0, 0.3), {9, 11, 17});
  for (auto _ : state) {
    bank.clear();
    bank.process(s, true);
    benchmark::DoNotOptimize(bank.hypotheses().data());
  }
  state.counters["hypotheses"] = static_cast<double>(bank.hypotheses().size());
}
BENCHMARK(BM_HypothesisSpawn)->Unit(benchmark::kMicrosecond);

void BM_HypothesisStep(benchmark::State& state) {
  const FieldMap map = FieldMap::miroSot();
  HypothesisBank bank(map, OdometryParams());
  Step s = ambiguousStep(map, Pose2(800.0, 1200.0, 0.3), {9});
  bank.process(s, true);
  s.step = 1;  // standing still: every hypothesis explains the sighting again
  for (auto _ : state) {
    bank.process(s, false);
    benchmark::DoNotOptimize(bank.hypotheses().data());
  }
  state.counters["hypotheses"] = static_cast<double>(bank.hypotheses().size());
}
BENCHMARK(BM_HypothesisStep)->Unit(benchmark::kMicrosecond);

// Collects the mean wall and CPU time per iteration (ns) of every run for the summary table.
// CPU time is the figure to compare with the targets on a shared machine (wall time includes
// waiting for the core).
class SummaryReporter : public benchmark::ConsoleReporter {
 public:
  void ReportRuns(const std::vector<Run>& runs) override {
    for (const Run& r : runs)
      if (r.run_type == Run::RT_Iteration && r.iterations > 0) {
        ns_[r.benchmark_name()] = r.real_accumulated_time * 1e9 / static_cast<double>(r.iterations);
        cpu_ns_[r.benchmark_name()] = r.cpu_accumulated_time * 1e9 / static_cast<double>(r.iterations);
      }
    ConsoleReporter::ReportRuns(runs);
  }
  double ns(const std::string& name) const { return find(ns_, name); }
  double cpuNs(const std::string& name) const { return find(cpu_ns_, name); }

 private:
  static double find(const std::map<std::string, double>& m, const std::string& name) {
    const auto it = m.find(name);
    return it == m.end() ? -1.0 : it->second;
  }
  std::map<std::string, double> ns_, cpu_ns_;
};

}  // namespace
}  // namespace stereoloc

int main(int argc, char** argv) {
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
  stereoloc::SummaryReporter reporter;
  benchmark::RunSpecifiedBenchmarks(&reporter);
  std::printf("\nsummary (mean time per step: CPU, and wall in brackets)\n");
  auto line = [&](const char* what, const std::string& name, double target_ns, const char* target) {
    const double cpu = reporter.cpuNs(name), wall = reporter.ns(name);
    if (cpu < 0) return;
    std::printf("  %-28s %10.3f us  (%10.3f us)", what, cpu / 1e3, wall / 1e3);
    if (target_ns > 0) std::printf("   target %-9s %s", target, cpu <= target_ns ? "ok" : "MISSED");
    std::printf("\n");
  };
  line("EKF predict + 2 updates", "BM_EkfPredictUpdate", 2000.0, "<= 2 us");
  line("EKF process() step", "BM_EkfStep", -1, "");
  line("PF 1000 particles step", "BM_PfStep/1000", -1, "");
  line("PF 3000 particles step", "BM_PfStep/3000", 1e6, "<= 1 ms");
  line("PF 3000 sorted roulette", "BM_PfStepRoulette/3000", -1, "");
  line("PF 3000 without regularisation", "BM_PfStepUnregularised/3000", -1, "");
  line("PF 3000 prior (Algorithm 6)", "BM_PfStepPriorProposal/3000", -1, "");
  line("PF 3000 on pixels", "BM_PfStepOnPixels/3000", -1, "");
  line("PF 3000 self-calibrating", "BM_PfStepSelfCalibrating/3000", -1, "");
  line("random start: bank spawn", "BM_HypothesisSpawn", -1, "");
  line("random start: bank step", "BM_HypothesisStep", -1, "");
  const double pf = reporter.cpuNs("BM_PfStep/3000"), ekf_step = reporter.cpuNs("BM_EkfStep");
  if (pf > 0 && ekf_step > 0)
    std::printf("  ratio PF(3000) / EKF process() step: %.0f x (CPU; thesis: the EKF is at least 10x cheaper)\n",
                pf / ekf_step);
  benchmark::Shutdown();
  return 0;
}
