#include "src/core/odometry_model.h"

#include <algorithm>
#include <cmath>
#include <sstream>

#include "src/core/error.h"

namespace stereoloc {
void OdometryParams::validate() const {
  auto check = [](bool ok, const char* field) {
    if (!ok) throw Error(std::string("odometry: ") + field + " is out of range");
  };
  // A millimetre to a hundred metres: outside, (B.10)'s 1/w and w^2 are nonsense, not a robot.
  if (!(wheel_base_mm >= 1.0 && wheel_base_mm <= 1e5)) {
    std::ostringstream w;  // %g: a 1e-300 stays 1e-300
    w << wheel_base_mm;
    throw Error("odometry: wheel_base_mm " + w.str() + " is outside [1, 100000] mm");
  }
  check(std::isfinite(k_left) && k_left >= 0, "k_left");
  check(std::isfinite(k_right) && k_right >= 0, "k_right");
  check(std::isfinite(wheel_variance_floor) && wheel_variance_floor >= 0, "wheel_variance_floor");
  check(control_variance_floor.allFinite() && (control_variance_floor.array() >= 0).all(), "control_variance_floor");
}

Eigen::Vector3d controlVector(double d_left, double d_right, double wheel_base_mm, Matrix32d* J_u_d) {
  if (!std::isfinite(d_left) || !std::isfinite(d_right)) throw Error("odometry: wheel increment is not finite");
  if (!(wheel_base_mm > 0)) throw Error("odometry: wheel base must be positive");
  const double w = wheel_base_mm;
  const double alpha = (d_right - d_left) / w;  // (B.1)
  const double v = 0.5 * (d_right + d_left);    // (B.2)
  const ArcFunctions<double> f = arcFunctions(alpha);
  if (J_u_d) {  // (B.8), written through dv/dd = 1/2 and dalpha/dd = -+1/w
    *J_u_d << 0.5 * f.S - v * f.dS / w, 0.5 * f.S + v * f.dS / w,  //
        0.5 * f.C - v * f.dC / w, 0.5 * f.C + v * f.dC / w,        //
        -1.0 / w, 1.0 / w;
  }
  return Eigen::Vector3d(v * f.S, v * f.C, alpha);  // (B.4)
}

Eigen::Matrix2d wheelCovariance(double d_left, double d_right, const OdometryParams& p) {
  Eigen::Matrix2d S = Eigen::Matrix2d::Zero();  // (B.6): the wheels' errors are independent
  S(0, 0) = p.k_left * std::fabs(d_left) + p.wheel_variance_floor;
  S(1, 1) = p.k_right * std::fabs(d_right) + p.wheel_variance_floor;
  return S;
}

Eigen::Matrix3d controlCovariance(double d_left, double d_right, const OdometryParams& p) {
  Matrix32d J;
  controlVector(d_left, d_right, p.wheel_base_mm, &J);
  Eigen::Matrix3d U = J * wheelCovariance(d_left, d_right, p) * J.transpose();  // (B.10)
  U.diagonal() += p.control_variance_floor;
  return 0.5 * (U + U.transpose());
}

WheelIncrements wheelIncrementsForArc(double arc_length_mm, double dtheta_rad, double wheel_base_mm) {
  const double half = 0.5 * dtheta_rad * wheel_base_mm;
  return WheelIncrements{arc_length_mm - half, arc_length_mm + half};
}

std::string toString(OdometryReadings readings) {
  return readings == OdometryReadings::Commands ? "commands" : "encoders";
}

OdometryReadings odometryReadingsFromString(const std::string& name) {
  for (OdometryReadings r : {OdometryReadings::Encoders, OdometryReadings::Commands})
    if (toString(r) == name) return r;
  throw Error("unknown odometry readings '" + name + "' (expected encoders or commands)");
}

NoiseTravel::NoiseTravel(OdometryReadings readings, int history) : readings_(readings) {
  if (history < 1) throw Error("noise travel: the history must be at least one step");
  recent_.resize(static_cast<size_t>(history));
}

WheelIncrements NoiseTravel::next(double d_left, double d_right) {
  const WheelIncrements now{std::fabs(d_left), std::fabs(d_right)};
  if (readings_ == OdometryReadings::Commands) return now;
  WheelIncrements t = now;
  if (size_ > 0) {
    double l = 0.0, r = 0.0;
    for (size_t i = 0; i < size_; ++i) {
      l += recent_[i].d_left;
      r += recent_[i].d_right;
    }
    const double n = static_cast<double>(size_);
    t = WheelIncrements{std::max(l / n, 0.5 * now.d_left), std::max(r / n, 0.5 * now.d_right)};
  }
  recent_[head_] = now;
  head_ = (head_ + 1) % recent_.size();
  size_ = std::min(size_ + 1, recent_.size());
  return t;
}

PosePrediction predictPose(const Pose2& pose, const Eigen::Matrix3d& covariance, double d_left, double d_right,
                           const OdometryParams& params) {
  const Eigen::Vector3d u = controlVector(d_left, d_right, params.wheel_base_mm);
  Matrix3d J1, J2;
  const Pose2 next = compose(pose, Pose2(u.x(), u.y(), u.z()), &J1, &J2);  // (B.16)-(B.19)
  const Eigen::Matrix3d U = controlCovariance(d_left, d_right, params);
  Eigen::Matrix3d P = J1 * covariance * J1.transpose() + J2 * U * J2.transpose();  // (5.9)
  return PosePrediction{next, 0.5 * (P + P.transpose())};
}

Arc arcBetween(const Pose2& a, const Pose2& b) {
  const Pose2 rel = between(a, b);
  Arc arc;
  arc.dtheta = rel.theta;
  const double chord = std::hypot(rel.x, rel.y);
  if (chord == 0.0) return arc;
  const double half = 0.5 * arc.dtheta;
  // On an arc the chord leaves at half the heading change (forward) or opposite (reverse).
  const double along = rel.x * std::cos(half) + rel.y * std::sin(half);
  const double ratio = std::fabs(half) < 1e-9 ? 1.0 + half * half / 6.0 : half / std::sin(half);
  arc.length = (along >= 0 ? 1.0 : -1.0) * chord * ratio;
  return arc;
}

}  // namespace stereoloc
