// Self-calibration factors: each reduces to its plain factor at the nominal calibration, is zero
// at the true calibration's prediction, and has Jacobians (poses and calibration blocks) that
// agree with central differences, on straight lines (alpha -> 0), turns and headings near +-pi.
#include <gtest/gtest.h>

#include <ceres/covariance.h>
#include <ceres/manifold.h>
#include <ceres/problem.h>
#include <ceres/solver.h>

#include <Eigen/LU>
#include <array>
#include <cstdint>
#include <memory>
#include <random>

#include "factors/calibration_prior_factor.h"
#include "factors/composed_odometry_calibration_factor.h"
#include "factors/factor_check.h"
#include "factors/odometry_calibration_factor.h"
#include "factors/odometry_factor.h"
#include "factors/range_bearing_calibration_factor.h"
#include "factors/range_bearing_factor.h"
#include "factors/stereo_pixel_calibration_factor.h"
#include "factors/stereo_pixel_image_calibration_factor.h"
#include "factors/stereo_pixel_factor.h"
#include "src/core/pose2.h"
#include "src/core/stereo_rig.h"
#include "stereo_sighting.h"
#include "test_util.h"

namespace stereoloc {
namespace {

using test::evaluateResiduals;

// Readings of a motion with the calibration `cal`: what the encoders report when the wheels
// roll the arc of (B.1)-(B.5).
std::pair<double, double> readings(double dl_true, double dr_true, const double* cal) {
  return {dl_true / cal[0], dr_true / cal[1]};
}

// (B.6) evaluated at the readings themselves (the factors' Jacobians do not depend on where).
WheelIncrements atReadings(double m_left, double m_right) { return {std::fabs(m_left), std::fabs(m_right)}; }
std::vector<WheelIncrements> atReadings(const std::vector<std::pair<double, double>>& m) {
  std::vector<WheelIncrements> t;
  for (const auto& [l, r] : m) t.push_back(atReadings(l, r));
  return t;
}

TEST(OdometryCalibrationFactor, ZeroAtTheTrueCalibrationAndJacobiansMatch) {
  const OdometryParams params;
  std::mt19937_64 rng(11);
  std::uniform_real_distribution<double> U(-1.0, 1.0);
  const double cal[3] = {1.012, 0.991, 77.5};
  // Straight, nearly straight, turning, turning on the spot, reversing; headings near +-pi.
  for (const auto& [dl, dr] : {std::pair{31.4, 31.4}, {30.0, 30.0 + 1e-6}, {28.0, 34.8}, {-6.0, 6.0}, {20.0, -3.0},
                               {-15.0, -18.0}}) {
    for (double th : {kPi - 1e-7, -kPi + 1e-7, 0.4}) {
      const Pose2 a(300 * U(rng), 300 * U(rng), th);
      const Pose2 b = compose(a, Pose2::fromVector(controlVector(dl, dr, cal[2])));
      const auto [ml, mr] = readings(dl, dr, cal);
      std::unique_ptr<ceres::CostFunction> f(OdometryCalibrationFactor::Create(ml, mr, atReadings(ml, mr), params));
      const double pa[3] = {a.x, a.y, a.theta}, pb[3] = {b.x, b.y, b.theta};
      EXPECT_LT(evaluateResiduals(*f, {pa, pb, cal}).norm(), 1e-7) << dl << " " << dr;
      const double pb_off[3] = {b.x + 0.3, b.y - 0.2, b.theta + 0.01};
      const double cal_off[3] = {1.0, 1.003, 75.0};
      for (const double* c : {cal, cal_off}) {
        const FactorCheck chk = checkFactorJacobians(*f, {pa, pb_off, c});
        EXPECT_TRUE(chk.ok) << dl << " " << dr << "\n" << chk.message;
      }
    }
  }
}

// To first order it carries the information of the control-vector factor: at the nominal
// calibration, for small pose errors, both give the same Mahalanobis distance up to the floors.
TEST(OdometryCalibrationFactor, AgreesWithTheControlVectorFactorToFirstOrder) {
  OdometryParams params;
  params.control_variance_floor = Eigen::Vector3d(1e-8, 1e-2, 1e-12);
  const double nominal[3] = {1.0, 1.0, params.wheel_base_mm};
  const Pose2 a(100, 200, 0.7);
  const double dl = 28.0, dr = 34.8;
  const Pose2 b = compose(a, Pose2::fromVector(controlVector(dl, dr, params.wheel_base_mm)));
  std::unique_ptr<ceres::CostFunction> calib(OdometryCalibrationFactor::Create(dl, dr, atReadings(dl, dr), params));
  std::unique_ptr<ceres::CostFunction> plain(OdometryFactor::Create(dl, dr, params));
  const double pa[3] = {a.x, a.y, a.theta};
  // A pose error along the arc (both wheels further) and a heading error (one wheel further).
  for (const Eigen::Vector3d& delta : {Eigen::Vector3d(0.02 * std::cos(b.theta), 0.02 * std::sin(b.theta), 0.0),
                                       Eigen::Vector3d(0.0, 0.0, 2e-4)}) {
    const double pb[3] = {b.x + delta.x(), b.y + delta.y(), b.theta + delta.z()};
    const double c2 = evaluateResiduals(*calib, {pa, pb, nominal}).squaredNorm(), p2 = evaluateResiduals(*plain, {pa, pb}).squaredNorm();
    EXPECT_NEAR(c2, p2, 0.05 * p2);
  }
}

// The wheel base fitted to a long turn on the spot with the poses known: weighted at each
// step's own readings, (B.6) favours the readings that came out small and the fit is low by about
// k / |d| (4 % here, many sigma); weighted at NoiseTravel's travel it is unbiased.
TEST(OdometryCalibrationFactor, WheelBaseUnbiasedWhenWeightedAtTheNoiseTravel) {
  OdometryParams params;
  params.k_left = params.k_right = 0.05;  // the simulator's encoder noise (mm^2/mm)
  const double w = params.wheel_base_mm, dtheta = -1.8 * kPi / 180.0;  // the thesis's spin
  const WheelIncrements truth = wheelIncrementsForArc(0.0, dtheta, w);
  const int n = 4000;
  std::mt19937_64 rng(3);
  std::normal_distribution<double> N(0.0, 1.0);
  std::vector<std::array<double, 3>> poses(n + 1);
  std::vector<std::pair<double, double>> m(n);
  for (int i = 0; i < n; ++i) {
    poses[i + 1] = {0.0, 0.0, wrapAngle(dtheta * (i + 1))};
    m[i] = {truth.d_left + std::sqrt(params.k_left * std::fabs(truth.d_left)) * N(rng),
            truth.d_right + std::sqrt(params.k_right * std::fabs(truth.d_right)) * N(rng)};
  }
  auto fit = [&](bool at_noise_travel, double* sigma) {
    ceres::Problem problem;
    std::array<double, 3> cal = {1.0, 1.0, w};
    NoiseTravel noise;
    for (int i = 0; i < n; ++i) {
      const WheelIncrements t = noise.next(m[i].first, m[i].second);
      problem.AddResidualBlock(OdometryCalibrationFactor::Create(m[i].first, m[i].second,
                                                                 at_noise_travel ? t : atReadings(m[i].first, m[i].second),
                                                                 params),
                               nullptr, poses[i].data(), poses[i + 1].data(), cal.data());
    }
    for (auto& p : poses) problem.SetParameterBlockConstant(p.data());
    problem.SetManifold(cal.data(), new ceres::SubsetManifold(3, {0, 1}));  // the scales are known
    ceres::Solver::Options options;
    ceres::Solver::Summary summary;
    ceres::Solve(options, &problem, &summary);
    EXPECT_TRUE(summary.IsSolutionUsable());
    ceres::Covariance::Options co;
    ceres::Covariance cov(co);
    EXPECT_TRUE(cov.Compute({std::make_pair(cal.data(), cal.data())}, &problem));
    double C[9];
    cov.GetCovarianceBlockInTangentSpace(cal.data(), cal.data(), C);
    *sigma = std::sqrt(C[0]);
    return cal[2];
  };
  double sigma = 0.0;
  const double biased = fit(false, &sigma);
  EXPECT_LT(biased, w - 5.0 * sigma);
  const double fitted = fit(true, &sigma);
  EXPECT_NEAR(fitted, w, 3.0 * sigma);
  EXPECT_LT(sigma, 0.01 * w);
}

StereoRig tiltedRig() {
  StereoRigParams p;
  p.tilt_rad = 0.2;
  p.offset_x_mm = 15.0;
  p.camera_height_mm = 80.0;
  return StereoRig(p);
}

TEST(ComposedOdometryCalibrationFactor, ZeroAtTheComposedTrueMotionAndJacobiansMatch) {
  const double cal[3] = {1.012, 0.991, 77.5};
  // Straight, nearly straight, turning, on the spot and reversing steps in one chain.
  const std::vector<std::pair<double, double>> truth = {{31.4, 31.4}, {30.0, 30.0 + 1e-6}, {28.0, 34.8}, {-6.0, 6.0},
                                                        {20.0, -3.0}, {-15.0, -18.0}};
  std::vector<std::pair<double, double>> m;
  for (const auto& [dl, dr] : truth) m.push_back(readings(dl, dr, cal));
  const std::vector<OdometryParams> params(truth.size());
  for (size_t n : {size_t{1}, size_t{2}, truth.size()}) {
    for (double th : {kPi - 1e-7, -kPi + 1e-7, 0.4}) {
      const Pose2 a(120.0, -340.0, th);
      Pose2 b = a;
      for (size_t i = 0; i < n; ++i)
        b = compose(b, Pose2::fromVector(controlVector(truth[i].first, truth[i].second, cal[2])));
      const long k = static_cast<long>(n);
      std::unique_ptr<ceres::CostFunction> f(ComposedOdometryCalibrationFactor::Create(
          std::vector<std::pair<double, double>>(m.begin(), m.begin() + k),
          atReadings(std::vector<std::pair<double, double>>(m.begin(), m.begin() + k)),
          std::vector<OdometryParams>(params.begin(), params.begin() + k)));
      const double pa[3] = {a.x, a.y, a.theta}, pb[3] = {b.x, b.y, b.theta};
      EXPECT_LT(evaluateResiduals(*f, {pa, pb, cal}).norm(), 1e-7) << n << " " << th;
      const double pb_off[3] = {b.x + 0.3, b.y - 0.2, b.theta + 0.01};
      const double cal_off[3] = {1.0, 1.003, 75.0};
      for (const double* c : {cal, cal_off}) {
        const FactorCheck chk = checkFactorJacobians(*f, {pa, pb_off, c});
        EXPECT_TRUE(chk.ok) << n << " " << th << "\n" << chk.message;
      }
    }
  }
}

TEST(ComposedOdometryCalibrationFactor, WeighsWithTheComposedPredictionCovariance) {
  // At any calibration the factor's weight is the covariance the EKF prediction (5.9) composes
  // over the same steps with that calibration's wheel increments, and variances scaled by c^2.
  std::vector<OdometryParams> params(3);
  params[1].wheel_variance_floor = 0.3;  // a step with slip
  const std::vector<std::pair<double, double>> m = {{28.0, 34.8}, {30.0, 30.0}, {-5.0, 7.0}};
  for (const Eigen::Vector3d& c : {Eigen::Vector3d(1.0, 1.0, 75.0), Eigen::Vector3d(1.03, 0.98, 80.0)}) {
    Pose2 b;
    Eigen::Matrix3d P = Eigen::Matrix3d::Zero();
    for (size_t i = 0; i < m.size(); ++i) {
      OdometryParams p = params[i];
      p.wheel_base_mm = c.z();
      // k |d| with d = c m equals c (k |m|); the factor scales k |m| by c^2, so hand it c k.
      p.k_left *= c.x();
      p.k_right *= c.y();
      p.wheel_variance_floor = 0.0;  // added below, scaled by c^2
      const double floor_l = c.x() * c.x() * params[i].wheel_variance_floor;
      const double floor_r = c.y() * c.y() * params[i].wheel_variance_floor;
      Matrix32d J;
      const Eigen::Vector3d u = controlVector(c.x() * m[i].first, c.y() * m[i].second, c.z(), &J);
      Eigen::Matrix2d W = wheelCovariance(c.x() * m[i].first, c.y() * m[i].second, p);
      W(0, 0) += floor_l;
      W(1, 1) += floor_r;
      Eigen::Matrix3d U = J * W * J.transpose();
      U.diagonal() += p.control_variance_floor;
      Eigen::Matrix3d J1, J2;
      b = compose(b, Pose2::fromVector(u), &J1, &J2);
      P = J1 * P * J1.transpose() + J2 * U * J2.transpose();
    }
    std::unique_ptr<ceres::CostFunction> f(ComposedOdometryCalibrationFactor::Create(m, atReadings(m), params));
    const Eigen::Vector3d delta(0.7, -0.4, 0.02);
    const double pa[3] = {0.0, 0.0, 0.0}, pb[3] = {b.x + delta.x(), b.y + delta.y(), b.theta + delta.z()};
    const double cal[3] = {c.x(), c.y(), c.z()};
    // betweenT(identity, b + delta) - g = delta, so |r|^2 is delta's Mahalanobis distance.
    const double expected = delta.dot(P.inverse() * delta);
    EXPECT_NEAR(evaluateResiduals(*f, {pa, pb, cal}).squaredNorm(), expected, 1e-9 * expected) << c.transpose();
  }
}

TEST(ComposedOdometryCalibrationFactor, RejectsBadInput) {
  const std::vector<OdometryParams> one(1);
  const std::vector<WheelIncrements> t1(1, WheelIncrements{1.0, 1.0}), t2(2, WheelIncrements{1.0, 1.0});
  EXPECT_THROW(ComposedOdometryCalibrationFactor::Create({}, {}, {}), Error);
  EXPECT_THROW(ComposedOdometryCalibrationFactor::Create({{1.0, std::nan("")}}, t1, one), Error);
  EXPECT_THROW(ComposedOdometryCalibrationFactor::Create({{1.0, 1.0}}, {WheelIncrements{std::nan(""), 1.0}}, one),
               Error);
  EXPECT_THROW(ComposedOdometryCalibrationFactor::Create({{1.0, 1.0}, {1.0, 1.0}}, t2, one), Error);
  EXPECT_THROW(ComposedOdometryCalibrationFactor::Create({{1.0, 1.0}, {1.0, 1.0}}, t1, {one[0], one[0]}), Error);
  OdometryParams no_floor;
  no_floor.control_variance_floor.setZero();
  EXPECT_THROW(ComposedOdometryCalibrationFactor::Create({{1.0, 1.0}}, t1, {no_floor}), Error);
  std::vector<OdometryParams> differ(2);
  differ[1].control_variance_floor.x() = 1.0;
  EXPECT_THROW(ComposedOdometryCalibrationFactor::Create({{1.0, 1.0}, {1.0, 1.0}}, t2, differ), Error);
}

TEST(StereoPixelCalibrationFactor, NominalEqualsPixelFactorTrueIsZeroAndJacobiansMatch) {
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> U(-1.0, 1.0);
  for (const StereoRig& rig : {StereoRig(), tiltedRig()}) {
    for (double th : {kPi - 1e-7, -kPi + 1e-7, 0.3, -2.0}) {
      for (PixelResiduals mode : {PixelResiduals::All, PixelResiduals::Columns}) {
        const Pose2 pose(600 * U(rng), 500 * U(rng), th);
        const double pan = 0.4 * U(rng);
        const test::Sighting s = test::sight(rig, pose, pan, 700 + 300 * U(rng), 0.4 * U(rng), 25.0);
        const double p[3] = {pose.x, pose.y, pose.theta};
        const double nominal[6] = {0.0, 1.0, 0.0, 0.0, 0.0, 0.0};
        std::unique_ptr<ceres::CostFunction> calib(
            StereoPixelCalibrationFactor::Create(rig, s.landmark, s.pixels, pan, 0.5, mode));
        std::unique_ptr<ceres::CostFunction> plain(StereoPixelFactor::Create(rig, s.landmark, s.pixels, pan, 0.5, mode));
        EXPECT_LT((evaluateResiduals(*calib, {p, nominal}) - evaluateResiduals(*plain, {p})).norm(), 1e-9);
        const double off[6] = {0.01, 1.02, 0.0, 0.0, 0.0, 0.0};
        const double off_px[6] = {-0.008, 0.985, 1.3, -0.7, 0.006, 0.0};
        const double off_f[6] = {0.004, 1.01, -0.9, 0.4, -0.005, 0.008};
        for (const double* q : {off, off_px, off_f}) {
          const FactorCheck c = checkFactorJacobians(*calib, {p, q});
          EXPECT_TRUE(c.ok) << c.message;
        }
        // Pixels of a rig with the tilt and baseline of `off` are explained exactly by `off`.
        StereoRigParams tp = rig.params();
        tp.tilt_rad += off[0];
        tp.baseline_mm *= off[1];
        const StereoRig truth(tp);
        const Eigen::Vector2d local = transformToLocal(pose, s.landmark.head<2>());
        const auto px = truth.project(Eigen::Vector3d(local.x(), local.y(), s.landmark.z()), pan);
        ASSERT_TRUE(px);
        std::unique_ptr<ceres::CostFunction> f(StereoPixelCalibrationFactor::Create(rig, s.landmark, *px, pan, 0.5, mode));
        EXPECT_LT(evaluateResiduals(*f, {p, off}).norm(), 1e-8);
        // ... and with the pixel offsets, focal ratio and focal scale of `off_px` and `off_f`
        // too: both cameras' focal length is f (1 + psi) (columns and rows), the disparity grows
        // by delta_d, both columns move by delta_u, the right column's distance from o_u scales
        // by 1 + phi.
        for (const double* q : {off_px, off_f}) {
          StereoRigParams tq = rig.params();
          tq.tilt_rad += q[0];
          tq.baseline_mm *= q[1];
          tq.focal_px = rig.focal() * (1.0 + q[5]);
          tq.principal_u = rig.principalU();
          tq.principal_v = rig.principalV();
          const StereoRig tq_rig(tq);
          const auto qx = tq_rig.project(Eigen::Vector3d(local.x(), local.y(), s.landmark.z()), pan);
          ASSERT_TRUE(qx);
          StereoPixels shifted = *qx;
          shifted.u_left += q[3] + 0.5 * q[2];
          shifted.u_right = tq_rig.principalU() + (1.0 + q[4]) * (shifted.u_right - tq_rig.principalU()) + q[3] - 0.5 * q[2];
          std::unique_ptr<ceres::CostFunction> g(
              StereoPixelCalibrationFactor::Create(rig, s.landmark, shifted, pan, 0.5, mode));
          EXPECT_LT(evaluateResiduals(*g, {p, q}).norm(), 1e-8);
        }
      }
    }
  }
}

TEST(RangeBearingCalibrationFactor, NominalEqualsRangeBearingFactorTrueIsZeroAndJacobiansMatch) {
  const Eigen::Vector2d l(2500.0, -1300.0);
  Eigen::Matrix2d R;
  R << 900.0, 0.2, 0.2, 1e-4;  // correlated R: the upper square root must whiten it
  for (const Pose2& truth : {Pose2(100.0, 200.0, 0.3), Pose2(-400.0, 50.0, kPi - 1e-3), Pose2(0.0, 0.0, -2.5)}) {
    const Eigen::Vector2d h = predictRangeBearing(truth, l);
    const double k_true[4] = {0.03, 0.01, -0.45, deg2rad(0.4)};
    // What such a sensor reports: the range scaled at the bearing it sees, the bearing offset.
    const double b = wrapAngle(h.y() + k_true[3]);
    const Eigen::Vector2d z((1.0 + k_true[0] + k_true[1] * b + k_true[2] * b * b) * h.x(), b);
    std::unique_ptr<ceres::CostFunction> calib(RangeBearingCalibrationFactor::Create(l, z, R));
    std::unique_ptr<ceres::CostFunction> plain(RangeBearingFactor::Create(l, z, R));
    const double p[3] = {truth.x, truth.y, truth.theta};
    EXPECT_LT(evaluateResiduals(*calib, {p, k_true}).norm(), 1e-9);
    const double k0[4] = {0, 0, 0, 0};
    const double p_off[3] = {truth.x + 30.0, truth.y - 20.0, truth.theta + 0.02};
    EXPECT_LT((evaluateResiduals(*calib, {p_off, k0}) - evaluateResiduals(*plain, {p_off})).norm(), 1e-12);
    for (const double* k : {k0, k_true}) {
      const FactorCheck c = checkFactorJacobians(*calib, {p_off, k});
      EXPECT_TRUE(c.ok) << c.message;
    }
  }
  // Coincident pose and landmark: the bearing is undefined, the evaluation fails.
  std::unique_ptr<ceres::CostFunction> f(
      RangeBearingCalibrationFactor::Create(l, Eigen::Vector2d(1000.0, 0.1), Eigen::Vector2d(9.0, 1e-4).asDiagonal()));
  const double at[3] = {l.x(), l.y(), 0.0}, k[4] = {0, 0, 0, 0};
  const double* blocks[2] = {at, k};
  Eigen::Vector2d r;
  EXPECT_FALSE(f->Evaluate(blocks, r.data(), nullptr));
}

TEST(CalibrationPriorFactor, WhitensAndJacobianMatches) {
  Eigen::Matrix3d C;
  C << 1e-4, 2e-5, 0, 2e-5, 4e-4, 0, 0, 0, 2.25;
  std::unique_ptr<ceres::CostFunction> f(CalibrationPriorFactor<3>::Create(Eigen::Vector3d(1, 1, 75), C));
  const double c[3] = {1.01, 0.98, 76.5};
  const Eigen::VectorXd r = evaluateResiduals(*f, {c});
  const Eigen::Vector3d e(0.01, -0.02, 1.5);
  EXPECT_NEAR(r.squaredNorm(), e.dot(C.inverse() * e), 1e-9);
  const FactorCheck chk = checkFactorJacobians(*f, {c});
  EXPECT_TRUE(chk.ok) << chk.message;
}

}  // namespace
}  // namespace stereoloc

