#include "src/core/exposure_offset.h"

#include <gtest/gtest.h>

#include <cmath>
#include <fstream>

#include "src/core/angles.h"
#include "src/core/atomic_file.h"
#include "src/core/error.h"
#include "test_util.h"

namespace stereoloc {
namespace {

StereoRig tiltedRig(double exposure_offset_s) {
  StereoRigParams p;
  p.tilt_rad = deg2rad(12);
  p.offset_x_mm = 15;
  p.exposure_offset_s = exposure_offset_s;
  return StereoRig(p);
}

TEST(BodyRate, IsTheStepsWheelIncrementsOverItsInterval) {
  const BodyRate r = bodyRate(8.0, 12.0, 0.1, 80.0);
  EXPECT_DOUBLE_EQ(r.forward_mm_s, 100.0);  // (8 + 12) / 2 mm in 0.1 s
  EXPECT_DOUBLE_EQ(r.yaw_rad_s, 0.5);       // (12 - 8) / 80 rad in 0.1 s
  // Without a previous step (NaN) or an interval: unknown, taken as at rest.
  for (double dt : {std::nan(""), 0.0, -0.1}) {
    const BodyRate z = bodyRate(8.0, 12.0, dt, 80.0);
    EXPECT_EQ(z.forward_mm_s, 0.0);
    EXPECT_EQ(z.yaw_rad_s, 0.0);
  }
  EXPECT_THROW(bodyRate(std::nan(""), 1.0, 0.1, 80.0), Error);
  EXPECT_THROW(bodyRate(1.0, 1.0, 0.1, 0.0), Error);
}

// Two poses on a circle of radius 500 mm, 0.2 rad of arc apart, 0.4 s: the chord along the mean
// heading and the turn over the interval, also where the headings straddle +-pi.
TEST(BodyRate, BetweenTwoPosesIsTheChordAndTheTurnOverTheInterval) {
  const double R = 500, phi = 0.2, dt = 0.4;
  for (double theta0 : {0.3, M_PI - 0.1}) {
    const Pose2 a(100, 200, wrapAngle(theta0));
    // Counter-clockwise: the centre lies to the left of a's heading.
    const double cx = a.x - R * std::sin(theta0), cy = a.y + R * std::cos(theta0);
    const Pose2 b(cx + R * std::sin(theta0 + phi), cy - R * std::cos(theta0 + phi), wrapAngle(theta0 + phi));
    const BodyRate r = bodyRateBetween(a, b, dt, 4e-4);
    EXPECT_NEAR(r.forward_mm_s, 2 * R * std::sin(phi / 2) / dt, 1e-9) << theta0;
    EXPECT_NEAR(r.yaw_rad_s, phi / dt, 1e-12) << theta0;
    EXPECT_NEAR(r.yaw_sigma_rad_s, 0.02 / dt, 1e-15);
  }
}

// The rate over the last half second of steps, and its error from the steps' rotation
// variances; the first step has no interval.
TEST(BodyRateTracker, AveragesTheLastWindowOfSteps) {
  BodyRateTracker tracker(80.0, 0.5);
  const BodyRate first = tracker.add(0.0, 1.0, 3.0, 1e-4);
  EXPECT_EQ(first.yaw_rad_s, 0.0);
  EXPECT_EQ(first.yaw_sigma_rad_s, 0.0);
  BodyRate r;
  for (int k = 1; k <= 10; ++k) r = tracker.add(0.1 * k, k <= 5 ? 8.0 : 4.0, 12.0, 1e-4);
  // Steps 6-10 (0.5 s): (12 - 4) / 80 rad per 0.1 s, (4 + 12) / 2 mm per 0.1 s.
  EXPECT_NEAR(r.yaw_rad_s, 1.0, 1e-12);
  EXPECT_NEAR(r.forward_mm_s, 80.0, 1e-9);
  EXPECT_NEAR(r.yaw_sigma_rad_s, std::sqrt(5 * 1e-4) / 0.5, 1e-12);
  // A turn's start is seen over the window: one step into it, a fifth of it.
  BodyRateTracker turning(80.0, 0.5);
  for (int k = 0; k <= 5; ++k) turning.add(0.1 * k, 10.0, 10.0, 0.0);
  EXPECT_NEAR(turning.add(0.6, 6.0, 14.0, 0.0).yaw_rad_s, 0.2, 1e-12);
  EXPECT_THROW(turning.add(0.5, 1.0, 1.0, 0.0), Error);  // before the previous step
  BodyRateTracker still(80.0, 0.5);
  still.add(1.0, 0.0, 0.0, 0.0);
  EXPECT_EQ(still.add(1.0, 2.0, 4.0, 1e-4).yaw_sigma_rad_s, 0.0);  // a repeated time: no interval
  EXPECT_THROW(turning.add(0.7, std::nan(""), 1.0, 0.0), Error);
  EXPECT_THROW(BodyRateTracker(80.0, 0.0), Error);
  // The rotation variance of a step from its wheels' (B.6).
  OdometryParams p;
  p.wheel_base_mm = 80.0;
  EXPECT_NEAR(stepRotationVariance(10.0, 20.0, p), (p.k_left * 10.0 + p.k_right * 20.0) / 6400.0, 1e-15);
}

// At dt = 0 the right column is the projection's; a turn of w dt moves it by about
// f (1 + x^2) w dt to the right (the scene turns against the robot), and driving ahead moves it
// away from the image centre by its distance from the centre times v dt / depth.
TEST(ExposureOffset, RightColumnAfterFollowsTheMotion) {
  const StereoRig rig = tiltedRig(0.0);
  const Eigen::Vector3d point(1000.0, 40.0, 30.0);
  const StereoPixels px = *rig.project(point, 0.1);
  EXPECT_NEAR(rightColumnAfter(rig, px, 0.1, BodyRate{300.0, 1.0}, 0.0), px.u_right, 1e-9);
  const double dt = 1e-4;
  const double turned = rightColumnAfter(rig, px, 0.1, BodyRate{0.0, 1.0}, dt) - px.u_right;
  const double xr = (px.u_right - rig.principalU()) / rig.focal();
  EXPECT_NEAR(turned, rig.focal() * (1 + xr * xr) * dt, 0.05 * rig.focal() * dt);  // the tilt bends it a little
  // Ahead, on a level head looking straight ahead: x falls by v dt, u_r - o_u = -f (y + b/2) / x grows.
  const StereoRig level;
  const StereoPixels side = *level.project(Eigen::Vector3d(1000.0, 300.0, 30.0), 0.0);
  const double ahead = rightColumnAfter(level, side, 0.0, BodyRate{300.0, 0.0}, dt) - side.u_right;
  EXPECT_NEAR(ahead, (side.u_right - level.principalU()) * 300.0 * dt / 1000.0, 1e-3 * std::fabs(ahead));
}

// The right camera of a head exposing 4 ms after the left, on a turning, driving robot: its
// columns as measured are moved back to the left camera's instant, to 1e-4 px, and the
// observation's range follows.
TEST(ExposureOffset, SynchronisedPixelsUndoTheOffset) {
  const double tau = 0.004;
  const StereoRig rig = tiltedRig(tau);
  const BodyRate rate{250.0, 1.2};
  for (const Eigen::Vector3d& point : {Eigen::Vector3d(600, -150, 0), Eigen::Vector3d(1500, 300, 30),
                                      Eigen::Vector3d(900, 0, 150)}) {
    const StereoPixels truth = *rig.project(point, -0.05);
    StereoPixels measured = truth;
    measured.u_right = rightColumnAfter(rig, truth, -0.05, rate, tau);
    EXPECT_GT(std::fabs(measured.u_right - truth.u_right), 1.0);  // px: not small against the disparity
    const StereoPixels back = synchronisedPixels(rig, measured, -0.05, rate);
    EXPECT_NEAR(back.u_right, truth.u_right, 1e-4);
    EXPECT_EQ(back.u_left, truth.u_left);
    EXPECT_EQ(back.v_right, truth.v_right);

    Observation o = observationFromPixels(rig, 4, LandmarkType::GoalCorner, measured, -0.05, 0.3);
    o.slide_gain = 0.7;
    const Observation s = synchronisedObservation(rig, o, rate);
    EXPECT_NEAR(s.range, std::hypot(point.x(), point.y()), 0.01 * s.range);
    EXPECT_GT(std::fabs(o.range - s.range), 0.01 * s.range);
    EXPECT_EQ(s.slide_gain, 0.7);
    EXPECT_EQ(s.landmark_id, 4);
    EXPECT_TRUE(s.pixel_covariance.isApprox(o.pixel_covariance));  // a rate known exactly
    // The turn rate's error joins u_r's variance: a correction of f w dt known to yaw_sigma.
    const BodyRate uncertain{rate.forward_mm_s, rate.yaw_rad_s, 0.2};
    const Observation noisy = synchronisedObservation(rig, o, uncertain);
    const double extra = noisy.pixel_covariance(2, 2) - o.pixel_covariance(2, 2);
    EXPECT_NEAR(std::sqrt(extra), rig.focal() * 0.2 * tau, 0.3 * rig.focal() * 0.2 * tau);
    EXPECT_EQ(noisy.pixel_covariance(0, 0), o.pixel_covariance(0, 0));
    // Nothing to do at rest, on a synchronised head, or without pixels.
    EXPECT_EQ(synchronisedObservation(rig, o, BodyRate()).pixels->u_right, o.pixels->u_right);
    EXPECT_EQ(synchronisedObservation(tiltedRig(0.0), o, rate).pixels->u_right, o.pixels->u_right);
    const Observation rb = observationFromRangeBearing(1, LandmarkType::Point, 800, 0.1, 10, 0.01);
    EXPECT_EQ(synchronisedObservation(rig, rb, rate).range, rb.range);
  }
}

TEST(ExposureOffset, IsARigKeyWithItsRange) {
  test::TempDir dir;
  tiltedRig(-0.003).save(dir.file("rig.yaml"));
  EXPECT_DOUBLE_EQ(StereoRig::load(dir.file("rig.yaml")).params().exposure_offset_s, -0.003);
  // A synchronised head's file does not carry the key; it reads back as 0.
  tiltedRig(0.0).save(dir.file("sync.yaml"));
  EXPECT_EQ(StereoRig::load(dir.file("sync.yaml")).params().exposure_offset_s, 0.0);
  tiltedRig(0.0).save(dir.file("bad.yaml"));
  std::ofstream(dir.file("bad.yaml"), std::ios::app) << "exposure_offset_s: 0.5\n";
  const std::string error = test::errorOf([&] { StereoRig::load(dir.file("bad.yaml")); });
  EXPECT_NE(error.find("bad.yaml"), std::string::npos) << error;
  EXPECT_NE(error.find("exposure_offset_s"), std::string::npos) << error;
}

}  // namespace
}  // namespace stereoloc
