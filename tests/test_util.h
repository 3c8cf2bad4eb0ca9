#pragma once
// Helpers shared by the test programs.
#include <ceres/cost_function.h>
#include <gtest/gtest.h>

#include <Eigen/Core>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <functional>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "src/core/angles.h"
#include "src/core/error.h"
#include "src/core/estimator.h"
#include "src/core/field_map.h"
#include "src/core/numeric_diff.h"
#include "src/io/dataset.h"

namespace stereoloc::test {

// The labelled real photographs and their rig (data/real).
inline const std::string kRealImagesDir = std::string(STEREOLOC_DATA_DIR) + "/real";

// The whole file, byte for byte ("" when it cannot be read).
inline std::string readFile(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

// A fresh empty directory under the system temp dir, removed at scope exit.
class TempDir {
 public:
  explicit TempDir(const std::string& tag = "stereoloc") {
    std::random_device rd;
    path_ = std::filesystem::temp_directory_path() / (tag + "_" + std::to_string(rd()) + std::to_string(rd()));
    std::filesystem::create_directories(path_);
  }
  ~TempDir() {
    std::error_code ec;
    std::filesystem::remove_all(path_, ec);
  }
  std::string path() const { return path_.string(); }
  std::string file(const std::string& name) const { return (path_ / name).string(); }

 private:
  std::filesystem::path path_;
};

// The message of the stereoloc::Error that f throws; empty when it throws none.
inline std::string errorOf(const std::function<void()>& f) {
  try {
    f();
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

// Drops every sighting that needs association (landmark_id -1): the runs whose estimators
// should see identified landmarks only.
inline void keepIdentifiedSightings(Dataset& d) {
  for (Step& s : d.steps) {
    std::vector<Observation> kept;
    for (const Observation& o : s.observations)
      if (o.landmark_id >= 0) kept.push_back(o);
    s.observations = kept;
  }
}

// A simulated run: the steps an estimator is fed and the true pose at each.
struct SyntheticRun {
  std::vector<Step> steps;
  std::vector<Pose2> truth;
};

// The residuals of `cost` at the parameter blocks `blocks` (the evaluation must succeed).
inline Eigen::VectorXd evaluateResiduals(const ceres::CostFunction& cost, const std::vector<const double*>& blocks) {
  Eigen::VectorXd r(cost.num_residuals());
  EXPECT_TRUE(cost.Evaluate(blocks.data(), r.data(), nullptr));
  return r;
}

// Root mean square of the position errors (mm) of estimates against the true poses, index by index.
inline double positionRmse(const std::vector<Estimate>& estimates, const std::vector<Pose2>& truth) {
  double s = 0;
  for (size_t i = 0; i < estimates.size(); ++i)
    s += (estimates[i].pose.translation() - truth[i].translation()).squaredNorm();
  return std::sqrt(s / static_cast<double>(estimates.size()));
}

// Position RMSE (mm) of estimates of a dataset's steps 0..n-1 against its ground truth, which
// every one of those steps must have.
inline double positionRmse(const std::vector<Estimate>& estimates, const Dataset& d) {
  double s = 0;
  for (size_t k = 0; k < estimates.size(); ++k)
    s += (estimates[k].pose.translation() - d.groundtruth.at(k).value().translation()).squaredNorm();
  return std::sqrt(s / static_cast<double>(estimates.size()));
}

// The thesis's random start made ambiguous (section 6.5): a compass reading with 3.5 degrees of
// noise at every step (noise drawn from `seed`), and every sighting of a landmark that is not
// unique on the map unidentified.
inline void ambiguousSightingsWithCompass(std::vector<Step>& steps, const std::vector<Pose2>& truth, const FieldMap& map,
                                          uint64_t seed) {
  std::mt19937_64 noise(seed);
  std::normal_distribution<double> n01(0.0, 1.0);
  for (size_t k = 0; k < steps.size(); ++k) {
    Step& s = steps[k];
    s.compass = wrapAngle(truth[k].theta + deg2rad(3.5) * n01(noise));
    s.compass_sigma = deg2rad(3.5);
    for (Observation& o : s.observations)
      if (!map.at(o.landmark_id).unique) o.landmark_id = -1;
  }
}

// Runs `estimator` over `steps`, every estimate finite, and returns the mean position error
// (mm) against `truth` over steps first sighting + 1 .. 79: Table 6.14's window.
inline double table614WindowMean(Estimator& estimator, const std::vector<Step>& steps, const std::vector<Pose2>& truth) {
  double sum = 0;
  int n = 0, first = -1;
  for (const Step& s : steps) {
    const Estimate e = estimator.process(s);
    EXPECT_TRUE(e.pose.isFinite() && e.covariance.allFinite());
    if (first < 0 && !s.observations.empty()) first = static_cast<int>(s.step);
    if (first >= 0 && s.step > first && s.step <= 79) {
      sum += (e.pose.translation() - truth[static_cast<size_t>(s.step)].translation()).norm();
      ++n;
    }
  }
  EXPECT_GT(n, 0);
  return n > 0 ? sum / n : 0.0;
}

// Runs `kept` and `newest` (the same filter, `newest` without history) over `steps`: the same
// estimates at every step, and finish() holds them all for `kept`, the newest alone for `newest`.
inline void expectOnlyTheNewestIsKept(Estimator& kept, Estimator& newest, const std::vector<Step>& steps) {
  for (const Step& s : steps) {
    const Estimate a = kept.process(s), b = newest.process(s);
    ASSERT_EQ(a.pose.x, b.pose.x) << "step " << s.step;
    ASSERT_EQ(a.covariance, b.covariance) << "step " << s.step;
  }
  const std::vector<Estimate> all = kept.finish(), last = newest.finish();
  EXPECT_EQ(all.size(), steps.size());
  ASSERT_EQ(last.size(), 1u);
  EXPECT_EQ(last[0].step, steps.back().step);
  EXPECT_EQ(last[0].pose.y, all.back().pose.y);
}

// Fails the test (with both matrices printed) when an analytic Jacobian differs from the
// numeric one by more than `tol` relative to max(1, |J|).
template <typename A, typename B>
::testing::AssertionResult jacobianMatches(const A& analytic, const B& numeric, double tol = 1e-6) {
  const double err = relativeJacobianError(analytic, numeric);
  if (err <= tol) return ::testing::AssertionSuccess();
  return ::testing::AssertionFailure() << "relative Jacobian error " << err << " > " << tol << "\nanalytic:\n"
                                       << analytic << "\nnumeric:\n"
                                       << numeric;
}

}  // namespace stereoloc::test
