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

// The same along the path of `line` (3 passes): the consecutive views of one landmark that the
// model's column sigma is set for (docs/estimators.md, "Observation covariance").
const std::vector<PixelErrorSample>& pathSample() {
  static const std::vector<PixelErrorSample> s = [] {
    const Dataset d = simulate("line", 0, SimulationConfig(), 1);
    PixelNoiseOptions o;
    o.pairs = 3;
    o.seed = 7;
    for (const auto& g : d.groundtruth)
      if (g) o.poses.push_back(*g);
    return measurePixelErrors(d.map, d.rig, frontend::FrontendParams(), o);
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
  auto path_by_type = samplesByType(pathSample());
  int checked = 0, checked_on_path = 0;
  const Eigen::Vector4d disparity(1, 0, -1, 0), column(0.5, 0, 0.5, 0);
  for (const auto& [type, s] : by_type) {
    if (s.size() < 40) continue;
    ++checked;
    const Eigen::Matrix4d C = params.stereo.pixelCovariance(type);
    // Disparity (range): at least as wide as measured, at most 10x in sigma.
    const double d_ratio = disparity.dot(C * disparity) / meanSquare(s, disparity);
    EXPECT_GT(d_ratio, 1.0) << toString(type) << " n=" << s.size();
    EXPECT_LT(d_ratio, 100.0) << toString(type) << " n=" << s.size();
    // Left and right columns of a marking feature share most of their error (measured
    // correlation above 0.9): the model's correlation is positive and not above the measured one.
    if (type != LandmarkType::GoalCorner) {
      const double measured = meanSquare(s, Eigen::Vector4d(1, 0, 1, 0)) - meanSquare(s, disparity);  // 4 E[u_l u_r]
      const double corr_measured =
          0.25 * measured / std::sqrt(meanSquare(s, Eigen::Vector4d(1, 0, 0, 0)) * meanSquare(s, Eigen::Vector4d(0, 0, 1, 0)));
      const double corr_model = C(0, 2) / std::sqrt(C(0, 0) * C(2, 2));
      EXPECT_GT(corr_measured, 0.8) << toString(type);
      EXPECT_GT(corr_model, 0.5) << toString(type);
      EXPECT_LE(corr_model, corr_measured) << toString(type);
    }
    // Mean column (bearing): at least as wide as measured over random views; the model adds
    // the error that repeats over consecutive views, so at most 3.2x in sigma what the views
    // along a path show.
    const double c_ratio = column.dot(C * column) / meanSquare(s, column);
    EXPECT_GT(c_ratio, 1.0) << toString(type) << " n=" << s.size();
    const auto& path = path_by_type[type];
    if (path.size() < 20) continue;
    ++checked_on_path;
    const double c_ratio_path = column.dot(C * column) / meanSquare(path, column);
    EXPECT_LT(c_ratio_path, 10.0) << toString(type) << " n=" << path.size() << " on the path";
  }
  EXPECT_GE(checked, 2);
  EXPECT_GE(checked_on_path, 2);
}

}  // namespace
}  // namespace stereoloc
