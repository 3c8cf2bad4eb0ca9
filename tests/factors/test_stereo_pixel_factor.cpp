// StereoPixelFactor: zero at the rig's own projection (StereoRig::project) for plain and
// panned / tilted / offset rigs, whitening, the columns form as a subset of the full one,
// Jacobians against central differences (headings near +-pi), failure behind the cameras, bad
// input.
#include <gtest/gtest.h>

#include <Eigen/LU>
#include <memory>
#include <random>

#include "factors/factor_check.h"
#include "factors/stereo_pixel_factor.h"
#include "src/core/measurement_model.h"
#include "src/core/pose2.h"
#include "src/core/stereo_rig.h"
#include "src/core/types.h"
#include "stereo_sighting.h"

namespace stereoloc {
namespace {

StereoRig offCentreTiltedRig() {
  StereoRigParams p;
  p.tilt_rad = 0.25;
  p.offset_x_mm = 20.0;
  p.camera_height_mm = 90.0;
  p.principal_u = 150.0;
  p.principal_v = 130.0;
  return StereoRig(p);
}

using test::evaluateResidual;
using test::sight;
using test::Sighting;

const double kSightingHeadings[] = {kPi - 1e-7, -kPi + 1e-7, 0.3, -2.0};

TEST(StereoPixelFactor, ZeroAtTheRigProjectionAndWhitened) {
  std::mt19937_64 rng(3);
  std::uniform_real_distribution<double> U(-1.0, 1.0);
  for (const StereoRig& rig : {StereoRig(), offCentreTiltedRig()}) {
    for (double th : kSightingHeadings) {
      for (int i = 0; i < 5; ++i) {
        const Pose2 pose(700 * U(rng), 600 * U(rng), th);
        const double pan = 0.5 * U(rng);
        const Sighting s = sight(rig, pose, pan, 600 + 400 * U(rng), 0.4 * U(rng), 25.0 + 20 * U(rng));
        const double p[3] = {pose.x, pose.y, pose.theta};
        std::unique_ptr<ceres::CostFunction> f(
            StereoPixelFactor::Create(rig, s.landmark, s.pixels, pan, 0.5, PixelResiduals::All));
        EXPECT_LT(evaluateResidual(*f, p).norm(), 1e-8) << th;
        // Measured pixels off by e: r = -e / sigma, in the order (u_l, v_l, u_r, v_r).
        const Eigen::Vector4d e(0.3, -0.2, 0.1, 0.4);
        const StereoPixels noisy{s.pixels.u_left + e[0], s.pixels.v_left + e[1], s.pixels.u_right + e[2],
                                 s.pixels.v_right + e[3]};
        std::unique_ptr<ceres::CostFunction> all(
            StereoPixelFactor::Create(rig, s.landmark, noisy, pan, 0.5, PixelResiduals::All));
        std::unique_ptr<ceres::CostFunction> cols(
            StereoPixelFactor::Create(rig, s.landmark, noisy, pan, 0.5, PixelResiduals::Columns));
        const Eigen::VectorXd ra = evaluateResidual(*all, p), rc = evaluateResidual(*cols, p);
        ASSERT_EQ(ra.size(), 4);
        ASSERT_EQ(rc.size(), 2);
        EXPECT_LT((ra + e / 0.5).norm(), 1e-8);
        EXPECT_NEAR(rc[0], ra[0], 1e-12);
        EXPECT_NEAR(rc[1], ra[2], 1e-12);
      }
    }
  }
}

TEST(StereoPixelFactor, JacobiansMatchCentralDifferences) {
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> U(-1.0, 1.0);
  for (const StereoRig& rig : {StereoRig(), offCentreTiltedRig()}) {
    for (double th : kSightingHeadings) {
      for (PixelResiduals which : {PixelResiduals::All, PixelResiduals::Columns}) {
        const Pose2 pose(500 * U(rng), 400 * U(rng), th);
        const double pan = 0.4 * U(rng);
        const Sighting s = sight(rig, pose, pan, 300 + 900 * (1 + U(rng)), 0.45 * U(rng), 25.0);
        const StereoPixels noisy{s.pixels.u_left + 0.4, s.pixels.v_left - 0.3, s.pixels.u_right, s.pixels.v_right};
        std::unique_ptr<ceres::CostFunction> f(StereoPixelFactor::Create(rig, s.landmark, noisy, pan, 0.7, which));
        const double p[3] = {pose.x, pose.y, pose.theta};
        const FactorCheck c = checkFactorJacobians(*f, {p});
        EXPECT_TRUE(c.ok) << "theta " << th << "\n" << c.message;
      }
    }
  }
}

TEST(StereoPixelFactor, FailsBehindTheCamerasAndRejectsBadInput) {
  const StereoRig rig;
  const Pose2 pose(0, 0, 0);
  const Sighting s = sight(rig, pose, 0.0, 800, 0.1, 25.0);
  std::unique_ptr<ceres::CostFunction> f(
      StereoPixelFactor::Create(rig, s.landmark, s.pixels, 0.0, 0.5, PixelResiduals::All));
  const double behind[3] = {0, 0, kPi};  // the robot turned away: the landmark is behind the cameras
  const double* p[1] = {behind};
  Eigen::Vector4d r;
  EXPECT_FALSE(f->Evaluate(p, r.data(), nullptr));
  EXPECT_THROW(StereoPixelFactor::Create(rig, s.landmark, s.pixels, 0.0, 0.0, PixelResiduals::All), Error);
  EXPECT_THROW(StereoPixelFactor::Create(rig, s.landmark, s.pixels, 0.0, -1.0, PixelResiduals::All), Error);
  StereoPixels bad = s.pixels;
  bad.u_left = std::nan("");
  EXPECT_THROW(StereoPixelFactor::Create(rig, s.landmark, bad, 0.0, 0.5, PixelResiduals::All), Error);
}

TEST(StereoPixelFactor, CorrelatedCovarianceWhitensToTheMahalanobisDistance) {
  const StereoRig rig = offCentreTiltedRig();
  const Pose2 pose(100, -50, 0.4);
  const Sighting s = sight(rig, pose, 0.2, 700, 0.2, 25.0);
  const double p[3] = {pose.x, pose.y, pose.theta};
  const Eigen::Matrix4d C = stereoPixelCovariance(0.3, 0.15, 0.06, -0.3);
  const Eigen::Vector4d e(0.3, -0.2, 0.25, -0.2);
  const StereoPixels noisy{s.pixels.u_left + e[0], s.pixels.v_left + e[1], s.pixels.u_right + e[2],
                           s.pixels.v_right + e[3]};
  std::unique_ptr<ceres::CostFunction> all(
      StereoPixelFactor::Create(rig, s.landmark, noisy, 0.2, C, PixelResiduals::All));
  std::unique_ptr<ceres::CostFunction> cols(
      StereoPixelFactor::Create(rig, s.landmark, noisy, 0.2, C, PixelResiduals::Columns));
  const Eigen::VectorXd ra = evaluateResidual(*all, p), rc = evaluateResidual(*cols, p);
  EXPECT_NEAR(ra.squaredNorm(), e.dot(C.inverse() * e), 1e-6 * e.dot(C.inverse() * e));
  Eigen::Matrix2d C2;
  C2 << C(0, 0), C(0, 2), C(2, 0), C(2, 2);
  const Eigen::Vector2d e2(e[0], e[2]);
  EXPECT_NEAR(rc.squaredNorm(), e2.dot(C2.inverse() * e2), 1e-6 * e2.dot(C2.inverse() * e2));
  // The scalar form is the isotropic covariance.
  std::unique_ptr<ceres::CostFunction> iso(
      StereoPixelFactor::Create(rig, s.landmark, noisy, 0.2, isotropicPixelCovariance(0.5), PixelResiduals::All));
  EXPECT_LT((evaluateResidual(*iso, p) + e / 0.5).norm(), 1e-8);
  // Jacobians with the correlated whitening.
  for (const auto* f : {all.get(), cols.get()}) {
    const FactorCheck c = checkFactorJacobians(*f, {p});
    EXPECT_TRUE(c.ok) << c.message;
  }
  Eigen::Matrix4d singular = C;
  singular(0, 2) = singular(2, 0) = std::sqrt(C(0, 0) * C(2, 2));
  EXPECT_THROW(StereoPixelFactor::Create(rig, s.landmark, s.pixels, 0.2, singular, PixelResiduals::Columns), Error);
  EXPECT_THROW(StereoPixelFactor::Create(rig, s.landmark, s.pixels, 0.2, Eigen::Matrix4d::Zero(), PixelResiduals::All),
               Error);
}

}  // namespace
}  // namespace stereoloc
