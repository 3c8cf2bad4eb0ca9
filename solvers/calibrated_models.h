#pragma once
// The measurement and motion models seen through a self-calibration's parameters
// (solvers/self_calibration.h), for the estimators that linearise them themselves: the
// calibrating EKF (solvers/ekf.h) and the sliding window's gate and association
// (solvers/sliding_window_smoother.h). The smoothers' factors carry the same models
// (factors/stereo_pixel_calibration_factor.h, factors/odometry_calibration_factor.h).
#include <Eigen/Core>

#include "solvers/self_calibration.h"
#include "src/core/odometry_model.h"
#include "src/core/pose2.h"
#include "src/core/stereo_rig.h"
#include "src/core/types.h"

namespace stereoloc {

// The prior standard deviations of the stereo block (CalibrationEstimate::head's order and
// units) and of the wheel block (c_l, c_r dimensionless, w in mm, about the wheel base
// `wheel_base_mm`) that `config` states.
CalibrationEstimate::StereoVector stereoPriorSigma(const SelfCalibrationConfig& config);
Eigen::Vector3d wheelPriorSigma(const SelfCalibrationConfig& config, double wheel_base_mm);
// The range block's (c0, c1, c2, d_b; RangeBearingCalibrationFactor).
Eigen::Vector4d rangePriorSigma(const SelfCalibrationConfig& config);
// The field block's prior covariance (kFieldDimensions, mm^2): the one `map` states
// (FieldMap::dimensionCovariance: a field an earlier drive measured), else
// config.field_dimension_sigma_mm squared on the diagonal.
FieldDimensionMatrix fieldPriorCovariance(const SelfCalibrationConfig& config, const FieldMap& map);

// What a step with wheel increments d_left, d_right (mm) adds to the variances of the wheel
// block (c_l, c_r, w mm) of a calibration that drifts (UnmodelledNoise::wheel_scale_drift,
// wheel_base_drift): s^2 |d_l| / 1000, s^2 |d_r| / 1000 and (b w)^2 (|d_l| + |d_r|) / 2000, w
// the nominal wheel base `wheel_base_mm`.
Eigen::Vector3d wheelDriftVariance(const UnmodelledNoise& noise, double d_left, double d_right, double wheel_base_mm);

// A range-bearing observation as a sensor with range block k would have reported it with k = 0:
// range divided by 1 + c0 + c1 b + c2 b^2 (b its measured bearing), bearing less d_b, R's range
// row and column divided alike, plus the uncertainty of k (covariance Ck) as J Ck J^T (the
// sliding window's gate and association read it). Throws stereoloc::Error when the factor is
// not positive.
Observation withRangeCalibration(const Observation& obs, const Eigen::Vector4d& k, const Eigen::Matrix4d& Ck);

// Range and bearing (3.6, 3.7) of the point that stereo calibration q (CalibrationEstimate::head)
// puts at the observation's pixels, with J_rb_px = d(range, bearing) / d(u_l, v_l, u_r, v_r) and
// J_rb_q = d(range, bearing) / dq (central differences; bearing differences wrapped). At the
// nominal q it is the rig's own triangulation. Throws GeometryError when the corrected disparity
// is not positive; `obs` must have pixels (stereoloc::Error otherwise).
struct CalibratedRangeBearing {
  Eigen::Vector2d z = Eigen::Vector2d::Zero();  // range (mm), bearing (rad)
  Eigen::Matrix<double, 2, 4> J_rb_px = Eigen::Matrix<double, 2, 4>::Zero();
  Eigen::Matrix<double, 2, 6> J_rb_q = Eigen::Matrix<double, 2, 6>::Zero();
};
CalibratedRangeBearing calibratedRangeBearing(const Observation& obs, const StereoRig& rig,
                                              const CalibrationEstimate::StereoVector& q);

// A stereo sighting of a landmark at `landmark` (mm, world) from pose p through stereo
// calibration q and row offset dv (px; the right column's slide s dv taken out first, s the
// observation's slide gain): the innovation nu = z(q, dv) [-] h(p) (range mm, bearing rad
// wrapped) and its Jacobians, d nu / dp = -H_p (5.27), d nu / dq = J_z_q, d nu / ddv =
// -s J_z_u_r. J_z_px gives the observation's noise, R = J_z_px C_px J_z_px^T. Throws
// GeometryError when the corrected disparity is not positive or the landmark is at the pose.
struct CalibratedSighting {
  Eigen::Vector2d nu = Eigen::Vector2d::Zero();
  Eigen::Matrix<double, 2, 3> J_nu_pose = Eigen::Matrix<double, 2, 3>::Zero();
  Eigen::Matrix<double, 2, 6> J_nu_q = Eigen::Matrix<double, 2, 6>::Zero();
  Eigen::Vector2d J_nu_row = Eigen::Vector2d::Zero();
  Eigen::Matrix<double, 2, 4> J_z_px = Eigen::Matrix<double, 2, 4>::Zero();
};
CalibratedSighting calibratedSighting(const Observation& obs, const StereoRig& rig, const Pose2& pose,
                                      const Eigen::Vector2d& landmark, const CalibrationEstimate::StereoVector& q,
                                      double row_offset_px);

// The observation as the cameras of stereo calibration q see it, with covariance Cq of q:
// calibratedRangeBearing, and R = J_px C_px J_px^T + J_q Cq J_q^T, C_px the pixel covariance. At
// the nominal q with Cq = 0 it is observationFromPixels. The window gates and associates these
// when it self-calibrates the stereo head (docs/estimators.md, "Self-calibration"). Throws as
// calibratedRangeBearing.
Observation calibratedObservation(const Observation& obs, const StereoRig& rig, const CalibrationEstimate::StereoVector& q,
                                  const CalibrationEstimate::StereoMatrix& Cq, const Eigen::Matrix4d& C_px);

// The pixel columns (u_l, u_r) in which stereo calibration q (CalibrationEstimate::head) sees a
// landmark at `landmark` (mm, world; its height included) from pose (x, y, theta): the model of
// factors/stereo_pixel_calibration_factor.h's columns, with the landmark in the right camera's
// frame C2 = R_tilt(dbeta)^T C1 (C1 the rig's vision frame at head pan `pan`),
//   u_l = o_u + delta_u + delta_d/2 - F (y - k b/2) / x,
//   u_r = o_u + delta_u - delta_d/2 - F (1 + phi) (y + k b/2) / x,   F = f (1 + psi),
// and J_u_pose = d(u_l, u_r) / d(x, y, theta). What does not depend on the pose or q is done once:
// the particle filter evaluates it for every particle's own pose and q. operator() returns false
// when the landmark is not in front of the cameras (x <= 1 mm). At the nominal q it is
// StereoRig::project.
class CalibratedColumns {
 public:
  CalibratedColumns(const StereoRig& rig, const Eigen::Vector3d& landmark, double pan);
  bool operator()(const CalibrationEstimate::StereoVector& q, double x, double y, double cos_theta, double sin_theta,
                  Eigen::Vector2d* u, Eigen::Matrix<double, 2, 3>* J_u_pose = nullptr) const;

 private:
  double focal_, centre_u_, baseline_;
  Eigen::Vector3d landmark_;
  Eigen::Matrix3d robot_to_vision_;  // R_tilt^T R_z(pan)^T (StereoRig::robotToVision)
  Eigen::Vector3d mount_;            // -R_tilt^T t: the vision frame's offset
};

// One odometry step through the wheel calibration wheels = (c_l, c_r, w) (factors/
// odometry_calibration_factor.h): rel (+) u(c_l d_left, c_r d_right, w) with the covariance of
// (5.9) (U at the scaled increments, `params` giving its noise), and, when J_c is given, the chain
// rule of (B.16)-(B.19) through the composition: on entry d rel / d wheels (3x3, columns c_l, c_r,
// w), on return that of the result. With it a prediction can carry the calibration's uncertainty
// (docs/estimators.md, "Self-calibration").
PosePrediction predictCalibratedStep(const Pose2& rel, const Eigen::Matrix3d& C, double d_left, double d_right,
                                     const Eigen::Vector3d& wheels, const OdometryParams& params,
                                     Eigen::Matrix3d* J_c = nullptr);

}  // namespace stereoloc
