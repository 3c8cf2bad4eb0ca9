#pragma once
// Differential-drive odometry (thesis appendix B): the control vector u from the wheel
// increments, its Jacobian J_u and covariance U_k, and pose compounding.
//
// Inputs are the distances travelled by the wheels during one step, d_left and d_right (mm;
// the thesis's v_lk, v_rk "per unit time"). With w the wheel base,
//   alpha = (d_r - d_l) / w        (B.1)      v = (d_r + d_l) / 2      (B.2)
//   u = (v sin(alpha)/alpha, v (1 - cos(alpha))/alpha, alpha)          (B.4, B.5 with c = v/alpha)
// We evaluate sin(a)/a and (1 - cos a)/a and their derivatives with series near a = 0, so u,
// J_u and U are exact and continuous across the straight-line limit (B.20) and finite at the
// turn on the spot v = 0 (B.24), where nothing is divided by v. (The printed B.22 has
// dy/dd = -+v/w; the correct limit is -+v/(2w). B.23 is garbled and is not used.)
#include <Eigen/Core>
#include <cmath>
#include <string>
#include <vector>

#include "src/core/pose2.h"

namespace stereoloc {

using Matrix32d = Eigen::Matrix<double, 3, 2>;

// sin(a)/a, (1 - cos a)/a and their derivatives in a (B.4, B.8), for double or ceres::Jet; series
// below |a| = 1e-2 (truncation < 1e-20), so straight steps are exact and smooth.
template <typename T>
struct ArcFunctions {
  T S, dS, C, dC;
};

template <typename T>
ArcFunctions<T> arcFunctions(const T& a) {
  using std::abs;
  using std::cos;
  using std::sin;
  ArcFunctions<T> r;
  const T a2 = a * a;
  if (abs(a) < T(1e-2)) {
    r.S = 1.0 - a2 / 6.0 * (1.0 - a2 / 20.0 * (1.0 - a2 / 42.0 * (1.0 - a2 / 72.0)));
    r.dS = a * (-1.0 / 3.0 + a2 * (1.0 / 30.0 + a2 * (-1.0 / 840.0 + a2 / 45360.0)));
    r.C = a * (0.5 - a2 * (1.0 / 24.0 - a2 * (1.0 / 720.0 - a2 * (1.0 / 40320.0 - a2 / 3628800.0))));
    r.dC = 0.5 - a2 * (1.0 / 8.0 - a2 * (1.0 / 144.0 - a2 * (1.0 / 5760.0 - a2 / 403200.0)));
  } else {
    const T s = sin(a), c = cos(a);
    r.S = s / a;
    r.dS = (a * c - s) / a2;
    r.C = (1.0 - c) / a;
    r.dC = (a * s - (1.0 - c)) / a2;
  }
  return r;
}

// What a step's wheel increments are, which decides where their noise lives (NoiseTravel).
enum class OdometryReadings {
  Encoders,  // measured wheel travel: reading = travel + noise of (B.6) (the thesis's robot)
  Commands,  // commanded travel (velocity commands times the period): travel = reading + noise
};
std::string toString(OdometryReadings readings);  // "encoders", "commands"
OdometryReadings odometryReadingsFromString(const std::string& name);  // throws Error naming the choices

struct OdometryParams {
  OdometryReadings readings = OdometryReadings::Encoders;
  double wheel_base_mm = 75.0;          // w, distance between the wheels
  double k_left = 0.02;                 // variance of d_left per mm travelled, mm^2/mm  (B.6)
  double k_right = 0.02;                // variance of d_right per mm travelled, mm^2/mm (B.6)
  double wheel_variance_floor = 0.0;    // mm^2 added to both wheel variances
  // Diagonal variance added to U (mm^2, mm^2, rad^2). U = J_u Sigma_v J_u^T has rank 2 (two
  // wheels drive three components), so without this floor its information is infinite
  // along one direction; a smoother needs a finite one. It also models unmodelled slip.
  Eigen::Vector3d control_variance_floor = Eigen::Vector3d(1e-2, 1e-2, 1e-6);

  void validate() const;  // throws stereoloc::Error naming the field
};

// (B.4)/(B.5); J_u_d is (B.8) with columns (d_left, d_right).
Eigen::Vector3d controlVector(double d_left, double d_right, double wheel_base_mm, Matrix32d* J_u_d = nullptr);

// (B.6): diag(sigma_l^2, sigma_r^2), with sigma^2 = k |d| + floor.
Eigen::Matrix2d wheelCovariance(double d_left, double d_right, const OdometryParams& params);

// (B.10): U = J_u Sigma_v J_u^T, plus the control variance floor.
Eigen::Matrix3d controlCovariance(double d_left, double d_right, const OdometryParams& params);

// The arc a differential-drive robot drives from `a` to `b` when it turns by the heading change
// and covers the chord in between: signed arc length (mm, negative = reverse) and heading change
// (rad). Exact when b lies on such an arc from a (all drivable scenarios); otherwise an
// approximation that keeps the chord length and the heading change.
struct Arc {
  double length = 0.0;  // mm
  double dtheta = 0.0;  // rad
};
Arc arcBetween(const Pose2& a, const Pose2& b);

// The wheel increments that drive an arc of the given length (mm, signed) and heading change
// (rad); the inverse of (B.1), (B.2).
struct WheelIncrements {
  double d_left = 0.0;   // mm
  double d_right = 0.0;  // mm
};
WheelIncrements wheelIncrementsForArc(double arc_length_mm, double dtheta_rad, double wheel_base_mm);

// The wheel travel at which a factor that estimates the wheel calibration evaluates (B.6)'s
// variance k |d|. Encoder readings: the mean |reading| of each wheel over the `history` steps
// before this one, and at least half this step's own |reading|. Why not the step's own reading: a
// weight computed from a reading is then correlated with that reading's noise; a reading that
// came out small gets more weight, and the fitted ratio of wheel travel to heading change (the
// wheel base) comes out low by about k / |d| (on the thesis's spin, k = 0.05 mm^2/mm over 1.2 mm
// steps: 4 %). The steps before are independent of this step's noise and, on a smooth motion,
// measure the same travel; the floor keeps a start from standstill from being taken as exact (a
// reading twice the mean of the steps before it is far outside (B.6)'s noise on a steady
// motion). The first step has no history and uses its own reading. Commanded travel: the
// reading itself, which carries no noise (the motion does), so a weight at it is independent of
// the noise and follows every change of command at once. Feed it every step in order, whether or
// not a factor is made from it; the batch and the sliding window then weigh the same step alike.
class NoiseTravel {
 public:
  explicit NoiseTravel(OdometryReadings readings = OdometryReadings::Encoders, int history = 10);
  // The travel (mm, >= 0 per wheel) for the reading (d_left, d_right) (mm), which it then keeps.
  WheelIncrements next(double d_left, double d_right);

 private:
  OdometryReadings readings_;
  std::vector<WheelIncrements> recent_;  // |reading|s of the last `history` steps, a ring
  size_t size_ = 0, head_ = 0;
};

// The EKF prediction (5.7), (5.9) in one call: p_k = p_{k-1} (+) u (B.16), and
// P_k = J1 P J1^T + J2 U J2^T with J1 (B.18), J2 (B.19).
struct PosePrediction {
  Pose2 pose;
  Eigen::Matrix3d covariance;
};
PosePrediction predictPose(const Pose2& pose, const Eigen::Matrix3d& covariance, double d_left, double d_right,
                           const OdometryParams& params);

}  // namespace stereoloc
