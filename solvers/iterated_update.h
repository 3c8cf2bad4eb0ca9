#pragma once
// The range-bearing update of a Gaussian pose belief: the EKF's one step (Algorithm 5) or the
// iterated EKF, Gauss-Newton on the MAP cost with step control. The one implementation used by
// the EKF (solvers/ekf.h) and by every hypothesis of the multi-hypothesis start
// (solvers/global_fix_hypotheses.h).
//
//   const auto gate = rangeBearingInnovationAt(prior, P, z, R, landmark);   // (5.14), (5.20)
//   if (gate && gate->mahalanobis_squared <= threshold)
//     const auto post = updateRangeBearingBelief(prior, P, z, R, landmark, {10, 1e-6});
//
// Prior x^ (mm, rad) with covariance P, observation z = (range mm, bearing rad) with covariance
// R of a landmark at l (mm, world), h = predictRangeBearing (5.27). With delta = x [-] x^ and
// nu(delta) = z [-] h(x^ [+] delta) (bearing wrapped), the MAP cost is
//       c(delta) = delta^T P^-1 delta + nu(delta)^T R^-1 nu(delta)  = |r(delta)|^2,
//       r(delta) = [ L_P^-1 delta ; L_R^-1 nu(delta) ]   (P = L_P L_P^T, R = L_R L_R^T),
//       J_r_delta = [ L_P^-1 ; -L_R^-1 H(delta) ],       H = dh/dx at x^ [+] delta.
// The Gauss-Newton step from delta_i solves the cost linearised at delta_i; in Kalman form
// (docs/estimators.md, "Iterated update"):
//       K_i = P H_i^T (H_i P H_i^T + R)^-1,   delta_GN = K_i (nu_i + H_i delta_i).
//   max_iterations == 1: delta = K_0 nu_0, the EKF update (5.15), (5.19) as printed.
//   max_iterations > 1:  delta_{i+1} = delta_i + a (delta_GN - delta_i), a = 1, 1/2, 1/4, ...
//                        the first a that lowers c (step control; a step that raises the cost
//                        by overshooting the curved bearing is never taken); the iteration
//                        stops when the step is below `tolerance`, when no a lowers c, or
//                        after max_iterations steps.
// The covariance is the Joseph form (5.17) with K and H at the final iterate.
#include <Eigen/Core>
#include <optional>

#include "src/core/pose2.h"

namespace stereoloc {

struct IteratedUpdateOptions {
  int max_iterations = 1;    // Gauss-Newton steps; 1: Algorithm 5's single step, no step control
  double tolerance = 1e-6;   // mm and rad: stop when no component of the accepted step is larger
  int max_step_halvings = 10;  // step control: the shortest step tried is 2^-max_step_halvings
};

// The innovation of a range-bearing observation at a belief: what the validation gate tests.
struct RangeBearingInnovation {
  Eigen::Vector2d innovation = Eigen::Vector2d::Zero();  // z [-] h(pose), (mm, rad), wrapped
  Eigen::Matrix2d covariance = Eigen::Matrix2d::Zero();  // S = H P H^T + R (5.14)
  Matrix23d J_h_pose = Matrix23d::Zero();                // H at the belief's pose
  double mahalanobis_squared = 0.0;                      // e^2 = nu^T S^-1 nu (5.20)
};

// nullopt when the bearing is undefined (the landmark at the robot) or e^2 is not finite.
std::optional<RangeBearingInnovation> rangeBearingInnovationAt(const Pose2& pose, const Eigen::Matrix3d& P,
                                                               const Eigen::Vector2d& z, const Eigen::Matrix2d& R,
                                                               const Eigen::Vector2d& landmark);

// r(delta) and J_r_delta of the header comment. nullopt when h is undefined at x^ [+] delta or
// P or R is not positive definite.
struct MapResidual {
  Eigen::Matrix<double, 5, 1> r = Eigen::Matrix<double, 5, 1>::Zero();
  Eigen::Matrix<double, 5, 3> J_r_delta = Eigen::Matrix<double, 5, 3>::Zero();
};
std::optional<MapResidual> rangeBearingMapResidual(const Pose2& prior, const Eigen::Matrix3d& P,
                                                   const Eigen::Vector2d& z, const Eigen::Matrix2d& R,
                                                   const Eigen::Vector2d& landmark, const Eigen::Vector3d& delta);

struct RangeBearingPosterior {
  Pose2 pose;                                            // x^ [+] delta, mm, rad
  Eigen::Matrix3d covariance = Eigen::Matrix3d::Zero();  // (5.17) at the final iterate
  int iterations = 0;       // Gauss-Newton steps taken
  double map_cost = 0.0;    // c(delta) at the result; +inf when P or R is not positive definite
};

// The update of the header comment. nullopt when h is undefined at the prior (nothing to fuse).
// Iterates whose bearing is undefined count as infinitely expensive (the step is shortened).
// With P or R not positive definite the cost is undefined: full Gauss-Newton steps then.
std::optional<RangeBearingPosterior> updateRangeBearingBelief(const Pose2& prior, const Eigen::Matrix3d& P,
                                                              const Eigen::Vector2d& z, const Eigen::Matrix2d& R,
                                                              const Eigen::Vector2d& landmark,
                                                              const IteratedUpdateOptions& options);

}  // namespace stereoloc
