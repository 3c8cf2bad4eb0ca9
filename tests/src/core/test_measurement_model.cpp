#include <gtest/gtest.h>

#include <ceres/jet.h>
#include <random>

#include "src/core/measurement_model.h"
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

}  // namespace stereoloc
