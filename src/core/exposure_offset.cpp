#include "src/core/exposure_offset.h"

#include <cmath>

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
  Observation out = observationFromPixels(rig, obs.landmark_id, obs.type,
                                          synchronisedPixels(rig, *obs.pixels, obs.head_pan, rate), obs.head_pan,
                                          obs.pixel_covariance);
  out.slide_gain = obs.slide_gain;
  return out;
}

}  // namespace stereoloc
