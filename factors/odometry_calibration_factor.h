#pragma once
// Odometry factor with the wheel calibration as parameters (self-calibration, thesis appendix B
// with the wheel scales and the wheel base unknown), written where the noise lives: in the
// encoder readings.
//
//   r = ( (d_l(p_{k-1}, p_k; w) / c_l - m_l) / sigma_l,                         3 residuals
//         (d_r(p_{k-1}, p_k; w) / c_r - m_r) / sigma_r,
//         lateral(p_{k-1}, p_k) / sigma_lat )
//
// p_{k-1}, p_k: poses (x, y, theta), world frame (mm, mm, rad). c = (c_l, c_r, w): calibration
// block, c_l and c_r the true distance per mm of encoder reading of each wheel (dimensionless,
// nominally 1; a wheel whose true radius is r (1 + e) has c = 1 + e), w the effective wheel base
// (mm). m_l, m_r: the encoder readings of step k (mm). The motion between the poses, rel =
// betweenT(p_{k-1}, p_k), is read as the arc of (B.1)-(B.5): with h = dtheta / 2 its chord leaves
// at angle h, so along = rel_x cos h + rel_y sin h is the chord (signed) and lateral =
// -rel_x sin h + rel_y cos h is zero on an arc; the arc length is L = along h / sin h and the
// wheels roll d_l = L - w h, d_r = L + w h (the inverse of B.1, B.2). sigma_l^2, sigma_r^2: (B.6)
// at the readings (wheelCovariance) plus the control variance floor's x term, which keeps a
// wheel that did not turn from getting infinite weight; sigma_lat: the lateral slip the model
// allows, the square root of the floor's y term (src/core/odometry_model.h).
// Why wheel space, not the control-vector form of factors/odometry_factor.h: with the wheel base
// unknown, the control form's weight U ~ 1 / w^2 would have to move with w; held fixed, its
// estimate of w is that of a regression on noisy regressors and comes out too large (on a
// 1500-step random walk with the simulator's encoder noise: +2.7 mm on 77 mm, 8 sigma).
// h / sin h uses its series for |h| < 1e-4, so straight lines and turns on the spot (L = 0)
// are both smooth.
#include <ceres/autodiff_cost_function.h>

#include <Eigen/Core>
#include <cmath>

#include "src/core/angles.h"
#include "src/core/error.h"
#include "src/core/odometry_model.h"
#include "src/core/pose2.h"

namespace stereoloc {

struct OdometryCalibrationFactor {
  OdometryCalibrationFactor(double m_left, double m_right, double sigma_left, double sigma_right, double sigma_lateral)
      : m_left_(m_left), m_right_(m_right), inv_l_(1.0 / sigma_left), inv_r_(1.0 / sigma_right),
        inv_lat_(1.0 / sigma_lateral) {}

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
    residual[0] = T(inv_l_) * (d_left / calib[0] - T(m_left_));
    residual[1] = T(inv_r_) * (d_right / calib[1] - T(m_right_));
    residual[2] = T(inv_lat_) * lateral;
    return true;
  }

  // Blocks: previous pose (3), current pose (3), calibration (c_l, c_r, w) (3).
  static ceres::CostFunction* Create(double m_left, double m_right, const OdometryParams& params) {
    params.validate();
    Eigen::Matrix2d S = wheelCovariance(m_left, m_right, params);
    S.diagonal().array() += params.control_variance_floor.x();
    const double lat = params.control_variance_floor.y();
    if (!(std::isfinite(m_left) && std::isfinite(m_right) && S(0, 0) > 0 && S(1, 1) > 0 && lat > 0))
      throw Error(
          "odometry calibration factor: readings must be finite, wheel variances and the lateral floor positive");
    return new ceres::AutoDiffCostFunction<OdometryCalibrationFactor, 3, 3, 3, 3>(
        new OdometryCalibrationFactor(m_left, m_right, std::sqrt(S(0, 0)), std::sqrt(S(1, 1)), std::sqrt(lat)));
  }

 private:
  double m_left_, m_right_, inv_l_, inv_r_, inv_lat_;
};

}  // namespace stereoloc
