// Renders one 320x240 stereo pair of the MiroSot field (target: at most 20 ms per pair).
// Run with --benchmark_repetitions=5 and read the medians; compare variants within one run.
//
//   BM_RenderPair*        the ideal pair at one pose (threads, truth, obstacles, edge refinement)
//   BM_StudyPairIdeal     the ideal pair as the studies render it (one thread, no truth), over
//                         the steps of one realistic circle trial
//   BM_StudyPairRealistic the raw pair of the realistic world (src/sim/raw_render.h) on the same
//                         steps: true cameras, motion blur, exposure offset, sensor noise
// "CPU" is the CPU time of the whole process (all threads).
#include <benchmark/benchmark.h>

#include "src/sim/raw_render.h"
#include "src/sim/renderer.h"
#include "src/sim/simulator.h"

namespace {

using namespace stereoloc;

void renderPair(benchmark::State& state, int threads, bool truth, int obstacles, int edge_samples = RenderOptions().edge_samples_per_axis) {
  RenderOptions o;
  o.edge_samples_per_axis = edge_samples;
  o.threads = threads;
  o.compute_truth = truth;
  const FieldMap map = FieldMap::miroSot();
  const StereoRenderer renderer(map, StereoRig(), o);
  std::vector<Obstacle> obs;
  for (int k = 0; k < obstacles; ++k) {
    Obstacle ob;
    ob.position = Eigen::Vector2d(300 + 150 * k, 500 + 40 * k);
    obs.push_back(ob);
  }
  const Pose2 pose(900, 600, 2.8);  // looking at the blue goal across the centre circle
  for (auto _ : state) {
    StereoImages im = renderer.render(pose, 0.0, obs);
    benchmark::DoNotOptimize(im.left.data);
  }
}

void BM_RenderPair(benchmark::State& s) { renderPair(s, 2, false, 0); }
void BM_RenderPairOneThread(benchmark::State& s) { renderPair(s, 1, false, 0); }
// The same without the edge-pixel refinement (2 x 2 samples everywhere): its cost, same run.
void BM_RenderPairOneThreadNoEdgeRefinement(benchmark::State& s) { renderPair(s, 1, false, 0, 0); }
void BM_RenderPairWithTruth(benchmark::State& s) { renderPair(s, 2, true, 0); }
void BM_RenderPairObstacles(benchmark::State& s) { renderPair(s, 2, false, 5); }
// One realistic circle trial (its drawn errors and its path); the benchmarks cycle over its steps.
struct StudyTrial {
  Dataset dataset;
  SimulationTrace trace;
  StudyTrial() {
    SimulationConfig cfg;
    cfg.profile = ErrorProfile::named("realistic");
    dataset = simulate("circle", 0, cfg, 7, &trace);
  }
};

const StudyTrial& studyTrial() {
  static const StudyTrial t;
  return t;
}

RenderOptions studyOptions() {
  RenderOptions o;
  o.compute_truth = false;
  o.threads = 1;
  o.noise_sigma = 1.5;
  return o;
}

void BM_StudyPairIdeal(benchmark::State& state) {
  const StudyTrial& t = studyTrial();
  const StereoRenderer renderer(t.dataset.map, StereoRig(t.trace.nominal_rig), studyOptions());
  size_t s = 0;
  for (auto _ : state) {
    StereoImages im = renderer.render(t.trace.scenario.poses[s], t.trace.scenario.head_pan[s], t.trace.obstacles[s], s);
    benchmark::DoNotOptimize(im.left.data);
    s = (s + 1) % t.trace.scenario.poses.size();
  }
}

void BM_StudyPairRealistic(benchmark::State& state) {
  const StudyTrial& t = studyTrial();
  const RawPairRenderer raw(t.dataset.map, t.trace.nominal_rig, t.trace.profile, t.trace.errors, studyOptions(),
                            t.trace.scenario.dt);
  size_t s = 0;
  for (auto _ : state) {
    StereoImages im = raw.render(t.trace.scenario, s, t.trace.obstacles[s], s);
    benchmark::DoNotOptimize(im.left.data);
    s = (s + 1) % t.trace.scenario.poses.size();
  }
}

BENCHMARK(BM_RenderPair)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(BM_RenderPairOneThread)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(BM_RenderPairOneThreadNoEdgeRefinement)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(BM_RenderPairWithTruth)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(BM_RenderPairObstacles)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(BM_StudyPairIdeal)->Unit(benchmark::kMillisecond)->MeasureProcessCPUTime()->UseRealTime();
BENCHMARK(BM_StudyPairRealistic)->Unit(benchmark::kMillisecond)->MeasureProcessCPUTime()->UseRealTime();

}  // namespace

BENCHMARK_MAIN();
