#pragma once
// Odometry over several steps with the wheel calibration as parameters: the sliding window's
// factor between keyframes that have steps without observations between them, when it
// self-calibrates the odometry (the single-step form is factors/odometry_calibration_factor.h).
//
//   r = S(c) (betweenT(p_a, p_b) [-] g(c))                                     3 residuals
//   g(c) = u_1(c) (+) u_2(c) (+) ... (+) u_n(c),
//   u_i(c) = controlVector(c_l m_l,i, c_r m_r,i, w)                            (B.1)-(B.5)
//   P(c):  P_0 = 0,  P_i = J1 P_{i-1} J1^T + J2 U_i(c) J2^T                    (5.9)
//   U_i(c) = J_u diag(c_l^2 s_l,i^2, c_r^2 s_r,i^2) J_u^T + floor              (B.8), (B.10)
//
// p_a, p_b: the keyframe poses (x, y, theta), world frame (mm, mm, rad); c = (c_l, c_r, w): the
// wheel scales (dimensionless) and the effective wheel base (mm), as in
// odometry_calibration_factor.h; m_l,i, m_r,i: the encoder readings of the n steps from a to b
// (mm), with variances s^2 (mm^2, (B.6) plus slip, at each step's noise travel: NoiseTravel in
// src/core/odometry_model.h) in reading units, so that the travelled
// distances c m have c^2 s^2. (+) is pose composition (B.16), J1 and J2 its Jacobians (B.18,
// B.19); [-] subtracts componentwise and wraps the angle; floor: the control variance floor
// (src/core/odometry_model.h). S(c): upper square-root information of P(c).
// Why P moves with c: the readings enter g as regressors. With a weight held fixed, the
// expected cost at a calibration c is |bias(c)|^2 plus tr(S^T S P(c)), and P(c) shrinks as the
// scales shrink and the wheel base grows, which pulls the estimate there (a regression on noisy
// regressors: on MR.CLAM, with noisy odometry and keyframes seconds apart, the wheel base came
// out 6-11 % too large, ten sigma). Weighted with P(c) itself the second term is 3 at every c,
// as in the wheel-space single-step factor, whose readings' covariance does not depend on c.
// Why not one wheel-space factor per step: that needs every step as a window pose, and a
// window of W poses then spans W steps instead of W keyframes. The window uses this form only
// between keyframes more than one step apart.
// Why not AutoDiffCostFunction: g and P depend on c only, so they are differentiated with jets
// of c's 3 dimensions, and the poses enter through betweenT, whose Jacobians are written out
// (J_rel_a, J_rel_b below); with 9-dimensional jets throughout, every operation of the
// propagation would carry the poses' six zero derivatives too. The real-time window evaluates
// these factors several times per frame (bench_pipeline, BM_PipelineSelfCalibrating).
#include <ceres/sized_cost_function.h>

#include <Eigen/Core>
#include <cmath>
#include <vector>

#include "src/core/angles.h"
#include "src/core/error.h"
#include "src/core/odometry_model.h"
#include "src/core/pose2.h"

namespace stereoloc {

class ComposedOdometryCalibrationFactor final : public ceres::SizedCostFunction<3, 3, 3, 3> {
 public:
  struct Reading {
    double m_left = 0.0, m_right = 0.0;      // encoder readings (mm)
    double var_left = 0.0, var_right = 0.0;  // their variances (mm^2)
  };

  ComposedOdometryCalibrationFactor(std::vector<Reading> readings, const Eigen::Vector3d& control_floor)
      : readings_(std::move(readings)), floor_(control_floor) {}

  // g(c) and P(c) (see the header); false for a calibration outside its domain.
  template <typename T>
  bool propagate(const T* calib, Eigen::Matrix<T, 3, 1>* g_out, Eigen::Matrix<T, 3, 3>* P_out) const {
    using std::cos;
    using std::sin;
    using M3 = Eigen::Matrix<T, 3, 3>;
    using V3 = Eigen::Matrix<T, 3, 1>;
    if (!(calib[0] > T(0.0) && calib[1] > T(0.0) && calib[2] > T(0.0))) return false;
    const T w = calib[2];
    V3 g(T(0.0), T(0.0), T(0.0));
    M3 P = M3::Zero();
    for (const Reading& m : readings_) {
      const T d_left = calib[0] * m.m_left, d_right = calib[1] * m.m_right;
      const T alpha = (d_right - d_left) / w;  // (B.1)
      const T v = 0.5 * (d_right + d_left);    // (B.2)
      const ArcFunctions<T> f = arcFunctions(alpha);
      const T &S = f.S, &C = f.C, &dS = f.dS, &dC = f.dC;
      const V3 u(v * S, v * C, alpha);  // (B.4)
      Eigen::Matrix<T, 3, 2> J_u_d;     // (B.8)
      J_u_d << 0.5 * S - v * dS / w, 0.5 * S + v * dS / w,  //
          0.5 * C - v * dC / w, 0.5 * C + v * dC / w,       //
          T(-1.0) / w, T(1.0) / w;
      const T var_l = calib[0] * calib[0] * m.var_left, var_r = calib[1] * calib[1] * m.var_right;
      const T c = cos(g[2]), s = sin(g[2]);
      // (5.9) with J1 = I + k e_3^T (B.18) and U = var_l a a^T + var_r b b^T + floor (B.10),
      // a and b the columns of J_u_d, written as rank-one updates:
      //   J1 P J1^T = P + k p^T + p k^T + P_33 k k^T,  p = P e_3;
      //   J2 U J2^T = var_l (J2 a)(J2 a)^T + var_r (J2 b)(J2 b)^T + J2 floor J2^T  (B.19).
      const V3 k(-s * u[0] - c * u[1], c * u[0] - s * u[1], T(0.0));
      const V3 p = P.col(2);
      const T p33 = P(2, 2);
      auto rotate = [&](const V3& x) { return V3(c * x[0] - s * x[1], s * x[0] + c * x[1], x[2]); };
      const V3 ra = rotate(J_u_d.col(0)), rb = rotate(J_u_d.col(1));
      P += k * p.transpose() + p * k.transpose() + (p33 * k) * k.transpose() + (var_l * ra) * ra.transpose() +
           (var_r * rb) * rb.transpose();
      const T f0 = T(floor_[0]), f1 = T(floor_[1]);
      P(0, 0) += c * c * f0 + s * s * f1;
      P(1, 1) += s * s * f0 + c * c * f1;
      P(0, 1) += c * s * (f0 - f1);
      P(1, 0) += c * s * (f0 - f1);
      P(2, 2) += T(floor_[2]);
      g += rotate(u);  // (B.16)
    }
    *g_out = g;
    *P_out = P;
    return true;
  }

  bool Evaluate(double const* const* parameters, double* residuals, double** jacobians) const override;

  // Blocks: pose a (3), pose b (3), calibration (c_l, c_r, w) (3). noise_travel: each step's
  // travel (mm) at which params, its odometry model (slip included), gives the reading's
  // variances; the steps' control floors must agree.
  static ceres::CostFunction* Create(const std::vector<std::pair<double, double>>& readings,
                                     const std::vector<WheelIncrements>& noise_travel,
                                     const std::vector<OdometryParams>& params);

 private:
  std::vector<Reading> readings_;
  Eigen::Vector3d floor_;
};

}  // namespace stereoloc
