#pragma once
// Closed-form global position fixes of thesis chapter 4: poses with a 3x3 covariance computed
// without any prior pose, used to start the trackers and to re-initialise them when lost.
//
//   fix1     one landmark + absolute heading (compass)       (4.10)-(4.15), section 4.3.2
//   fix2     two landmarks: intersection of two range circles (4.1)-(4.7), (4.16)-(4.18)
//   running  one landmark seen twice with the motion in between (virtual landmark, 4.2.4)
//   multi    n landmarks (+ compass): range-bearing least squares with Ceres (4.2.8)
//
// Uncertainty. Every observation carries (range, bearing) and its covariance R, which the rig
// computed from the pixel noise by (5.32), R = J_rb_px sigma^2 J_rb_px^T. The closed forms
// depend on the pixels only through (range, bearing), so J_pose_z R J_pose_z^T is the same
// first-order covariance as J_pose_px sigma^2 I J_pose_px^T of (4.15)/(4.18) — and it also
// works for sensors that report range and bearing directly. (tests/solvers/test_global_fix.cpp
// checks the identity against a pixel-level propagation.)
//
// The printed two-landmark solution (4.5) divides by a = y_l2 - y_l1 and fails for landmarks
// with equal y; here the intersection is computed in the frame of the landmark baseline, which
// is rotation invariant. Its Jacobian comes from differentiating the two circle equations
// |p - c_i|^2 = r_i^2 implicitly (no use of the misprinted partials after 4.18).
#include <Eigen/Core>
#include <array>
#include <optional>
#include <string>
#include <vector>

#include "src/angles.h"
#include "src/field_map.h"
#include "src/pose2.h"
#include "src/types.h"

