#pragma once
// Closed-form global position fixes of thesis chapter 4: poses with a 3x3 covariance computed
// without any prior pose, used to start the trackers and to re-initialise them when lost.
//
//   fix1     one landmark + absolute heading (compass)       (4.10)-(4.15), section 4.3.2
//   fix2     two landmarks: intersection of two range circles (4.1)-(4.7), (4.16)-(4.18)
//   running  one landmark seen twice with the motion in between (virtual landmark, 4.2.4)
//   multi    n landmarks (+ compass): least squares with Ceres (4.2.8) on range-bearing or,
//            with GlobalFixOptions::rig, on the stereo pixels
//
// Uncertainty. Every observation carries (range, bearing) and its covariance R, which the rig
// computed from the pixel noise by (5.32), R = J_rb_px sigma^2 J_rb_px^T. The closed forms
// depend on the pixels only through (range, bearing), so J_pose_z R J_pose_z^T is the same
// first-order covariance as J_pose_px sigma^2 I J_pose_px^T of (4.15)/(4.18) — and it also
// works for sensors that report range and bearing directly. (tests/solvers/test_global_fix.cpp
// checks the identity against a pixel-level propagation.)
//
// That first-order covariance is kept (FixCovariance::FirstOrder) but is not the default: with
// stereo it is far too confident in 3 dof. The default propagates the noise through the exact
// closed forms with sigma points (FixCovariance::SigmaPoints; stereo ranges as inverse range) and
// reports how nonlinear each fix is (GlobalFix::nonlinearity). Measurements: docs/results.md,
// "Global fixes"; the reasoning: docs/estimators.md.
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

#include "src/core/angles.h"
#include "src/core/field_map.h"
#include "src/core/pose2.h"
#include "src/core/stereo_rig.h"
#include "src/core/types.h"

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

// Covariance of a closed-form fix.
//   FirstOrder   the thesis's propagation J Sigma J^T, (4.15) and (4.18).
//   SecondOrder  plus 1/2 tr(H_k Sigma H_l Sigma) of the dominant curvatures (fix1: range x
//                heading and heading^2 of (4.10); fix2: atan2 of (4.6) under the position
//                covariance).
//   SigmaPoints  the mean squared error matrix E[(f(z) - f(z_hat))(...)^T] of the exact closed
//                form f about the estimate, by a symmetric fifth-degree Gaussian quadrature over
//                the measurement noise (sigma points at sqrt(3) sigma along each axis and each
//                pair of axes). Exact for any f that is quadratic in the inputs, including the
//                squared bias; the stereo range is propagated as inverse range (see
//                GlobalFixOptions::stereo_inverse_range). fix1's is exact in the angles and
//                takes the range by Gauss-Hermite: where the compass is far wider than the
//                bearing, the fifth-degree rule misses the arc's higher orders. Falls back to
//                SecondOrder when the quadrature does not give a positive-definite matrix.
// First order is over-confident for stereo: the bearings are ~100x more precise than the
// ranges, so the 3x3 covariance is nearly singular and the heading / arc curvature that it
// drops decides the 3-dof NEES (fixstudy measured mean 3-dof NEES 200-1700).
enum class FixCovariance { FirstOrder, SecondOrder, SigmaPoints };
std::string toString(FixCovariance model);                       // "first_order", "second_order", "sigma_points"
FixCovariance fixCovarianceFromString(const std::string& name);  // throws stereoloc::Error

