// The frontend's pixel covariance model against a Monte Carlo of its errors on rendered pairs.
#include <gtest/gtest.h>

#include <Eigen/LU>
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

// Mean of e^T C^-1 e over the (u_l, u_r) block, the data the range-bearing form and the
// pixel-column factors use: 2 for a model that matches the errors' second moments.
double meanMahalanobisColumns(const std::vector<PixelErrorSample>& s, const Eigen::Matrix4d& C) {
  Eigen::Matrix2d C2;
  C2 << C(0, 0), C(0, 2), C(2, 0), C(2, 2);
  const Eigen::Matrix2d I = C2.inverse();
  double sum = 0;
  for (const PixelErrorSample& e : s) {
    const Eigen::Vector2d x(e.error[0], e.error[2]);
    sum += x.dot(I * x);
  }
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
  for (const auto& [type, s] : by_type) {
    if (s.size() < 40) continue;
    ++checked;
    const Eigen::Matrix4d C = params.stereo.pixelCovariance(type);
    const double m = meanMahalanobisColumns(s, C);
    // The mean of n chi-square(2) values has standard deviation 2 / sqrt(n); the frontend's
    // errors have heavier tails, so the band is wider than that.
    EXPECT_GT(m, 1.2) << toString(type) << " n=" << s.size();
    EXPECT_LT(m, 3.0) << toString(type) << " n=" << s.size();
    // The disparity direction on its own: its variance within a factor 2.5 of the model's.
    double sd2 = 0;
    for (const PixelErrorSample& e : s) sd2 += (e.error[0] - e.error[2]) * (e.error[0] - e.error[2]);
    sd2 /= static_cast<double>(s.size());
    const double model_d2 = C(0, 0) - 2 * C(0, 2) + C(2, 2);
    EXPECT_GT(sd2 / model_d2, 1.0 / 2.5) << toString(type);
    EXPECT_LT(sd2 / model_d2, 2.5) << toString(type);
  }
  EXPECT_GE(checked, 2);
}

}  // namespace
}  // namespace stereoloc