#include <opencv2/calib3d.hpp>

#include "src/core/stereo_calibration.h"

namespace stereoloc {
namespace {

// A rig whose given calibration has barrel distortion (k1 = -0.2, as the realistic profile's
// lens), rectified with alpha 0: its rectified focal length differs from the raw one and the
// rectification map's scale changes over the image.
StereoRig distortedRig() {
  const StereoRig nominal;
  StereoCalibration c = idealCalibration(320, 240, nominal.focal(), 160.0, 120.0, 30.0);
  c.D1 = (cv::Mat_<double>(1, 4) << -0.2, 0.05, 0.0005, -0.0004);
  c.D2 = (cv::Mat_<double>(1, 4) << -0.19, 0.045, -0.0003, 0.0002);
  c.rectify();
  return StereoRig(nominal.params(), c);
}

// The rectified pixels (with the rig's given calibration) of a robot-frame point through raw
// cameras K, D, turned by R (X_raw = R X_ideal, OpenCV axes), as the simulator renders them.
StereoPixels throughRawCameras(const StereoRig& rig, const Eigen::Vector3d& p_robot, double pan, const cv::Mat K[2],
                               const cv::Mat D[2], const cv::Mat R[2]) {
  const Eigen::Vector3d p = rig.robotToVision(p_robot, pan);
  const double hb = 0.5 * rig.params().baseline_mm;
  const StereoCalibration& g = *rig.calibration();
  double uv[2][2];
  for (int c = 0; c < 2; ++c) {
    const cv::Mat X = (cv::Mat_<double>(3, 1) << -(p.y() - (c == 0 ? hb : -hb)), -p.z(), p.x());
    const cv::Mat Xr = R[c] * X;
    std::vector<cv::Point2d> raw, rect;
    cv::projectPoints(std::vector<cv::Point3d>{cv::Point3d(Xr.at<double>(0), Xr.at<double>(1), Xr.at<double>(2))},
                      cv::Vec3d(0, 0, 0), cv::Vec3d(0, 0, 0), K[c], D[c], raw);
    const cv::TermCriteria crit(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 50, 1e-12);
    cv::undistortPoints(raw, rect, c == 0 ? g.K1 : g.K2, c == 0 ? g.D1 : g.D2, c == 0 ? g.R1 : g.R2,
                        c == 0 ? g.P1 : g.P2, crit);
    uv[c][0] = rect[0].x;
    uv[c][1] = rect[0].y;
  }
  return StereoPixels{uv[0][0], uv[0][1], uv[1][0], uv[1][1]};
}

// The image block's sigmas (lens terms of both cameras, then the right camera's rotation) at
// which the pixel calibration factors are checked.
stereo_pixel_calibration::ImageErrorVector checkedImageSigmas() {
  stereo_pixel_calibration::ImageErrorVector sigma;
  sigma << 0.01, 0.005, 0.0003, 0.0003, 0.01, 0.005, 0.0003, 0.0003, 0.0017, 0.0017, 0.0017, 0.003;
  return sigma;
}

// A robot driving and turning at its image, for the image block's exposure offset.
constexpr BodyRate kRate{250.0, 0.8};  // mm/s, rad/s

// Four random sightings on each rig (plain, tilted, with a rectification map) and residual mode,
// each handed to check(rig, mode, sighting, pan, pose p, calibration q, image errors e, uniform)
// with q and e off nominal; uniform() draws from [-1, 1] for whatever else a check needs.
template <typename Check>
void forEachCalibrationCase(std::uint64_t seed, Check check) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> U(-1.0, 1.0);
  auto uniform = [&] { return U(rng); };
  for (const StereoRig& rig : {StereoRig(), tiltedRig(), distortedRig()}) {
    for (PixelResiduals mode : {PixelResiduals::All, PixelResiduals::Columns}) {
      for (int k = 0; k < 4; ++k) {
        const Pose2 pose(600 * U(rng), 500 * U(rng), kPi * U(rng));
        const double pan = 0.3 * U(rng);
        const test::Sighting s = test::sight(rig, pose, pan, 900 + 400 * U(rng), 0.45 * U(rng), 60 + 60 * U(rng));
        const double p[3] = {pose.x, pose.y, pose.theta};
        const double q[6] = {0.004, 1.01, -0.9, 0.4, -0.005, 0.008};
        double e[12];
        for (double& v : e) v = 1.5 * U(rng);
        check(rig, mode, s, pan, p, q, e, uniform);
      }
    }
  }
}

TEST(StereoPixelImageCalibrationFactor, ZeroImageErrorsEqualTheCalibrationFactorAndJacobiansMatch) {
  const stereo_pixel_calibration::ImageErrorVector sigma = checkedImageSigmas();
  forEachCalibrationCase(11, [&](const StereoRig& rig, PixelResiduals mode, const test::Sighting& s, double pan,
                                 const double* p, const double* q, const double* e, auto&) {
    const double zero[12] = {0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0};
    std::unique_ptr<ceres::CostFunction> image(
        StereoPixelImageCalibrationFactor::Create(rig, s.landmark, s.pixels, pan, 0.3 * Eigen::Matrix4d::Identity(), mode, sigma, kRate));
    std::unique_ptr<ceres::CostFunction> calib(
        StereoPixelCalibrationFactor::Create(rig, s.landmark, s.pixels, pan, 0.3 * Eigen::Matrix4d::Identity(), mode));
    EXPECT_LT((evaluateResiduals(*image, {p, q, zero}) - evaluateResiduals(*calib, {p, q})).norm(), 1e-12);
    const FactorCheck c = checkFactorJacobians(*image, {p, q, e});
    EXPECT_TRUE(c.ok) << c.message;
    const FactorCheck d = checkFactorJacobians(*calib, {p, q});
    EXPECT_TRUE(d.ok) << d.message;
  });
}

// Raw cameras with principal-point and focal-length errors, lens distortion other than the
// given estimate and a right camera turned against the left: the rectified pixels are those the
// factors predict with q = (0, 1, delta_d, delta_u, phi, psi) of the raw errors and the image
// block of the lens and rotation errors, to second order, across the image (the raw terms'
// gain at the image's edge differs from 1 by ~20 %).
TEST(StereoPixelImageCalibrationFactor, PredictsTheRectifiedPixelsOfErroneousRawCameras) {
  const StereoRig rig = distortedRig();
  const StereoCalibration& g = *rig.calibration();
  const double f = rig.focal(), f_raw = g.K1.at<double>(0, 0);
  const double dl = 0.9, dr = -1.2, psi = 0.004, phi = -0.006;                        // raw px, scales
  const double lens[2][4] = {{0.01, -0.005, 0.0003, -0.0002}, {-0.008, 0.004, -0.0002, 0.0003}};
  const double pitch = 0.0015, yaw = -0.0012, roll = 0.0018;                           // rad
  cv::Mat K[2] = {g.K1.clone(), g.K2.clone()}, D[2] = {g.D1.clone(), g.D2.clone()}, R[2];
  K[0].at<double>(0, 2) += dl;
  K[1].at<double>(0, 2) += dr;
  K[0].at<double>(0, 0) *= 1 + psi;
  K[0].at<double>(1, 1) *= 1 + psi;
  K[1].at<double>(0, 0) *= (1 + psi) * (1 + phi);
  K[1].at<double>(1, 1) *= 1 + psi;
  for (int c = 0; c < 2; ++c)
    for (int j = 0; j < 4; ++j) D[c].at<double>(j) += lens[c][j];
  R[0] = cv::Mat::eye(3, 3, CV_64F);
  cv::Rodrigues(cv::Vec3d(pitch, yaw, roll), R[1]);
  // delta_u +- delta_d / 2: the raw offsets at the centre's gain f / f_raw; the right column also
  // takes the yaw's constant f yaw.
  const double left = dl * f / f_raw, right = dr * f / f_raw + f * yaw;
  const double q[6] = {0.0, 1.0, left - right, 0.5 * (left + right), phi, psi};
  stereo_pixel_calibration::ImageErrorVector sigma;
  sigma << 0.01, 0.005, 0.0003, 0.0003, 0.01, 0.005, 0.0003, 0.0003, 0.0017, 0.0017, 0.0017, 0.003;
  double e[12];
  for (int c = 0; c < 2; ++c)
    for (int j = 0; j < 4; ++j) e[4 * c + j] = lens[c][j] / sigma[4 * c + j];
  // Pitch moves the right column by -f x y, roll by -f y (OpenCV's rotation vector).
  e[8] = -pitch / sigma[8];
  e[9] = yaw / sigma[9];
  e[10] = roll / sigma[10];
  e[11] = 0.0;  // the robot stands: no exposure offset's shift
  const double zero[12] = {0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0};
  const Pose2 pose(100.0, -50.0, 0.3);
  const double p[3] = {pose.x, pose.y, pose.theta};
  double worst = 0, worst_without_image = 0, largest_gain = 0;
  for (double bearing : {-0.45, -0.25, 0.0, 0.2, 0.42})
    for (double height : {0.0, 40.0, 150.0})
      for (double range : {450.0, 900.0, 1500.0}) {
        const Eigen::Vector2d local(range * std::cos(bearing), range * std::sin(bearing));
        const Eigen::Vector2d world = transformToWorld(pose, local);
        const StereoPixels px = throughRawCameras(rig, Eigen::Vector3d(local.x(), local.y(), height), 0.0, K, D, R);
        if (px.u_left < 0 || px.u_left > 319 || px.u_right < 0 || px.u_right > 319 || px.v_left < 0 || px.v_left > 239)
          continue;
        const Eigen::Vector3d landmark(world.x(), world.y(), height);
        std::unique_ptr<ceres::CostFunction> factor(StereoPixelImageCalibrationFactor::Create(
            rig, landmark, px, 0.0, Eigen::Matrix4d::Identity(), PixelResiduals::Columns, sigma, BodyRate()));
        worst = std::max(worst, evaluateResiduals(*factor, {p, q, e}).cwiseAbs().maxCoeff());
        worst_without_image = std::max(worst_without_image, evaluateResiduals(*factor, {p, q, zero}).cwiseAbs().maxCoeff());
        const auto response = stereo_pixel_calibration::columnResponse(rig, px, nullptr, BodyRate());
        largest_gain = std::max({largest_gain, std::fabs(response.offset[0]), std::fabs(response.offset[1])});
      }
  EXPECT_LT(worst, 0.02);                 // px
  EXPECT_GT(worst_without_image, 0.2);    // the lens and rotation errors are not small
  EXPECT_GT(largest_gain, 0.1);           // and the raw terms' gain departs from 1
}

}  // namespace
}  // namespace stereoloc