struct GlobalFix {
  FixStatus status = FixStatus::NotEnoughLandmarks;
  FixMethod method = FixMethod::TwoLandmarks;
  Pose2 pose;                                            // mm, rad (meaningful unless NotEnough/Degenerate)
  Eigen::Matrix3d covariance = Eigen::Matrix3d::Zero();  // (x, y, theta): mm^2, mm*rad, rad^2
  std::vector<int> landmark_ids;                         // landmarks the fix used
  // How far the closed form is from linear at this fix, in [0, 1]: |P^-1/2 b| over the position
  // (x, y), with b the second-order bias E[f(z + n)] - f(z) and P the covariance, both from the
  // sigma points
  // (FixCovariance::SigmaPoints; the other models leave it 0). For a 1-D quadratic
  // f = a n + c n^2 it is |c| sigma^2 / sqrt(a^2 sigma^2 + 3 c^2 sigma^4): 0 when linear, 1/sqrt(3)
  // when purely quadratic. 1 when the sigma points leave the domain of the closed form (a range
  // through infinity) and for closest-point fixes of circles that do not meet. The multi fix
  // leaves it 0, or 1 when its sigma points fail and it keeps (J^T W J)^-1.
  double nonlinearity = 0.0;
  bool linearisationHolds(double max_nonlinearity) const { return nonlinearity <= max_nonlinearity; }
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
  // The least-squares fix's model of stereo observations. With a rig (the one that took the
  // pixels, Dataset::rig), an observation that carries pixels and a pixel covariance, and
  // the landmark's 3D position (the overload of fixFromLandmarks with Vector3d landmarks, and
  // globalFix), the residual is the stereo pixel factor on (u_l, u_r) (factors/stereo_pixel_factor.h,
  // PixelResiduals::Columns: the same data as range and bearing) whitened by its pixel covariance:
  // predicted at the pose being estimated, so that the weights do not depend on the noisy
  // measurement. Without a rig: range and bearing with R at the measured pixels (5.32).
  // Measured with `stereoloc fixstudy` (goal corners, 0.5 px, 3.5 deg compass): docs/results.md.
  std::optional<StereoRig> rig;
  // How the fixes' covariances are computed (see FixCovariance). Default: sigma points.
  FixCovariance covariance = FixCovariance::SigmaPoints;
  // SigmaPoints, and the least-squares fix's residual: treat the range of an observation that
  // came from the stereo rig (Observation::pixels set) as inverse range rho = 1/r. Stereo range is r = f b / disparity
  // (3.4, 3.6), so rho is linear in the pixels: its noise is Gaussian with a variance that does
  // not depend on the (noisy) disparity, whereas r is skewed and its variance R(0,0) ~ r^4 is
  // evaluated at the noisy range. Observations without pixels (range sensors) keep r.
  bool stereo_inverse_range = true;
  // A fix on its own (the fix1 and fix2 methods, fixstudy) takes one view's share of each
  // sighting's covariance (Observation::single_view_share). A tracker that starts from the fix
  // goes on fusing sightings of the same landmarks, whose errors repeat those the fix used, and
  // keeps the stated covariance (defaultGlobalFix), so that the fix's sightings count no more
  // than the later ones. The running fix always keeps it: its two sightings are of one landmark.
  bool single_view_covariance = true;
  // A fix's linearisation "holds" when its nonlinearity (GlobalFix::nonlinearity) is at most this.
  // Used to split consistency checks (fixstudy, tests); it does not change the fix. 0.05: the
  // second-order bias is below 5 % of the position sigma (its square below 0.25 % of the MSE).
  double linear_max_nonlinearity = 0.05;
};

// Best available fix from one step's observations (those with landmark_id >= 0; positions
// from the map; an id the map lacks throws stereoloc::Error). Preference: multi (n >= 3, or
// n >= 2 with a compass), then fix2 with the pair seen furthest apart (largest
// |sin(psi_j - psi_i)|), then fix1 with the landmark seen closest to the optical axis. The
// choices use the bearings, not the covariances, which grow with the measured (noisy) ranges:
// choosing by them selects on the noise and makes the chosen fixes over-confident.
// Returns NotEnoughLandmarks when no allowed method applies.
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

// multi: minimises sum |S_i (h(p, l_i) [-] z_i)|^2 (+ the compass residual; stereo ranges as
// inverse range, see GlobalFixOptions::stereo_inverse_range; or the pixel residual, see
// GlobalFixOptions::rig) with Ceres, started from both candidates of the best pair (or from fix1
// when only one pair is missing). Covariance: FixCovariance::SigmaPoints (default) the mean
// squared error of the least-squares estimator about the estimate, by the same fifth-degree rule
// over the whitened measurement noise (2 per observation, 1 for the compass; each point re-solved
// by Gauss-Newton from the estimate); otherwise (J^T W J)^-1 at the optimum, which is
// over-confident with stereo (fixstudy, 2 goal corners + 3.5 deg compass: mean 3-dof NEES
// 5.9-8.7, 2-dof 3.9-4.8; sigma points 3.00-3.10 / 1.91-2.02). Needs n >= 3, or n >= 2 with a
// compass (nullopt = no compass).
GlobalFix fixFromLandmarks(const std::vector<Observation>& observations, const std::vector<Eigen::Vector2d>& landmarks,
                           const std::optional<double>& compass_theta, double compass_sigma,
                           const GlobalFixOptions& options = {});
// The same with 3D landmark positions (mm, world; z = height above the floor), which the pixel
// residual needs (GlobalFixOptions::rig).
GlobalFix fixFromLandmarks(const std::vector<Observation>& observations, const std::vector<Eigen::Vector3d>& landmarks,
                           const std::optional<double>& compass_theta, double compass_sigma,
                           const GlobalFixOptions& options = {});

// The options of a fix that starts or re-anchors a tracker: the sightings' stated covariances
// (GlobalFixOptions::single_view_covariance).
GlobalFixOptions trackerFixOptions();

// The sighting as a fix with `options` takes it: the covariances scaled by its single-view share
// when options.single_view_covariance (and the share then 1, so that scaling twice is scaling
// once); unchanged otherwise.
Observation fixSighting(const Observation& observation, const GlobalFixOptions& options);

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
  double nonlinearity = 0.0;                 // as GlobalFix::nonlinearity
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