namespace stereoloc {

enum class FixStatus {
  Ok,
  ApproximateNoIntersection,  // the range circles do not meet (noise): closest point, flagged
  NotEnoughLandmarks,         // too few identified landmarks (or no compass for fix1)
  Degenerate,                 // concentric circles, coincident landmarks, singular geometry,
                              // or circles missing each other by far more than the noise
  Ambiguous,                  // two candidates that the ordering rule cannot tell apart
};
std::string toString(FixStatus status);  // "ok", "approximate", "not_enough_landmarks", "degenerate", "ambiguous"
FixStatus fixStatusFromString(const std::string& name);  // throws stereoloc::Error

enum class FixMethod { OneLandmarkCompass, TwoLandmarks, RunningFix, MultiLandmark };
std::string toString(FixMethod method);  // "fix1", "fix2", "running", "multi"
FixMethod fixMethodFromString(const std::string& name);  // throws stereoloc::Error

struct GlobalFix {
  FixStatus status = FixStatus::NotEnoughLandmarks;
  FixMethod method = FixMethod::TwoLandmarks;
  Pose2 pose;                                            // mm, rad (meaningful unless NotEnough/Degenerate)
  Eigen::Matrix3d covariance = Eigen::Matrix3d::Zero();  // (x, y, theta): mm^2, mm*rad, rad^2
  std::vector<int> landmark_ids;                         // landmarks the fix used
  // Usable: a pose with a positive-definite covariance (Ok, or the flagged approximate /
  // ambiguous outcomes, which callers may accept or not).
  bool hasPose() const {
    return status == FixStatus::Ok || status == FixStatus::ApproximateNoIntersection || status == FixStatus::Ambiguous;
  }
};

struct GlobalFixOptions {
  bool allow_one_landmark = true;   // fix1 (needs Step::compass)
  bool allow_two_landmarks = true;  // fix2
  bool allow_multi = true;          // least squares over all landmarks (n >= 3, or n >= 2 with compass)
  // Compass sigma (rad) used when Step::compass_sigma <= 0. The thesis's compass is accurate to
  // "< 3 deg" when the robot stands still (section 4.3.2).
  double compass_sigma_default = deg2rad(3.0);
  // Smallest compass sigma (rad) put into a covariance, so that a noise-free compass (the
  // thesis's 0 deg rows) still gives an invertible pose covariance.
  double compass_sigma_floor = 1e-4;
  // The ordering rule (sign of the bearing difference) is trusted when the bearing difference
  // is at least this many of its standard deviations away from 0 and from pi; otherwise the
  // two-circle solution is Ambiguous (globalFix then tries the map bounds).
  double ordering_min_sigma = 1.0;
  // Circles that miss each other by more than this many standard deviations of the range sum /
  // difference, or whose closest point contradicts the measured bearings by more than this
  // (sqrt of the 1-dof chi-square of all four measurements), are inconsistent (wrong
  // association, outlier, nested circles): Degenerate instead of approximate.
  double max_gap_sigma = 5.0;
  // A candidate this far (mm) outside the map bounds is impossible (thesis 4.2.1: "one of the
  // solutions lies at impossible locations"); used by globalFix to resolve ambiguity.
  double bounds_margin_mm = 100.0;
  int multi_max_iterations = 50;  // Ceres iterations of the least-squares fix
  // false: the thesis's first-order propagation (4.15), (4.18). true (default): add the second-order terms
  // 1/2 tr(H_k Sigma H_l Sigma) of the dominant curvatures — for fix1 the (range x heading) and
  // heading^2 terms of (4.10), for fix2 the curvature of atan2 in (4.6) under the position
  // covariance. The first-order covariance is nearly singular (stereo bearings are ~100x more
  // precise than ranges), so these terms decide the joint 3-dof consistency (NEES): `fixstudy`
  // measured mean 3-dof NEES 200-1700 first-order against 2.5-3.7 with them for landmarks
  // closer than 1 m (5-7 beyond 1 m, where the linearisation itself fails, section 4.4).
  bool second_order_covariance = true;
};

// Best available fix from one step's observations (those with landmark_id >= 0; positions
// from the map; an id the map lacks throws stereoloc::Error). Preference: multi (n >= 3, or
// n >= 2 with a compass), then fix2, then fix1 with the closest landmark (smallest position
// covariance). Returns NotEnoughLandmarks when no allowed method applies.
GlobalFix globalFix(const Step& step, const FieldMap& map, const GlobalFixOptions& options = {});

// fix2: the robot is where the circles |p - l_a| = r_a and |p - l_b| = r_b meet; the ordering
// rule picks the intersection on the side where l_b appears counter-clockwise of l_a iff the
// measured bearing difference psi_b - psi_a is positive. theta combines both landmarks (4.6).
GlobalFix fixFromTwoLandmarks(const Observation& a, const Observation& b, const Eigen::Vector2d& landmark_a,
                              const Eigen::Vector2d& landmark_b, const GlobalFixOptions& options = {});

// fix1 (4.10): p = l - r (cos phi, sin phi), phi = theta + psi, theta = the compass.
// compass_sigma (rad) is floored at options.compass_sigma_floor.
GlobalFix fixFromOneLandmark(const Observation& o, const Eigen::Vector2d& landmark, double compass_theta,
                             double compass_sigma, const GlobalFixOptions& options = {});

// Running fix with a virtual landmark (4.2.4). `earlier` and `later` see the same landmark at
// times k-1 and k; motion_world = (x_k - x_{k-1}, y_k - y_{k-1}, wrap(theta_k - theta_{k-1})) is
// the motion in the WORLD frame (odometry rotated by a known heading, as in the thesis's
// "movement by delta_x and delta_y"), with its 3x3 covariance. The earlier circle moves with
// the robot to the virtual landmark l + delta, seen at range r_{k-1} and bearing
// psi_{k-1} - delta_theta; both candidates are poses at time k.
struct RunningFixResult {
  FixStatus status = FixStatus::NotEnoughLandmarks;  // Ok: `preferred` is decided; Ambiguous: it is not
  std::array<GlobalFix, 2> candidates;               // [0] is the one the ordering rule favours
  int preferred = -1;                                // index into candidates, -1 when undecided
};
RunningFixResult runningFix(const Observation& earlier, const Observation& later, const Eigen::Vector2d& landmark,
                            const Eigen::Vector3d& motion_world, const Eigen::Matrix3d& motion_covariance,
                            const std::optional<Eigen::Vector2d>& coarse_prior = std::nullopt,
                            const GlobalFixOptions& options = {});

// multi: minimises sum |S_i (h(p, l_i) [-] z_i)|^2 (+ the compass residual) with Ceres, started
// from both candidates of the best pair (or from fix1 when only one pair is missing), covariance
// (J^T W J)^-1 at the optimum. Needs n >= 3, or n >= 2 with a compass (nullopt = no compass).
GlobalFix fixFromLandmarks(const std::vector<Observation>& observations, const std::vector<Eigen::Vector2d>& landmarks,
                           const std::optional<double>& compass_theta, double compass_sigma,
                           const GlobalFixOptions& options = {});

// ---- The two-circle core, exposed for tests and for other solvers that build virtual circles.
// Input vector x = (c1x, c1y, r1, psi1, c2x, c2y, r2, psi2): two circle centres (mm, world) with
// the range (mm) and robot-frame bearing (rad) at which each centre is seen.
using Vector8d = Eigen::Matrix<double, 8, 1>;
using Matrix8d = Eigen::Matrix<double, 8, 8>;
using Matrix38d = Eigen::Matrix<double, 3, 8>;

struct TwoCircleSolution {
  FixStatus status = FixStatus::Degenerate;  // Ok (two or one tangent intersection), Approximate, Degenerate
  Pose2 pose;                                // on the side `side` of the baseline c1 -> c2
  Eigen::Matrix3d covariance = Eigen::Matrix3d::Zero();
  Matrix38d J_pose_x = Matrix38d::Zero();    // d pose / d x (valid when status == Ok and not tangent)
  double half_chord = 0.0;                   // h: distance of the intersections from the baseline (mm)
  double gap_sigma = 0.0;                    // inconsistency of a closest-point solution, in sigmas
};

// side = +1: the intersection to the left of c1 -> c2 (c2 appears counter-clockwise of c1 from
// the robot), -1: to the right. x_cov is the 8x8 covariance of x. Weights for combining the two
// headings are the best linear unbiased ones under x_cov (treated as constants in J_pose_x,
// which is exact to first order at consistent measurements).
TwoCircleSolution solveTwoCircles(const Vector8d& x, const Matrix8d& x_cov, int side,
                                  const GlobalFixOptions& options = {});

// The side the ordering rule picks from the bearings (+1 when wrap(psi2 - psi1) >= 0), and how
// many standard deviations the bearing difference lies from 0 and pi (its significance).
int orderingSide(double psi1, double psi2);
double orderingSignificance(double psi1, double psi2, double sigma_difference);

}  // namespace stereoloc