#include "factors/stereo_pixel_row_calibration_factor.h"

namespace stereoloc {
namespace {

// The row block: with dv = 0 the factor is the stereo (or image) calibration factor; a right
// column slid by s dv is explained by dv; Jacobians against central differences, with and
// without the image block, on rigs with and without a rectification map.
TEST(StereoPixelRowCalibrationFactor, ZeroRowOffsetEqualsTheCalibrationFactorSlideIsExplainedAndJacobiansMatch) {
  const stereo_pixel_calibration::ImageErrorVector sigma = checkedImageSigmas();
  forEachCalibrationCase(23, [&](const StereoRig& rig, PixelResiduals mode, const test::Sighting& s, double pan,
                                 const double* p, const double* q, const double* e, auto& uniform) {
    const double gain = 1.5 * uniform(), zero[1] = {0.0}, dv[1] = {1.4 * uniform()};
    const Eigen::Matrix4d C = 0.3 * Eigen::Matrix4d::Identity();
    std::unique_ptr<ceres::CostFunction> row(
        StereoPixelRowCalibrationFactor::Create(rig, s.landmark, s.pixels, gain, pan, C, mode, nullptr, kRate));
    std::unique_ptr<ceres::CostFunction> row_image(
        StereoPixelRowCalibrationFactor::Create(rig, s.landmark, s.pixels, gain, pan, C, mode, &sigma, kRate));
    std::unique_ptr<ceres::CostFunction> calib(StereoPixelCalibrationFactor::Create(rig, s.landmark, s.pixels, pan, C, mode));
    std::unique_ptr<ceres::CostFunction> image(
        StereoPixelImageCalibrationFactor::Create(rig, s.landmark, s.pixels, pan, C, mode, sigma, kRate));
    EXPECT_LT((evaluateResiduals(*row, {p, q, zero}) - evaluateResiduals(*calib, {p, q})).norm(), 1e-12);
    EXPECT_LT((evaluateResiduals(*row_image, {p, q, e, zero}) - evaluateResiduals(*image, {p, q, e})).norm(), 1e-12);
    // The frontend's right column slid by s dv: dv explains it, the same residual as unslid
    // (exactly where the column gains do not depend on the measured pixels: no image block,
    // no rectification map).
    StereoPixels slid = s.pixels;
    slid.u_right += gain * dv[0];
    std::unique_ptr<ceres::CostFunction> row_slid(
        StereoPixelRowCalibrationFactor::Create(rig, s.landmark, slid, gain, pan, C, mode, nullptr, kRate));
    const double tolerance = rig.calibration() ? 0.02 : 1e-9;
    EXPECT_LT((evaluateResiduals(*row_slid, {p, q, dv}) - evaluateResiduals(*calib, {p, q})).norm(), tolerance);
    EXPECT_GT((evaluateResiduals(*row_slid, {p, q, zero}) - evaluateResiduals(*calib, {p, q})).norm(), 0.5 * std::fabs(gain * dv[0]));
    const FactorCheck a = checkFactorJacobians(*row, {p, q, dv});
    EXPECT_TRUE(a.ok) << a.message;
    const FactorCheck b = checkFactorJacobians(*row_image, {p, q, e, dv});
    EXPECT_TRUE(b.ok) << b.message;
  });
  const test::Sighting s = test::sight(StereoRig(), Pose2(), 0.0, 900, 0.1, 60);
  EXPECT_THROW(StereoPixelRowCalibrationFactor::Create(StereoRig(), s.landmark, s.pixels, std::nan(""), 0.0,
                                                       Eigen::Matrix4d::Identity(), PixelResiduals::All, nullptr, kRate),
               Error);
}

}  // namespace
}  // namespace stereoloc

