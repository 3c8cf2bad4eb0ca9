#include "solvers/calibrated_models.h"

#include <cmath>

#include "src/core/angles.h"
#include "src/core/error.h"
#include "src/core/measurement_model.h"
#include "src/core/pose2.h"

namespace stereoloc {
namespace {

// Range and bearing (3.6, 3.7) of the point that stereo calibration q puts at `px`: the model of
// factors/stereo_pixel_calibration_factor.h solved for the point in C2,
//   a = (y - k b/2) / x = -(u_l - o_u - delta_u - delta_d/2) / F,
//   c = (y + k b/2) / x = -(u_r - o_u - delta_u + delta_d/2) / (F (1 + phi)),
//   x = k b / (c - a),  y = x (a + c) / 2,  z = -x (v - o_v) / F  (v the rows' mean, F = f (1 + psi)),
// then rotated by the tilt correction (C1 = R_tilt(beta) R_tilt(dbeta) C2) into the robot frame.
// False when the corrected disparity is not positive.
bool triangulateCalibrated(const StereoRig& rig, const double* px, double pan, const double* q, Eigen::Vector2d* rb) {
  const double F = rig.focal() * (1.0 + q[5]);
  const double a = -(px[0] - rig.principalU() - q[3] - 0.5 * q[2]) / F;
  const double c = -(px[2] - rig.principalU() - q[3] + 0.5 * q[2]) / (F * (1.0 + q[4]));
  const double kb = q[1] * rig.params().baseline_mm;
  if (!(c - a > 0) || !(kb > 0)) return false;
  const double x = kb / (c - a);
  const double y = 0.5 * x * (a + c);
  const double z = -x * (0.5 * (px[1] + px[3]) - rig.principalV()) / F;
  const double cb = std::cos(q[0]), sb = std::sin(q[0]);
  const Eigen::Vector3d p = rig.visionToRobot(Eigen::Vector3d(cb * x + sb * z, y, -sb * x + cb * z), pan);
  const double r = std::hypot(p.x(), p.y());
  if (!(r > 1e-9) || !std::isfinite(r)) return false;
  *rb = Eigen::Vector2d(r, std::atan2(p.y(), p.x()));
  return true;
}

}  // namespace

CalibrationEstimate::StereoVector stereoPriorSigma(const SelfCalibrationConfig& c) {
  CalibrationEstimate::StereoVector s;
  s << c.tilt_sigma_rad, c.baseline_scale_sigma, c.disparity_offset_sigma_px, c.column_offset_sigma_px,
      c.focal_ratio_sigma, c.focal_scale_sigma;
  return s;
}

Eigen::Vector4d rangePriorSigma(const SelfCalibrationConfig& c) {
  return Eigen::Vector4d(c.range_scale_sigma, c.range_scale_slope_sigma, c.range_scale_curvature_sigma,
                         c.bearing_offset_sigma_rad);
}

FieldDimensionMatrix fieldPriorCovariance(const SelfCalibrationConfig& c, const FieldMap& map) {
  if (map.dimensionCovariance()) return *map.dimensionCovariance();
  return FieldDimensionMatrix::Identity() * (c.field_dimension_sigma_mm * c.field_dimension_sigma_mm);
}

Observation withRangeCalibration(const Observation& obs, const Eigen::Vector4d& k, const Eigen::Matrix4d& Ck) {
  const double b = obs.bearing;
  const double f = rangeFactorAt(k.data(), b);
  if (!(f > 0)) throw Error("range calibration: the range factor is not positive at this bearing");
  Observation out = obs;
  out.range = obs.range / f;
  out.bearing = wrapAngle(obs.bearing - k[3]);
  const Eigen::Vector2d scale(1.0 / f, 1.0);
  // d(range / f) / dc = -(range / f^2) df/dc; d(bearing - d_b) / dd_b = -1.
  Eigen::Matrix<double, 2, 4> J_z_k = Eigen::Matrix<double, 2, 4>::Zero();
  J_z_k.row(0).head<3>() = -(out.range / f) * rangeFactorGradient(b).transpose();
  J_z_k(1, 3) = -1.0;
  out.covariance = scale.asDiagonal() * obs.covariance * scale.asDiagonal() + J_z_k * Ck * J_z_k.transpose();
  return out;
}

Eigen::Vector3d wheelPriorSigma(const SelfCalibrationConfig& c, double wheel_base_mm) {
  return Eigen::Vector3d(c.wheel_scale_sigma, c.wheel_scale_sigma, c.wheel_base_rel_sigma * wheel_base_mm);
}

Eigen::Vector3d wheelDriftVariance(const UnmodelledNoise& noise, double d_left, double d_right, double wheel_base_mm) {
  const double s2 = noise.wheel_scale_drift * noise.wheel_scale_drift;
  const double b = noise.wheel_base_drift * wheel_base_mm;
  const double l_m = std::fabs(d_left) / 1000.0, r_m = std::fabs(d_right) / 1000.0;  // m
  return Eigen::Vector3d(s2 * l_m, s2 * r_m, b * b * 0.5 * (l_m + r_m));
}

CalibratedRangeBearing calibratedRangeBearing(const Observation& obs, const StereoRig& rig,
                                              const CalibrationEstimate::StereoVector& q) {
  if (!obs.pixels) throw Error("calibratedRangeBearing: the observation has no pixels");
  const StereoPixels& s = *obs.pixels;
  double px[4] = {s.u_left, s.v_left, s.u_right, s.v_right};
  CalibrationEstimate::StereoVector qq = q;
  CalibratedRangeBearing out;
  if (!triangulateCalibrated(rig, px, obs.head_pan, qq.data(), &out.z))
    throw GeometryError("calibratedRangeBearing: the calibrated disparity is not positive");
  // Central differences; steps well inside each parameter's scale (px, rad, dimensionless).
  auto column = [&](double* v, double h) {
    const double v0 = *v;
    Eigen::Vector2d plus_rb, minus_rb;
    *v = v0 + h;
    const bool ok_plus = triangulateCalibrated(rig, px, obs.head_pan, qq.data(), &plus_rb);
    *v = v0 - h;
    const bool ok_minus = triangulateCalibrated(rig, px, obs.head_pan, qq.data(), &minus_rb);
    *v = v0;
    if (!ok_plus || !ok_minus) throw GeometryError("calibratedRangeBearing: the calibrated disparity is not positive");
    Eigen::Vector2d d = plus_rb - minus_rb;
    d(1) = angleDiff(plus_rb(1), minus_rb(1));
    return Eigen::Vector2d(d / (2.0 * h));
  };
  for (int i = 0; i < 4; ++i) out.J_rb_px.col(i) = column(&px[i], 1e-4);
  const double steps[6] = {1e-7, 1e-7, 1e-4, 1e-4, 1e-7, 1e-7};
  for (int i = 0; i < 6; ++i) out.J_rb_q.col(i) = column(&qq[i], steps[i]);
  return out;
}

CalibratedSighting calibratedSighting(const Observation& obs, const StereoRig& rig, const Pose2& pose,
                                      const Eigen::Vector2d& landmark, const CalibrationEstimate::StereoVector& q,
                                      double row_offset_px) {
  Observation slid = obs;
  if (slid.pixels) slid.pixels->u_right -= obs.slide_gain * row_offset_px;
  const CalibratedRangeBearing c = calibratedRangeBearing(slid, rig, q);
  Matrix23d H_p;
  const Eigen::Vector2d zhat = predictRangeBearing(pose, landmark, &H_p);  // (5.27)
  CalibratedSighting out;
  out.nu = rangeBearingInnovation(c.z, zhat);
  out.J_nu_pose = -H_p;
  out.J_nu_q = c.J_rb_q;
  out.J_nu_row = -obs.slide_gain * c.J_rb_px.col(2);
  out.J_z_px = c.J_rb_px;
  return out;
}

Observation calibratedObservation(const Observation& obs, const StereoRig& rig, const CalibrationEstimate::StereoVector& q,
                                  const CalibrationEstimate::StereoMatrix& Cq, const Eigen::Matrix4d& C_px) {
  const CalibratedRangeBearing c = calibratedRangeBearing(obs, rig, q);
  Observation out = obs;
  out.range = c.z(0);
  out.bearing = c.z(1);
  const Eigen::Matrix2d R = c.J_rb_px * C_px * c.J_rb_px.transpose() + c.J_rb_q * Cq * c.J_rb_q.transpose();
  out.covariance = 0.5 * (R + R.transpose());
  out.single_view_share = 1.0;  // R holds the calibration's uncertainty, which one view does not shrink
  return out;
}

CalibratedColumns::CalibratedColumns(const StereoRig& rig, const Eigen::Vector3d& landmark, double pan)
    : focal_(rig.focal()), centre_u_(rig.principalU()), baseline_(rig.params().baseline_mm), landmark_(landmark) {
  // robotToVision is affine: R_tilt^T (R_z(pan)^T p - t).
  mount_ = rig.robotToVision(Eigen::Vector3d::Zero(), pan);
  for (int j = 0; j < 3; ++j) robot_to_vision_.col(j) = rig.robotToVision(Eigen::Vector3d::Unit(j), pan) - mount_;
}

bool CalibratedColumns::operator()(const CalibrationEstimate::StereoVector& q, double x, double y, double cos_theta,
                                   double sin_theta, Eigen::Vector2d* u, Eigen::Matrix<double, 2, 3>* J_u_pose) const {
  // The landmark in the robot frame (5.27's rotation), then in C1 and C2.
  const double dx = landmark_.x() - x, dy = landmark_.y() - y;
  const Eigen::Vector3d p_robot(cos_theta * dx + sin_theta * dy, -sin_theta * dx + cos_theta * dy, landmark_.z());
  const Eigen::Vector3d c1 = robot_to_vision_ * p_robot + mount_;
  const double cb = std::cos(q[0]), sb = std::sin(q[0]);
  const double x2 = cb * c1.x() - sb * c1.z(), y2 = c1.y();
  if (!(x2 > 1.0)) return false;
  const double F = focal_ * (1.0 + q[5]), Fr = F * (1.0 + q[4]), half_kb = 0.5 * q[1] * baseline_;
  *u = Eigen::Vector2d(centre_u_ + q[3] + 0.5 * q[2] - F * (y2 - half_kb) / x2,
                       centre_u_ + q[3] - 0.5 * q[2] - Fr * (y2 + half_kb) / x2);
  if (J_u_pose) {
    Eigen::Matrix<double, 2, 2> J_u_c2;  // d(u_l, u_r) / d(x2, y2)
    J_u_c2 << F * (y2 - half_kb) / (x2 * x2), -F / x2, Fr * (y2 + half_kb) / (x2 * x2), -Fr / x2;
    Eigen::Matrix<double, 2, 3> J_c2_c1;
    J_c2_c1 << cb, 0.0, -sb, 0.0, 1.0, 0.0;
    Eigen::Matrix<double, 3, 3> J_robot_pose;  // d p_robot / d(x, y, theta)
    J_robot_pose << -cos_theta, -sin_theta, p_robot.y(), sin_theta, -cos_theta, -p_robot.x(), 0.0, 0.0, 0.0;
    *J_u_pose = J_u_c2 * J_c2_c1 * robot_to_vision_ * J_robot_pose;
  }
  return true;
}

PosePrediction predictCalibratedStep(const Pose2& rel, const Eigen::Matrix3d& C, double d_left, double d_right,
                                     const Eigen::Vector3d& wheels, const OdometryParams& params, Eigen::Matrix3d* J_c) {
  OdometryParams p = params;
  p.wheel_base_mm = wheels[2];
  const double dl = wheels[0] * d_left, dr = wheels[1] * d_right;
  Matrix32d J_u;
  const Eigen::Vector3d u = controlVector(dl, dr, p.wheel_base_mm, &J_u);  // (B.4)
  Matrix3d J1, J2;
  const Pose2 next = compose(rel, Pose2(u.x(), u.y(), u.z()), &J1, &J2);  // (B.16)-(B.19)
  const Eigen::Matrix3d U = controlCovariance(dl, dr, p);
  const Eigen::Matrix3d P = J1 * C * J1.transpose() + J2 * U * J2.transpose();  // (5.9)
  if (J_c) {
    // u depends on the scales through the scaled increments (B.8), and on w only through
    // alpha = (d_r - d_l) / w (B.1): du/dalpha = (w / 2)(du/dd_r - du/dd_l) and dalpha/dw = -alpha / w.
    Matrix3d D;
    D.col(0) = J_u.col(0) * d_left;
    D.col(1) = J_u.col(1) * d_right;
    D.col(2) = -0.5 * u.z() * (J_u.col(1) - J_u.col(0));
    *J_c = J1 * *J_c + J2 * D;
  }
  return PosePrediction{next, 0.5 * (P + P.transpose())};
}

}  // namespace stereoloc
