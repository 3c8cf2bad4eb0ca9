#pragma once
// Two cameras that do not expose together. The right camera of an unsynchronised head exposes
// `StereoRigParams::exposure_offset_s` after the left (negative: before); while the robot moves,
// its image is taken from another pose, so every disparity carries the motion of that interval:
// turning at w, a column shift of about f (1 + x^2) w dt (0.87 px at 0.63 rad/s and 5 ms, a tenth
// of a landmark's disparity at 1 m), which no constant disparity offset can take once the turn
// rate changes. The robot's rate at a step comes from its odometry (BodyRateTracker); the right
// column is moved to the left camera's instant with the rig's offset (synchronisedPixels), and a
// self-calibration may estimate what remains of the offset with the same motion model
// (factors/stereo_pixel_calibration_factor.h, the image block's last entry; opt-in, see
// docs/realistic_world.md, "Cameras that do not expose together").
// Frames and units: robot frame C0 (x ahead, y left), mm, s, rad; pixels rectified.
#include <vector>

#include "src/core/odometry_model.h"
#include "src/core/stereo_rig.h"
#include "src/core/types.h"

namespace stereoloc {

// The robot's motion at an image: forward speed (mm/s) and turn rate (rad/s, counter-clockwise),
// and the standard deviation of the turn rate as the wheel increments give it (rad/s).
struct BodyRate {
  double forward_mm_s = 0.0;
  double yaw_rad_s = 0.0;
  double yaw_sigma_rad_s = 0.0;
};

// The rate of a step's wheel increments (mm) over the interval since the previous step, dt (s),
// for wheel base w (mm): ((d_l + d_r) / (2 dt), (d_r - d_l) / (w dt)) (B.1, B.2). Zero when dt
// is not a positive finite number (NaN: the first step, without a previous one). Throws Error
// for a non-finite increment or w <= 0.
BodyRate bodyRate(double d_left, double d_right, double dt_s, double wheel_base_mm);

// The rate between poses a and b dt_s apart (s, > 0): the forward travel along the mean heading
// and the turn, over dt; the yaw's sigma from the variance of the rotation between them (rad^2).
// The smoothers' rate at a pose from its neighbours' estimates (central difference).
BodyRate bodyRateBetween(const Pose2& a, const Pose2& b, double dt_s, double rotation_variance);

// The variance of a step's rotation (rad^2) from its wheels' (B.6): (sigma_l^2 + sigma_r^2) / w^2.
double stepRotationVariance(double d_left, double d_right, const OdometryParams& params);

// The body rate at each step from the wheel increments of the last `window_s` seconds: one
// step's increments are too noisy for it (the realistic profile's odometry: 0.12 rad/s per
// 0.1 s step on a straight drive, a fifth of the circle's turn rate), and a model that took
// them as the true rate would read that noise as information on the exposure offset (an
// errors-in-variables bias). Averaged over 0.5 s the noise falls by sqrt(5) and a turn's start
// is seen 0.25 s late. yaw_sigma_rad_s is the average's error from the steps' stated rotation
// variances.
class BodyRateTracker {
 public:
  static constexpr double kDefaultWindowS = 0.5;
  // `window_s` > 0 (s); throws Error otherwise or for w <= 0 (mm).
  explicit BodyRateTracker(double wheel_base_mm, double window_s = kDefaultWindowS);
  // The step at time t (s, not before the previous step's) with its wheel increments (mm) and
  // the variance of its rotation (rad^2, >= 0): the rate over the steps of the last window_s, at
  // least this one. The first step, and steps at the time of all kept ones, have no interval:
  // their rate is zero. Throws Error for non-finite input or a time before the previous one.
  BodyRate add(double t_s, double d_left, double d_right, double rotation_variance);

 private:
  struct Entry {
    double t, d_left, d_right, rotation_variance;
  };
  double wheel_base_mm_, window_s_;
  std::vector<Entry> recent_;  // the last steps, oldest first; recent_[0] opens the interval
};

// The right image's column of a point seen at rectified `px` (head pan `pan`) had the right
// camera exposed `dt_s` later than the left on a robot moving at `rate`: the point triangulated
// from `px`, seen from the pose the robot reaches in dt (ahead by v dt, turned by w dt),
// projected into the right camera. The difference to px.u_right is the shift the offset causes.
// Throws GeometryError when `px` cannot be triangulated or the moved point is behind the camera.
double rightColumnAfter(const StereoRig& rig, const StereoPixels& px, double pan, const BodyRate& rate, double dt_s);

// `px` with the right column moved to the left camera's instant, for a rig whose right camera
// exposes rig.params().exposure_offset_s after the left: the column u_r whose
// rightColumnAfter(offset) is the measured one. The pixels unchanged when the offset or the rate
// is zero. Throws GeometryError as rightColumnAfter.
StereoPixels synchronisedPixels(const StereoRig& rig, const StereoPixels& px, double pan, const BodyRate& rate);

// `obs` measured on `rig` at `rate`, its right column moved to the left camera's instant
// (synchronisedPixels) and range, bearing and R triangulated again (observationFromPixels, with
// its slide gain and its pixel covariance, whose u_r variance grows by the correction's error
// from the turn rate's, rate.yaw_sigma_rad_s). Unchanged without pixels, when the rig's offset is
// zero or the robot is at rest. Throws GeometryError as synchronisedPixels.
Observation synchronisedObservation(const StereoRig& rig, const Observation& obs, const BodyRate& rate);

}  // namespace stereoloc