#include "factors/stereo_pixel_feature_calibration_factor.h"

namespace stereoloc {
namespace {

// The feature offsets: with (b_c, b_d) = 0 the factor is the row factor; both columns moved by
// b_c and the right one by b_d more are explained by them; Jacobians against central
// differences, with and without the image block.
TEST(StereoPixelFeatureCalibrationFactor, ZeroOffsetEqualsTheRowFactorOffsetIsExplainedAndJacobiansMatch) {
  const stereo_pixel_calibration::ImageErrorVector sigma = checkedImageSigmas();
  forEachCalibrationCase(29, [&](const StereoRig& rig, PixelResiduals mode, const test::Sighting& s, double pan,
                                 const double* p, const double* q, const double* e, auto& uniform) {
    const double gain = 1.5 * uniform(), zero[2] = {0.0, 0.0}, dv[1] = {1.4 * uniform()},
                 b[2] = {0.5 * uniform(), 0.8 * uniform()};
    const Eigen::Matrix4d C = 0.3 * Eigen::Matrix4d::Identity();
    std::unique_ptr<ceres::CostFunction> feature(
        StereoPixelFeatureCalibrationFactor::Create(rig, s.landmark, s.pixels, gain, pan, C, mode, nullptr, kRate));
    std::unique_ptr<ceres::CostFunction> feature_image(
        StereoPixelFeatureCalibrationFactor::Create(rig, s.landmark, s.pixels, gain, pan, C, mode, &sigma, kRate));
    std::unique_ptr<ceres::CostFunction> row(
        StereoPixelRowCalibrationFactor::Create(rig, s.landmark, s.pixels, gain, pan, C, mode, nullptr, kRate));
    std::unique_ptr<ceres::CostFunction> row_image(
        StereoPixelRowCalibrationFactor::Create(rig, s.landmark, s.pixels, gain, pan, C, mode, &sigma, kRate));
    EXPECT_LT((evaluateResiduals(*feature, {p, q, dv, zero}) - evaluateResiduals(*row, {p, q, dv})).norm(), 1e-12);
    EXPECT_LT((evaluateResiduals(*feature_image, {p, q, e, dv, zero}) - evaluateResiduals(*row_image, {p, q, e, dv})).norm(), 1e-12);
    StereoPixels moved = s.pixels;
    moved.u_left += b[0];
    moved.u_right += b[0] + b[1];
    std::unique_ptr<ceres::CostFunction> feature_moved(
        StereoPixelFeatureCalibrationFactor::Create(rig, s.landmark, moved, gain, pan, C, mode, nullptr, kRate));
    const double tolerance = rig.calibration() ? 0.02 : 1e-9;
    EXPECT_LT((evaluateResiduals(*feature_moved, {p, q, dv, b}) - evaluateResiduals(*row, {p, q, dv})).norm(), tolerance);
    EXPECT_GT((evaluateResiduals(*feature_moved, {p, q, dv, zero}) - evaluateResiduals(*row, {p, q, dv})).norm(),
              0.5 * std::max(std::fabs(b[0]), std::fabs(b[1])));
    const FactorCheck c1 = checkFactorJacobians(*feature, {p, q, dv, b});
    EXPECT_TRUE(c1.ok) << c1.message;
    const FactorCheck c2 = checkFactorJacobians(*feature_image, {p, q, e, dv, b});
    EXPECT_TRUE(c2.ok) << c2.message;
  });
  const test::Sighting s = test::sight(StereoRig(), Pose2(), 0.0, 900, 0.1, 60);
  EXPECT_THROW(StereoPixelFeatureCalibrationFactor::Create(StereoRig(), s.landmark, s.pixels, std::nan(""), 0.0,
                                                           Eigen::Matrix4d::Identity(), PixelResiduals::All, nullptr, kRate),
               Error);
}

}  // namespace
}  // namespace stereoloc

