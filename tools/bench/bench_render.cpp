// Renders one 320x240 stereo pair of the MiroSot field (target: at most 20 ms per pair).
// Run with --benchmark_repetitions=5 and read the medians; compare variants within one run.
#include <benchmark/benchmark.h>

#include "src/sim/renderer.h"

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
BENCHMARK(BM_RenderPair)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(BM_RenderPairOneThread)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(BM_RenderPairOneThreadNoEdgeRefinement)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(BM_RenderPairWithTruth)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(BM_RenderPairObstacles)->Unit(benchmark::kMillisecond)->UseRealTime();

}  // namespace

BENCHMARK_MAIN();
