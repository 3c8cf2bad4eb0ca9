#pragma once
// Odometry factor with the wheel calibration as parameters (self-calibration, thesis appendix B
// with the wheel scales and the wheel base unknown), written where the noise lives: in the
// encoder readings.
//
//   r = ( S [d_l(p_{k-1}, p_k; w) / c_l - m_l;                                   3 residuals
//            d_r(p_{k-1}, p_k; w) / c_r - m_r],
//         lateral(p_{k-1}, p_k) / sigma_lat )
//
// p_{k-1}, p_k: poses (x, y, theta), world frame (mm, mm, rad). c = (c_l, c_r, w): calibration
// block, c_l and c_r the true distance per mm of encoder reading of each wheel (dimensionless,
// nominally 1; a wheel whose true radius is r (1 + e) has c = 1 + e), w the effective wheel base
// (mm). m_l, m_r: the encoder readings of step k (mm). The motion between the poses, rel =
// betweenT(p_{k-1}, p_k), is read as the arc of (B.1)-(B.5): with h = dtheta / 2 its chord leaves
// at angle h, so along = rel_x cos h + rel_y sin h is the chord (signed) and lateral =
// -rel_x sin h + rel_y cos h is zero on an arc; the arc length is L = along h / sin h and the
// wheels roll d_l = L - w h, d_r = L + w h (the inverse of B.1, B.2). S: upper square-root
// information of the readings' 2x2 covariance, (B.6) at the noise travel t (wheelCovariance;
// NoiseTravel in src/core/odometry_model.h: not at the readings themselves, whose noise such a
// weight would correlate with, biasing the wheel base low by about k / |d|) plus the
// control variance floor's x and theta terms carried into wheel space (L = (d_l + d_r) / 2,
// dtheta = (d_r - d_l) / w: floor_x [1 1; 1 1] + floor_theta w^2 / 4 [1 -1; -1 1], w nominal), so
// that at the nominal calibration the factor weighs a motion as the control-vector factor does,
// standstill included; sigma_lat: the lateral slip the model allows, the square root of the
// floor's y term (src/core/odometry_model.h).
// Why wheel space, not the control-vector form of factors/odometry_factor.h: with the wheel base
// unknown, the control form's weight U ~ 1 / w^2 would have to move with w; held fixed, its
// estimate of w is that of a regression on noisy regressors and comes out too large (on a
// 1500-step random walk with the simulator's encoder noise: +2.7 mm on 77 mm, 8 sigma).
// h / sin h uses its series for |h| < 1e-4, so straight lines and turns on the spot (L = 0)
// are both smooth.
#include <ceres/cost_function.h>

#include <Eigen/Core>
#include <cmath>

#include "src/core/angles.h"
#include "src/core/error.h"
#include "src/core/gaussian.h"
#include "src/core/odometry_model.h"
#include "src/core/pose2.h"

namespace stereoloc {

struct OdometryCalibrationFactor {
  // sqrt_information: upper square-root information of the readings' 2x2 covariance.
  OdometryCalibrationFactor(double m_left, double m_right, const Eigen::Matrix2d& sqrt_information, double sigma_lateral)
      : m_left_(m_left), m_right_(m_right), S_(sqrt_information), inv_lat_(1.0 / sigma_lateral) {}

  template <typename T>
  bool operator()(const T* prev, const T* curr, const T* calib, T* residual) const {
    using std::abs;
    using std::cos;
    using std::sin;
    if (!(calib[0] > T(0.0) && calib[1] > T(0.0) && calib[2] > T(0.0))) return false;
    T rel[3];
    betweenT(prev, curr, rel);
    const T h = 0.5 * rel[2];
    const T ch = cos(h), sh = sin(h);
    const T along = rel[0] * ch + rel[1] * sh;
    const T lateral = -rel[0] * sh + rel[1] * ch;
    const T h2 = h * h;
    const T ratio = abs(h) < T(1e-4) ? T(1.0) + h2 / 6.0 + 7.0 * h2 * h2 / 360.0 : h / sh;  // h / sin h
    const T L = along * ratio;
    const T d_left = L - calib[2] * h, d_right = L + calib[2] * h;
    const T e_left = d_left / calib[0] - T(m_left_), e_right = d_right / calib[1] - T(m_right_);
    residual[0] = T(S_(0, 0)) * e_left + T(S_(0, 1)) * e_right;
    residual[1] = T(S_(1, 1)) * e_right;
    residual[2] = T(inv_lat_) * lateral;
    return true;
  }

  // Blocks: previous pose (3), current pose (3), calibration (c_l, c_r, w) (3).
  // noise_travel: t (mm); params: the odometry model at t (slip included).
  static ceres::CostFunction* Create(double m_left, double m_right, const WheelIncrements& noise_travel,
                                     const OdometryParams& params);

 private:
  double m_left_, m_right_;
  Eigen::Matrix2d S_;
  double inv_lat_;
};

}  // namespace stereoloc