#include "factors/held_entries.h"
#include "factors/joined_global_blocks.h"

namespace stereoloc {
namespace {

// The dynamic prior whitens each entry by its sigma; its Jacobian is the inverse sigmas.
TEST(DiagonalPriorFactor, WhitensEachEntryAndJacobianMatches) {
  const Eigen::VectorXd mean = Eigen::Vector4d(1.0, 0.0, -2.0, 0.5);
  const Eigen::VectorXd sigma = Eigen::Vector4d(0.1, 2.0, 0.5, 1.0);
  DiagonalPriorFactor f(mean, sigma);
  const double c[4] = {1.2, -1.0, -2.0, 0.0};
  const Eigen::VectorXd r = evaluateResiduals(f, {c});
  EXPECT_NEAR(r[0], 2.0, 1e-12);
  EXPECT_NEAR(r[1], -0.5, 1e-12);
  EXPECT_NEAR(r[2], 0.0, 1e-12);
  EXPECT_NEAR(r[3], -0.5, 1e-12);
  const FactorCheck check = checkFactorJacobians(f, {c});
  EXPECT_TRUE(check.ok) << check.message;
  EXPECT_THROW(DiagonalPriorFactor(mean, Eigen::VectorXd::Zero(4)), Error);
  EXPECT_THROW(DiagonalPriorFactor(mean, Eigen::VectorXd::Ones(3)), Error);
}

// With a full covariance the squared residual is the Mahalanobis distance, correlations
// included; the Jacobian is the square-root information.
TEST(DensePriorFactor, WhitensByTheFullCovarianceAndJacobianMatches) {
  Eigen::VectorXd mean(3);
  mean << 1.0, 0.0, -2.0;
  Eigen::MatrixXd covariance(3, 3);
  covariance << 4.0, 1.5, 0.2, 1.5, 1.0, -0.3, 0.2, -0.3, 0.5;
  DensePriorFactor f(mean, covariance);
  const double c[3] = {1.5, -0.4, -1.1};
  const Eigen::VectorXd r = evaluateResiduals(f, {c});
  Eigen::VectorXd e(3);
  for (int i = 0; i < 3; ++i) e[i] = c[i] - mean[i];
  EXPECT_NEAR(r.squaredNorm(), e.dot(covariance.ldlt().solve(e)), 1e-12);
  const FactorCheck check = checkFactorJacobians(f, {c});
  EXPECT_TRUE(check.ok) << check.message;
  Eigen::MatrixXd singular = covariance;
  singular.row(1).setZero();
  singular.col(1).setZero();
  EXPECT_THROW(DensePriorFactor(mean, singular), Error);
  EXPECT_THROW(DensePriorFactor(mean, Eigen::MatrixXd::Identity(2, 2)), Error);
}

// Joined into one global block with entries scattered and one held at zero, the feature factor
// gives the residual of its own blocks and Jacobians that agree with central differences.
TEST(JoinedGlobalBlocks, ScattersTheInnerBlocksAndHoldsUnmappedEntriesAtZero) {
  forEachCalibrationCase(31, [&](const StereoRig& rig, PixelResiduals mode, const test::Sighting& s, double pan,
                                 const double* p, const double* q, const double*, auto& uniform) {
    const double gain = 1.5 * uniform(), dv[1] = {1.4 * uniform()}, b[2] = {0.4 * uniform(), 0.0};
    const Eigen::Matrix4d C = 0.3 * Eigen::Matrix4d::Identity();
    ceres::CostFunction* inner =
        StereoPixelFeatureCalibrationFactor::Create(rig, s.landmark, s.pixels, gain, pan, C, mode, nullptr, kRate);
    const Eigen::VectorXd direct = evaluateResiduals(*inner, {p, q, dv, b});
    // g = [dv, q (6), unused, b_c]; b_d held at zero.
    std::vector<std::vector<int>> indices{{1, 2, 3, 4, 5, 6}, {0}, {8, -1}};
    JoinedGlobalBlocks joined(inner, indices, 10);
    ASSERT_EQ(joined.parameter_block_sizes()[1], 10);
    double g[10] = {dv[0], q[0], q[1], q[2], q[3], q[4], q[5], 0.7, b[0], -0.3};
    EXPECT_LT((evaluateResiduals(joined, {p, g}) - direct).norm(), 1e-12);
    const FactorCheck check = checkFactorJacobians(joined, {p, g});
    EXPECT_TRUE(check.ok) << check.message;
  });
  EXPECT_THROW(JoinedGlobalBlocks(StereoPixelFeatureCalibrationFactor::Create(
                                      StereoRig(), test::sight(StereoRig(), Pose2(), 0.0, 900, 0.1, 60).landmark,
                                      test::sight(StereoRig(), Pose2(), 0.0, 900, 0.1, 60).pixels, 0.0, 0.0,
                                      Eigen::Matrix4d::Identity(), PixelResiduals::All, nullptr, kRate),
                                  {{0, 1, 2, 3, 4, 5}, {6}}),
               Error);
}

// A goal corner's feature block in the window: only b_c is a parameter, b_d held at zero. The
// residual is the inner factor's with b_d = 0 and the Jacobians agree with central differences;
// keeping both entries reproduces the inner factor.
TEST(HeldEntries, KeepsTheStatedEntriesOfTheLastBlockAndHoldsTheOthersAtZero) {
  forEachCalibrationCase(37, [&](const StereoRig& rig, PixelResiduals mode, const test::Sighting& s, double pan,
                                 const double* p, const double* q, const double* e, auto& uniform) {
    const double gain = 1.5 * uniform(), dv[1] = {1.4 * uniform()}, b[2] = {0.4 * uniform(), 0.0};
    const Eigen::Matrix4d C = 0.3 * Eigen::Matrix4d::Identity();
    const stereo_pixel_calibration::ImageErrorVector sigmas = stereo_pixel_calibration::ImageErrorVector::Constant(0.002);
    for (const bool image : {false, true}) {
      auto inner = [&] {
        return StereoPixelFeatureCalibrationFactor::Create(rig, s.landmark, s.pixels, gain, pan, C, mode,
                                                           image ? &sigmas : nullptr, kRate);
      };
      const std::unique_ptr<ceres::CostFunction> direct_cost(inner());
      const double b_c[1] = {b[0]};
      std::vector<const double*> full{p, q}, held{p, q};
      if (image) {
        full.push_back(e);
        held.push_back(e);
      }
      full.insert(full.end(), {dv, b});
      held.insert(held.end(), {dv, b_c});
      HeldEntries column(inner(), {0});
      ASSERT_EQ(column.parameter_block_sizes().back(), 1);
      EXPECT_LT((evaluateResiduals(column, held) - evaluateResiduals(*direct_cost, full)).norm(), 1e-12);
      const FactorCheck check = checkFactorJacobians(column, held);
      EXPECT_TRUE(check.ok) << check.message;
      HeldEntries both(inner(), {0, 1});
      EXPECT_LT((evaluateResiduals(both, full) - evaluateResiduals(*direct_cost, full)).norm(), 1e-12);
    }
  });
  auto factor = [] {
    const test::Sighting s = test::sight(StereoRig(), Pose2(), 0.0, 900, 0.1, 60);
    return StereoPixelFeatureCalibrationFactor::Create(StereoRig(), s.landmark, s.pixels, 0.0, 0.0,
                                                       Eigen::Matrix4d::Identity(), PixelResiduals::All, nullptr, kRate);
  };
  EXPECT_THROW(HeldEntries(factor(), {}), Error);
  EXPECT_THROW(HeldEntries(factor(), {1, 0}), Error);
  EXPECT_THROW(HeldEntries(factor(), {2}), Error);
}

}  // namespace
}  // namespace stereoloc

