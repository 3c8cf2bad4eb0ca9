// The frontend's pixel covariance model against a Monte Carlo of its errors on rendered pairs.
#include <gtest/gtest.h>

#include <cmath>

#include "frontend/frontend.h"
#include "src/pipeline/pixel_noise.h"
#include "src/sim/simulator.h"

namespace stereoloc {
namespace {

struct Sample {
  FieldMap map;
  StereoRig rig;
  std::vector<PixelErrorSample> errors;
};

const Sample& sample() {
  static const Sample s = [] {
    const Dataset d = simulate("line", 0, SimulationConfig(), 1);
    PixelNoiseOptions o;
    o.pairs = 120;
    o.seed = 7;
    return Sample{d.map, d.rig, measurePixelErrors(d.map, d.rig, frontend::FrontendParams(), o)};
  }();
  return s;
}

// Mean square of a linear combination w of the pixel errors (w^T e)^2, and the model's w^T C w.
double meanSquare(const std::vector<PixelErrorSample>& s, const Eigen::Vector4d& w) {
  double sum = 0;
  for (const PixelErrorSample& e : s) sum += w.dot(e.error) * w.dot(e.error);
  return sum / static_cast<double>(s.size());
}

TEST(PixelNoise, SamplesMatchTheirLandmarksClosely) {
  const auto& s = sample().errors;
  ASSERT_GT(s.size(), 100u);
  for (const PixelErrorSample& e : s) {
    EXPECT_LE(std::hypot(e.error[0], e.error[1]), 2.0);
    EXPECT_GT(e.range_mm, 0.0);
  }
}

TEST(PixelNoise, ModelCovarianceMatchesTheFrontendsErrors) {
  const frontend::FrontendParams params;
  const auto by_type = samplesByType(sample().errors);
  int checked = 0;
  const Eigen::Vector4d disparity(1, 0, -1, 0), column(0.5, 0, 0.5, 0);
  for (const auto& [type, s] : by_type) {
    if (s.size() < 40) continue;
    ++checked;
    const Eigen::Matrix4d C = params.stereo.pixelCovariance(type);
    // Disparity (range): the model's variance is the measured one (heavy-tailed errors and a
    // few dozen samples: within a factor 4).
    const double d_ratio = meanSquare(s, disparity) / disparity.dot(C * disparity);
    EXPECT_GT(d_ratio, 0.25) << toString(type) << " n=" << s.size();
    EXPECT_LT(d_ratio, 4.0) << toString(type) << " n=" << s.size();
    // Mean column (bearing): at least as wide as measured (the model adds the error that
    // repeats over consecutive views, docs/estimators.md), at most 2.5x in sigma.
    const double c_ratio = column.dot(C * column) / meanSquare(s, column);
    EXPECT_GT(c_ratio, 1.0) << toString(type) << " n=" << s.size();
    EXPECT_LT(c_ratio, 6.25) << toString(type) << " n=" << s.size();
  }
  EXPECT_GE(checked, 2);
}

}  // namespace
}  // namespace stereoloc
