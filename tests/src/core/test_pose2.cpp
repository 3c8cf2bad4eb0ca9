#include <gtest/gtest.h>

#include <ceres/jet.h>
#include <random>

#include "src/core/pose2.h"
#include "test_util.h"

namespace stereoloc {
namespace {

Pose2 randomPose(std::mt19937_64& rng, bool near_pi = false) {
  std::uniform_real_distribution<double> U(-1.0, 1.0);
  const double theta = near_pi ? kPi - 1e-7 * (1 + U(rng)) * (U(rng) > 0 ? 1 : -1) : kPi * U(rng);
  return Pose2(1000 * U(rng), 1000 * U(rng), theta);
}

Vector3d poseMinusVec(const Vector3d& a, const Vector3d& b) {
  return Vector3d(a.x() - b.x(), a.y() - b.y(), angleDiff(a.z(), b.z()));
}

// Central differences with the (x, y, theta) additive convention of pose2.h.
template <typename F>
Matrix3d numericPoseJacobian(const F& f, const Pose2& at) {
  auto fv = [&](const Vector3d& v) { return f(Pose2(v.x(), v.y(), v.z())).vector(); };
  return numericJacobian<3, 3>(fv, at.vector(), poseMinusVec);
}

}  // namespace

TEST(Pose2, ComposeInverseIdentity) {
  std::mt19937_64 rng(1);
  for (int i = 0; i < 100; ++i) {
    const Pose2 a = randomPose(rng);
    const Pose2 id = compose(a, inverse(a));
    EXPECT_NEAR(id.x, 0, 1e-9);
    EXPECT_NEAR(id.y, 0, 1e-9);
    EXPECT_NEAR(id.theta, 0, 1e-12);
    const Pose2 b = randomPose(rng);
    const Pose2 back = compose(a, between(a, b));
    EXPECT_NEAR(minus(back, b).norm(), 0, 1e-9);
  }
}

TEST(Pose2, ComposeMatchesThesisB16) {
  // (B.16) with u = (dx, dy, dtheta) applied at theta = 90 deg.
  const Pose2 p(100, 200, kPi / 2);
  const Pose2 q = compose(p, Pose2(10, 5, 0.1));
  EXPECT_NEAR(q.x, 100 - 5, 1e-12);
  EXPECT_NEAR(q.y, 200 + 10, 1e-12);
  EXPECT_NEAR(q.theta, kPi / 2 + 0.1, 1e-12);
}

TEST(Pose2, JacobiansMatchCentralDifferencesIncludingNearPi) {
  std::mt19937_64 rng(2);
  for (int i = 0; i < 200; ++i) {
    const bool near_pi = i % 2 == 1;
    const Pose2 a = randomPose(rng, near_pi), b = randomPose(rng, near_pi);
    Matrix3d Ja, Jb;
    compose(a, b, &Ja, &Jb);
    EXPECT_TRUE(test::jacobianMatches(Ja, numericPoseJacobian([&](const Pose2& x) { return compose(x, b); }, a)));
    EXPECT_TRUE(test::jacobianMatches(Jb, numericPoseJacobian([&](const Pose2& x) { return compose(a, x); }, b)));
    between(a, b, &Ja, &Jb);
    EXPECT_TRUE(test::jacobianMatches(Ja, numericPoseJacobian([&](const Pose2& x) { return between(x, b); }, a)));
    EXPECT_TRUE(test::jacobianMatches(Jb, numericPoseJacobian([&](const Pose2& x) { return between(a, x); }, b)));
    Matrix3d Ji;
    inverse(a, &Ji);
    EXPECT_TRUE(test::jacobianMatches(Ji, numericPoseJacobian([&](const Pose2& x) { return inverse(x); }, a)));
  }
}

TEST(Pose2, TransformToLocalJacobians) {
  std::mt19937_64 rng(3);
  for (int i = 0; i < 100; ++i) {
    const Pose2 p = randomPose(rng, i % 3 == 0);
    const Vector2d w(300.0 * (i % 7) - 900, 200.0 * (i % 5) - 400);
    Matrix23d Jp;
    Matrix2d Jw;
    transformToLocal(p, w, &Jp, &Jw);
    auto fp = [&](const Vector3d& v) { return transformToLocal(Pose2(v.x(), v.y(), v.z()), w); };
    auto fw = [&](const Vector2d& v) { return transformToLocal(p, v); };
    EXPECT_TRUE(test::jacobianMatches(Jp, numericJacobian<2, 3>(fp, p.vector())));
    EXPECT_TRUE(test::jacobianMatches(Jw, numericJacobian<2, 2>(fw, w)));
    EXPECT_NEAR((transformToWorld(p, transformToLocal(p, w)) - w).norm(), 0, 1e-9);
  }
}

TEST(Pose2, TemplatedFormsAgreeWithDoubleForms) {
  std::mt19937_64 rng(4);
  const Pose2 a = randomPose(rng), b = randomPose(rng);
  const double av[3] = {a.x, a.y, a.theta}, bv[3] = {b.x, b.y, b.theta};
  double c[3], d[3];
  composeT(av, bv, c);
  betweenT(av, bv, d);
  EXPECT_NEAR(minus(Pose2(c[0], c[1], c[2]), compose(a, b)).norm(), 0, 1e-9);
  EXPECT_NEAR(minus(Pose2(d[0], d[1], d[2]), between(a, b)).norm(), 0, 1e-9);
  using Jet = ceres::Jet<double, 3>;
  Jet aj[3] = {Jet(a.x, 0), Jet(a.y, 1), Jet(a.theta, 2)}, bj[3] = {Jet(b.x), Jet(b.y), Jet(b.theta)}, dj[3];
  betweenT(aj, bj, dj);
  Matrix3d J;
  between(a, b, &J);
  for (int r = 0; r < 3; ++r)
    for (int col = 0; col < 3; ++col) EXPECT_NEAR(dj[r].v[col], J(r, col), 1e-12);
}

TEST(Pose2, PlusMinusRoundTripWrapsTheta) {
  const Pose2 p(1, 2, kPi - 0.01);
  const Pose2 q = plus(p, Vector3d(3, 4, 0.02));
  EXPECT_NEAR(q.theta, -kPi + 0.01, 1e-12);
  EXPECT_NEAR((minus(q, p) - Vector3d(3, 4, 0.02)).norm(), 0, 1e-12);
}

}  // namespace stereoloc