namespace stereoloc {
namespace {

// The image block's exposure offset: a right column measured dt after the left on a moving
// robot (src/core/exposure_offset.h's rightColumnAfter, the rig's own geometry) is explained by
// e_11 = dt / sigma, to rounding, on rigs with and without tilt and rectification map; at rest
// the entry does nothing.
TEST(StereoPixelImageCalibrationFactor, TheExposureOffsetExplainsARightColumnTakenLater) {
  const stereo_pixel_calibration::ImageErrorVector sigma = checkedImageSigmas();
  const double q[6] = {0, 1, 0, 0, 0, 0};
  const double dt = 0.004;  // s
  for (const StereoRig& rig : {StereoRig(), tiltedRig(), distortedRig()}) {
    const Pose2 pose(200.0, -100.0, 0.4);
    const double p[3] = {pose.x, pose.y, pose.theta};
    for (double bearing : {-0.4, 0.0, 0.3}) {
      const test::Sighting s = test::sight(rig, pose, 0.1, 1100, bearing, 60);
      StereoPixels later = s.pixels;
      later.u_right = rightColumnAfter(rig, s.pixels, 0.1, kRate, dt);
      ASSERT_GT(std::fabs(later.u_right - s.pixels.u_right), 0.5);
      const double zero[12] = {0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0};
      double e[12] = {0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0};
      std::unique_ptr<ceres::CostFunction> at(StereoPixelImageCalibrationFactor::Create(
          rig, s.landmark, s.pixels, 0.1, Eigen::Matrix4d::Identity(), PixelResiduals::All, sigma, kRate));
      std::unique_ptr<ceres::CostFunction> taken_later(StereoPixelImageCalibrationFactor::Create(
          rig, s.landmark, later, 0.1, Eigen::Matrix4d::Identity(), PixelResiduals::All, sigma, kRate));
      std::unique_ptr<ceres::CostFunction> standing(StereoPixelImageCalibrationFactor::Create(
          rig, s.landmark, later, 0.1, Eigen::Matrix4d::Identity(), PixelResiduals::All, sigma, BodyRate()));
      const Eigen::VectorXd without = evaluateResiduals(*taken_later, {p, q, e});
      const Eigen::VectorXd still = evaluateResiduals(*standing, {p, q, e});
      e[stereo_pixel_calibration::kExposureOffsetEntry] = dt / sigma[stereo_pixel_calibration::kExposureOffsetEntry];
      EXPECT_LT((evaluateResiduals(*taken_later, {p, q, e}) - evaluateResiduals(*at, {p, q, zero})).norm(), 1e-6);
      EXPECT_GT(without.norm(), 0.5);
      EXPECT_LT((evaluateResiduals(*standing, {p, q, e}) - still).norm(), 1e-12);
    }
  }
  EXPECT_THROW(StereoPixelImageCalibrationFactor::Create(StereoRig(), Eigen::Vector3d(1000, 0, 60),
                                                         *StereoRig().project(Eigen::Vector3d(1000, 0, 60), 0.0), 0.0,
                                                         Eigen::Matrix4d::Identity(), PixelResiduals::All, sigma,
                                                         BodyRate{std::nan(""), 0.0}),
               Error);
}

}  // namespace
}  // namespace stereoloc
