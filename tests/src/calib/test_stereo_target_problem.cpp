#include "src/calib/stereo_target_problem.h"

#include <gtest/gtest.h>

#include <opencv2/calib3d.hpp>
#include <random>

#include "src/core/checker_board.h"
#include "src/core/numeric_diff.h"

namespace stereoloc {
namespace {

// Cameras with a realistic lens and a slightly turned right camera, boards at three poses, and
// the corners as measured (the true projections plus 0.1 px noise).
struct Problem {
  StereoTargetLayout layout;
  StereoTargetParameters truth;
  std::vector<cv::Point3d> object;
  std::vector<std::vector<cv::Point2f>> left, right;
};

Problem makeProblem(int distortion, bool same_focal) {
  Problem P;
  P.layout.distortion = distortion;
  P.layout.same_focal = same_focal;
  P.layout.pairs = 3;
  const double d[8] = {-0.2, 0.05, 0.001, -0.0008, 0.01, 0.002, -0.001, 0.0005};
  for (int c = 0; c < 2; ++c) {
    P.truth.K[c] = (cv::Mat_<double>(3, 3) << 277 + c, 0, 160 - c, 0, same_focal ? 277 + c : 276.5 + c, 119.5, 0, 0, 1);
    P.truth.D[c] = cv::Mat(1, distortion, CV_64F);
    for (int k = 0; k < distortion; ++k) P.truth.D[c].at<double>(0, k) = d[k] * (1 + 0.1 * c);
  }
  P.truth.r = cv::Vec3d(0.002, -0.003, 0.001);
  P.truth.T = cv::Vec3d(-30.0, 0.1, -0.2);
  const CheckerBoard board;
  for (const auto& p : board.corners()) P.object.emplace_back(p.x, p.y, p.z);
  std::mt19937_64 rng(3);
  std::normal_distribution<double> noise(0.0, 0.1);
  for (int v = 0; v < 3; ++v) {
    P.truth.rv.emplace_back(0.3 - 0.25 * v, 0.2 * v - 0.2, 0.1);
    P.truth.tv.emplace_back(-60.0 + 5 * v, -35.0, 280.0 + 30 * v);
    std::vector<cv::Point2d> l, r;
    cv::projectPoints(P.object, P.truth.rv[v], P.truth.tv[v], P.truth.K[0], P.truth.D[0], l);
    cv::Mat r3, t3;
    cv::composeRT(P.truth.rv[v], P.truth.tv[v], P.truth.r, P.truth.T, r3, t3);
    cv::projectPoints(P.object, r3, t3, P.truth.K[1], P.truth.D[1], r);
    std::vector<cv::Point2f> lf, rf;
    for (size_t i = 0; i < l.size(); ++i) {
      lf.emplace_back(static_cast<float>(l[i].x + noise(rng)), static_cast<float>(l[i].y + noise(rng)));
      rf.emplace_back(static_cast<float>(r[i].x + noise(rng)), static_cast<float>(r[i].y + noise(rng)));
    }
    P.left.push_back(lf);
    P.right.push_back(rf);
  }
  return P;
}

class StereoTargetProblemJacobian : public ::testing::TestWithParam<std::tuple<int, bool>> {};

TEST_P(StereoTargetProblemJacobian, MatchesCentralDifferences) {
  const auto [distortion, same_focal] = GetParam();
  const Problem P = makeProblem(distortion, same_focal);
  // Away from the truth, where the residuals are not small.
  Eigen::VectorXd offset(P.layout.size());
  std::mt19937_64 rng(5);
  std::normal_distribution<double> n01(0.0, 1.0);
  for (int k = 0; k < offset.size(); ++k) offset(k) = 1e-3 * n01(rng);
  const StereoTargetParameters x = P.truth.plus(P.layout, offset);
  for (int v = 0; v < P.layout.pairs; ++v) {
    Eigen::VectorXd e, ep, em;
    Eigen::MatrixXd J;
    stereoTargetResiduals(x, P.layout, v, P.object, P.left[v], P.right[v], e, &J);
    ASSERT_EQ(J.rows(), 4 * static_cast<int>(P.object.size()));
    ASSERT_EQ(J.cols(), P.layout.size());
    Eigen::MatrixXd numeric(J.rows(), J.cols());
    for (int k = 0; k < J.cols(); ++k) {
      const double h = 1e-6;
      Eigen::VectorXd dx = Eigen::VectorXd::Zero(J.cols());
      dx(k) = h;
      stereoTargetResiduals(x.plus(P.layout, dx), P.layout, v, P.object, P.left[v], P.right[v], ep, nullptr);
      stereoTargetResiduals(x.plus(P.layout, -dx), P.layout, v, P.object, P.left[v], P.right[v], em, nullptr);
      numeric.col(k) = (ep - em) / (2 * h);
    }
    EXPECT_LT(relativeJacobianError(J, numeric), 1e-6) << "pair " << v;
    // Another pair's board pose does not move this pair's corners.
    for (int w = 0; w < P.layout.pairs; ++w) {
      if (w == v) continue;
      EXPECT_EQ(J.middleCols(P.layout.view(w), 6).cwiseAbs().maxCoeff(), 0.0);
    }
  }
}

INSTANTIATE_TEST_SUITE_P(DistortionModels, StereoTargetProblemJacobian,
                         ::testing::Values(std::make_tuple(4, false), std::make_tuple(5, false),
                                           std::make_tuple(8, false), std::make_tuple(4, true)));

TEST(StereoTargetProblem, ResidualsAreTheMeasurementNoiseAtTheTruth) {
  const Problem P = makeProblem(4, false);
  double sum = 0.0;
  int count = 0;
  for (int v = 0; v < P.layout.pairs; ++v) {
    Eigen::VectorXd e;
    stereoTargetResiduals(P.truth, P.layout, v, P.object, P.left[v], P.right[v], e, nullptr);
    sum += e.squaredNorm();
    count += static_cast<int>(e.size());
  }
  EXPECT_NEAR(std::sqrt(sum / count), 0.1, 0.01);  // the 0.1 px the corners were measured with
}

}  // namespace
}  // namespace stereoloc
