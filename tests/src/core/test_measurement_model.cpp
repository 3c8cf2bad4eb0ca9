#include <gtest/gtest.h>

#include <ceres/jet.h>
#include <random>

#include "src/core/error.h"
#include "src/core/measurement_model.h"
#include "src/core/numeric_diff.h"
#include "test_util.h"

namespace stereoloc {

TEST(MeasurementModel, PredictionMatchesThesis527) {
  const Pose2 p(100, 100, kPi / 2);
  const Eigen::Vector2d z = predictRangeBearing(p, Eigen::Vector2d(100, 400));
  EXPECT_NEAR(z.x(), 300, 1e-12);
  EXPECT_NEAR(z.y(), 0, 1e-12);
  const Eigen::Vector2d left = predictRangeBearing(Pose2(0, 0, 0), Eigen::Vector2d(0, 50));
  EXPECT_NEAR(left.y(), kPi / 2, 1e-12);
}

TEST(MeasurementModel, JacobianIncludingBearingsNearPi) {
  std::mt19937_64 rng(21);
  std::uniform_real_distribution<double> U(-1, 1);
  auto wrapMinus = [](const Eigen::Vector2d& a, const Eigen::Vector2d& b) { return rangeBearingInnovation(a, b); };
  for (int i = 0; i < 300; ++i) {
    Pose2 p(700 * U(rng), 700 * U(rng), kPi * U(rng));
    Eigen::Vector2d lm(700 * U(rng), 700 * U(rng));
    if (i % 2 == 0) {  // landmark straight behind: bearing at +-pi
      lm = transformToWorld(p, Eigen::Vector2d(-300 - 200 * U(rng), 1e-7 * U(rng)));
    }
    Matrix23d J;
    predictRangeBearing(p, lm, &J);
    auto h = [&](const Eigen::Vector3d& v) { return predictRangeBearing(Pose2(v(0), v(1), v(2)), lm); };
    EXPECT_TRUE(test::jacobianMatches(J, numericJacobian<2, 3>(h, p.vector(), wrapMinus)));
  }
}

TEST(MeasurementModel, TemplatedFormAgreesAndDifferentiates) {
  const double pose[3] = {10, -20, 0.3}, lm[2] = {400, 250};
  double z[2];
  predictRangeBearingT(pose, lm, z);
  const Eigen::Vector2d ref = predictRangeBearing(Pose2(10, -20, 0.3), Eigen::Vector2d(400, 250));
  EXPECT_NEAR(z[0], ref.x(), 1e-12);
  EXPECT_NEAR(z[1], ref.y(), 1e-12);
  using Jet = ceres::Jet<double, 3>;
  const Jet pj[3] = {Jet(10, 0), Jet(-20, 1), Jet(0.3, 2)}, lj[2] = {Jet(400), Jet(250)};
  Jet zj[2];
  predictRangeBearingT(pj, lj, zj);
  Matrix23d J;
  predictRangeBearing(Pose2(10, -20, 0.3), Eigen::Vector2d(400, 250), &J);
  for (int r = 0; r < 2; ++r)
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(zj[r].v[c], J(r, c), 1e-12);
}

TEST(MeasurementModel, InnovationWrapsAndDegenerateThrows) {
  const Eigen::Vector2d nu = rangeBearingInnovation(Eigen::Vector2d(100, kPi - 0.05), Eigen::Vector2d(90, -kPi + 0.05));
  EXPECT_NEAR(nu.x(), 10, 1e-12);
  EXPECT_NEAR(nu.y(), -0.1, 1e-12);
  EXPECT_THROW(predictRangeBearing(Pose2(5, 5, 0), Eigen::Vector2d(5, 5)), GeometryError);
  const Pose2 p(10, 20, 1.0);
  const Eigen::Vector2d lm = landmarkFromRangeBearing(p, 300, 0.4);
  const Eigen::Vector2d z = predictRangeBearing(p, lm);
  EXPECT_NEAR(z.x(), 300, 1e-9);
  EXPECT_NEAR(z.y(), 0.4, 1e-12);
}

// (u, v, d) of the pixel errors: the left column, the mean row and the disparity.
Eigen::Matrix3d uvdCovariance(const Eigen::Matrix4d& C) {
  Eigen::Matrix<double, 3, 4> T;
  T << 1, 0, 0, 0, 0, 0.5, 0, 0.5, 1, 0, -1, 0;
  return T * C * T.transpose();
}

TEST(PixelCovariance, ModelInUvdGivesItsSigmasAndCorrelation) {
  const Eigen::Matrix4d C = stereoPixelCovariance(0.3, 0.2, 0.05, -0.4);
  const Eigen::Matrix3d U = uvdCovariance(C);
  EXPECT_NEAR(std::sqrt(U(0, 0)), 0.3, 1e-12);
  EXPECT_NEAR(U(1, 1), 0.2 * 0.2 + 0.25 * kRowDifferenceSigma * kRowDifferenceSigma, 1e-12);
  EXPECT_NEAR(std::sqrt(U(2, 2)), 0.05, 1e-12);
  EXPECT_NEAR(U(0, 2) / (0.3 * 0.05), -0.4, 1e-12);
  // Left and right columns share the common-mode error: correlation close to 1.
  EXPECT_GT(C(0, 2) / std::sqrt(C(0, 0) * C(2, 2)), 0.95);
  EXPECT_NO_THROW(checkPixelCovariance(C, "test"));
  // A sample drawn from the (u, v, d) model has C as its covariance.
  std::mt19937_64 rng(3);
  std::normal_distribution<double> N;
  Eigen::Matrix4d S = Eigen::Matrix4d::Zero();
  const int n = 200000;
  for (int i = 0; i < n; ++i) {
    const double a = N(rng), b = N(rng);
    const double eu = 0.3 * a, ed = 0.05 * (-0.4 * a + std::sqrt(1 - 0.16) * b);
    const double ev = 0.2 * N(rng), delta = kRowDifferenceSigma * N(rng);
    const Eigen::Vector4d e(eu, ev, eu - ed, ev + delta);
    S += e * e.transpose();
  }
  S /= n;
  EXPECT_LT((S - C).cwiseAbs().maxCoeff(), 0.01 * C.cwiseAbs().maxCoeff() + 2e-4);
}

TEST(PixelCovariance, BadModelsAndMatricesThrow) {
  EXPECT_THROW(stereoPixelCovariance(0, 0.2, 0.1, 0), Error);
  EXPECT_THROW(stereoPixelCovariance(0.2, -1, 0.1, 0), Error);
  EXPECT_THROW(stereoPixelCovariance(0.2, 0.2, std::nan(""), 0), Error);
  EXPECT_THROW(stereoPixelCovariance(0.2, 0.2, 0.1, 1.0), Error);
  EXPECT_THROW(isotropicPixelCovariance(0), Error);
  Eigen::Matrix4d C = Eigen::Matrix4d::Identity();
  C(0, 2) = 0.5;
  EXPECT_THROW(checkPixelCovariance(C, "test"), Error);  // not symmetric
  C(2, 0) = 0.5;
  EXPECT_NO_THROW(checkPixelCovariance(C, "test"));
  C(0, 2) = C(2, 0) = 1.0;  // singular
  EXPECT_THROW(checkPixelCovariance(C, "test"), Error);
  EXPECT_THROW(checkPixelCovariance(Eigen::Matrix4d::Zero(), "test"), Error);
}

TEST(PixelCovariance, RangeBearingCovarianceIsJCJtWithNumericJacobian) {
  StereoRigParams rp;
  rp.tilt_rad = 0.2;
  rp.offset_x_mm = 20;
  const StereoRig rig(rp);
  const Eigen::Matrix4d C = stereoPixelCovariance(0.3, 0.2, 0.05, 0.3);
  for (const double pan : {0.0, 0.4, -0.7}) {
    const auto px = rig.project(Eigen::Vector3d(600, 150, 0), pan);
    ASSERT_TRUE(px.has_value());
    const Eigen::Vector4d x(px->u_left, px->v_left, px->u_right, px->v_right);
    auto h = [&](const Eigen::Vector4d& p) {
      const RangeBearing rb = rig.rangeBearing(StereoPixels{p(0), p(1), p(2), p(3)}, pan);
      return Eigen::Vector2d(rb.range, rb.bearing);
    };
    const Eigen::Matrix<double, 2, 4> J = numericJacobian<2, 4>(h, x, 1e-5);
    const Eigen::Matrix2d R = rangeBearingCovariance(rig, *px, pan, C);
    const Eigen::Matrix2d R_num = J * C * J.transpose();
    EXPECT_LT((R - R_num).cwiseAbs().maxCoeff(), 1e-6 * R_num.cwiseAbs().maxCoeff());
    // sigma^2 I reproduces the thesis's (5.32).
    EXPECT_LT((rangeBearingCovariance(rig, *px, pan, isotropicPixelCovariance(0.5)) -
               rig.rangeBearingCovariance(*px, pan, 0.5))
                  .cwiseAbs()
                  .maxCoeff(),
              1e-9);
  }
}

TEST(PixelCovariance, CommonModeErrorLeavesRangeNearlyUntouched) {
  // The same covariance of each column, but correlated left and right: the range variance
  // follows the disparity's, far below that of independent columns.
  const StereoRig rig;
  const auto px = rig.project(Eigen::Vector3d(900, 0, 0), 0.0);
  ASSERT_TRUE(px.has_value());
  const Eigen::Matrix2d R_iid = rangeBearingCovariance(rig, *px, 0.0, isotropicPixelCovariance(0.3));
  const Eigen::Matrix2d R_common = rangeBearingCovariance(rig, *px, 0.0, stereoPixelCovariance(0.3, 0.3, 0.05, 0.0));
  EXPECT_LT(R_common(0, 0), 0.1 * R_iid(0, 0));
  EXPECT_GT(R_common(1, 1), 1.5 * R_iid(1, 1));  // the bearing sees the whole common-mode error
}

}  // namespace stereoloc
