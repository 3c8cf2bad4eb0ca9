// The batch smoother's NEES on `line` with the image frontend: consistent with the frontend's
// pixel covariance (docs/estimators.md, "Observation covariance"). Six trials of the study's
// own data (rendered pairs, sensor noise, default frontend); about 12 s of CPU, the price of
// rendering and running the frontend on 600 pairs, the only way to test the covariance end to end.
#include <gtest/gtest.h>

#include "src/eval/evaluation.h"
#include "src/pipeline/frontend_source.h"
#include "src/pipeline/methods.h"
#include "src/study/study.h"
#include "src/study/study_trial.h"

namespace stereoloc {
namespace {

TEST(LineConsistency, BatchNeesWithTheImageFrontendIsNearThree) {
  const StudyConfig c;
  const std::string scenario = "line";
  double sum = 0;
  long n = 0;
  for (int t = 0; t < 6; ++t) {
    SimulationTrace trace;
    const uint64_t seed = trialSeed(c.seed, scenario, t);
    Dataset d = simulate(scenario, study::thesisTrial(scenario, t), SimulationConfig(), seed, &trace);
    RenderOptions ro;
    ro.compute_truth = false;
    ro.threads = 1;
    const StereoRenderer renderer(d.map, d.rig, ro);
    observeRenderedImages(d, trace, renderer, c.image_noise,
                          study::splitmix64(seed ^ study::hashString("images")));
    const MethodRun run = runMethod("batch", d, study::methodSeed(c, scenario, t, "batch"), c.method_options);
    for (const PoseError& e : poseErrors(run.estimates, truthByStep(d.steps, d.groundtruth)))
      if (e.nees) {
        sum += *e.nees;
        ++n;
      }
  }
  ASSERT_GT(n, 500);
  // Mean of 6 trials: per-trial means scatter by about 1, so the mean of 6 by about 0.4.
  const double mean = sum / static_cast<double>(n);
  EXPECT_GT(mean, 2.0);
  EXPECT_LT(mean, 4.2);
}

}  // namespace
}  // namespace stereoloc
