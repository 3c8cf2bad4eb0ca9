#include "src/core/exposure_offset.h"

#include <cmath>

#include "src/core/angles.h"
#include "src/core/error.h"

namespace stereoloc {

BodyRate bodyRate(double d_left, double d_right, double dt_s, double wheel_base_mm) {
  if (!(std::isfinite(d_left) && std::isfinite(d_right))) throw Error("body rate: wheel increments must be finite");
  if (!(std::isfinite(wheel_base_mm) && wheel_base_mm > 0)) throw Error("body rate: wheel base must be positive");
  BodyRate r;
  if (!(dt_s > 0 && std::isfinite(dt_s))) return r;  // no previous step (NaN), or no interval
  r.forward_mm_s = 0.5 * (d_left + d_right) / dt_s;   // (B.2)
  r.yaw_rad_s = (d_right - d_left) / (wheel_base_mm * dt_s);  // (B.1)
  return r;
}

BodyRate bodyRateBetween(const Pose2& a, const Pose2& b, double dt_s, double rotation_variance) {
  const double turn = angleDiff(b.theta, a.theta);
  const double mid = a.theta + 0.5 * turn;
  BodyRate r;
  r.forward_mm_s = ((b.x - a.x) * std::cos(mid) + (b.y - a.y) * std::sin(mid)) / dt_s;
  r.yaw_rad_s = turn / dt_s;
  r.yaw_sigma_rad_s = std::sqrt(rotation_variance) / dt_s;
  return r;
}

double stepRotationVariance(double d_left, double d_right, const OdometryParams& params) {
  const Eigen::Matrix2d C = wheelCovariance(d_left, d_right, params);
  return (C(0, 0) + C(1, 1)) / (params.wheel_base_mm * params.wheel_base_mm);
}

BodyRateTracker::BodyRateTracker(double wheel_base_mm, double window_s)
    : wheel_base_mm_(wheel_base_mm), window_s_(window_s) {
  if (!(std::isfinite(wheel_base_mm) && wheel_base_mm > 0)) throw Error("body rate: wheel base must be positive");
  if (!(std::isfinite(window_s) && window_s > 0)) throw Error("body rate: window must be a positive time");
}

BodyRate BodyRateTracker::add(double t_s, double d_left, double d_right, double rotation_variance) {
  if (!(std::isfinite(t_s) && std::isfinite(d_left) && std::isfinite(d_right) && std::isfinite(rotation_variance) &&
        rotation_variance >= 0))
    throw Error("body rate: time, wheel increments and rotation variance must be finite");
  if (!recent_.empty() && t_s < recent_.back().t)
    throw Error("body rate: step time " + std::to_string(t_s) + " s is before the previous step's " +
                std::to_string(recent_.back().t) + " s");
  recent_.push_back({t_s, d_left, d_right, rotation_variance});
  // Keep the steps inside the window and the one before them, whose time opens the interval.
  while (recent_.size() > 2 && t_s - recent_[1].t >= window_s_) recent_.erase(recent_.begin());
  BodyRate r;
  if (recent_.size() < 2) return r;
  double dl = 0, dr = 0, var = 0;
  for (size_t i = 1; i < recent_.size(); ++i) {
    dl += recent_[i].d_left;
    dr += recent_[i].d_right;
    var += recent_[i].rotation_variance;
  }
  const double T = t_s - recent_.front().t;
  if (!(T > 0)) return r;  // steps at one time (a dataset's t may repeat): no interval
  r = bodyRate(dl, dr, T, wheel_base_mm_);
  r.yaw_sigma_rad_s = std::sqrt(var) / T;
  return r;
}

double rightColumnAfter(const StereoRig& rig, const StereoPixels& px, double pan, const BodyRate& rate, double dt_s) {
  const Eigen::Vector3d p = rig.triangulate(px, pan);
  // The robot after dt: ahead by v dt, turned by w dt (the arc's sideways part, v w dt^2 / 2, is
  // of second order in dt). The point in the robot's frame then: Rz(-w dt) (p - (v dt, 0, 0)).
  const double a = rate.yaw_rad_s * dt_s, c = std::cos(a), s = std::sin(a);
  const Eigen::Vector3d q(p.x() - rate.forward_mm_s * dt_s, p.y(), p.z());
  const Eigen::Vector3d moved(c * q.x() + s * q.y(), -s * q.x() + c * q.y(), q.z());
  const Eigen::Vector3d v = rig.robotToVision(moved, pan);
  if (!(v.x() > 1e-6)) throw GeometryError("exposure offset: the point is behind the camera at the right exposure");
  return rig.principalU() - rig.focal() * (v.y() + 0.5 * rig.params().baseline_mm) / v.x();
}

StereoPixels synchronisedPixels(const StereoRig& rig, const StereoPixels& px, double pan, const BodyRate& rate) {
  const double dt = rig.params().exposure_offset_s;
  if (dt == 0.0 || (rate.forward_mm_s == 0.0 && rate.yaw_rad_s == 0.0)) return px;
  // The column u whose point, seen dt later, is the measured one: u = u_m - shift(u), by fixed
  // point; the shift changes with u by a few per cent of it (through the triangulated depth), so
  // three rounds leave ~1e-5 px of a 1 px shift. Each shift is taken against the projection of
  // the triangulated point at dt = 0, so that a row difference of px does not enter it.
  StereoPixels out = px;
  for (int round = 0; round < 3; ++round) {
    const double shift = rightColumnAfter(rig, out, pan, rate, dt) - rightColumnAfter(rig, out, pan, rate, 0.0);
    out.u_right = px.u_right - shift;
  }
  return out;
}

Observation synchronisedObservation(const StereoRig& rig, const Observation& obs, const BodyRate& rate) {
  if (!obs.pixels || rig.params().exposure_offset_s == 0.0 || (rate.forward_mm_s == 0.0 && rate.yaw_rad_s == 0.0))
    return obs;
  // The turn rate is known to yaw_sigma: the correction's error, shift per rad/s times it,
  // joins the right column's variance.
  const double tau = rig.params().exposure_offset_s;
  const BodyRate unit{0.0, 1.0, 0.0};
  const double per_rate = rightColumnAfter(rig, *obs.pixels, obs.head_pan, unit, tau) -
                          rightColumnAfter(rig, *obs.pixels, obs.head_pan, unit, 0.0);
  Eigen::Matrix4d C = obs.pixel_covariance;
  C(2, 2) += per_rate * per_rate * rate.yaw_sigma_rad_s * rate.yaw_sigma_rad_s;
  Observation out = observationFromPixels(rig, obs.landmark_id, obs.type,
                                          synchronisedPixels(rig, *obs.pixels, obs.head_pan, rate), obs.head_pan, C);
  out.slide_gain = obs.slide_gain;
  return out;
}

}  // namespace stereoloc
