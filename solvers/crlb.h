#pragma once
// The posterior Cramér–Rao bound (CRLB) of a planar trajectory: the lower bound on the error
// covariance of any unbiased estimator of the poses, from the Fisher information of the data
// (prior on pose 0, odometry, range-bearing or pixel observations, compass; the project's
// models) evaluated at the TRUE trajectory. The information is block tridiagonal, so each bound
// costs O(N). Bounds per pose, 3x3 in (x, y, theta) (mm^2, mm rad, rad^2):
//   smoothing  [J^-1]_kk: all the data (the batch smoother);
//   filtering  the Tichavsky-Muravchik-Nehorai recursion: causal estimators (EKF, PF);
//   fixed lag  L: data up to step k + L (the sliding window's history, L = W - 1).
// Derivation and the factor informations: docs/estimators.md, "The Cramér–Rao bound".
#include <Eigen/Core>
#include <string>
#include <vector>

#include "solvers/smoother_common.h"
#include "src/io/dataset.h"
#include "src/core/field_map.h"
#include "src/core/odometry_model.h"
#include "src/core/pose2.h"
#include "src/core/types.h"

namespace stereoloc {

// Where U_k (controlCovariance) is evaluated.
enum class OdometryCovarianceAt {
  Truth,     // at the wheel increments of the true motion between the true poses
  Measured,  // at the step's measured wheel increments (what the estimators use)
};
std::string toString(OdometryCovarianceAt at);                           // "truth", "measured"
OdometryCovarianceAt odometryCovarianceAtFromString(const std::string& name);  // throws stereoloc::Error

// Which terms enter the information (all by default; switching some off shows that information
// adds, and gives the bound of estimators that ignore a sensor).
struct CrlbOptions {
  bool prior = true;
  bool odometry = true;
  bool observations = true;
  bool compass = true;
  OdometryCovarianceAt odometry_covariance = OdometryCovarianceAt::Truth;
  ObservationModelConfig observation_model;  // the information of which data (see the header comment)
};

// The Fisher information of a trajectory of N poses in block-tridiagonal form.
struct TrajectoryInformation {
  std::vector<long> steps;                    // step number of each pose
  std::vector<Eigen::Matrix3d> unary;         // prior (pose 0), compass and range-bearing on pose k
  // The odometry factor between poses k-1 and k, stored at index k (index 0 is zero):
  std::vector<Eigen::Matrix3d> odometry_prev;   // D11 = Ja^T U^-1 Ja   (on pose k-1)
  std::vector<Eigen::Matrix3d> odometry_cross;  // D12 = Ja^T U^-1 Jb   (pose k-1 row, pose k column)
  std::vector<Eigen::Matrix3d> odometry_curr;   // D22 = Jb^T U^-1 Jb   (on pose k)
  long observations_used = 0;
  long observations_skipped = 0;  // unidentified (landmark_id -1) or degenerate (landmark under the robot)
  long compass_used = 0;

  size_t size() const { return steps.size(); }
  // A trajectory with n poses and zero information.
  static TrajectoryInformation zero(const std::vector<long>& steps);
  // Information adds: the same poses, blockwise sum. Throws stereoloc::Error on different poses.
  TrajectoryInformation& operator+=(const TrajectoryInformation& other);
  // The diagonal blocks D_k and the super-diagonal blocks B_k = J(k-1, k) (B_0 = 0) of the full
  // information (the form of chainMarginalCovariances, solvers/smoother_common.h).
  void chainBlocks(std::vector<Eigen::Matrix3d>* D, std::vector<Eigen::Matrix3d>* B) const;
  // The full 3N x 3N matrix (tests, small problems).
  Eigen::MatrixXd dense() const;
};

// The information of one odometry factor between true poses a and b with covariance U: the 6x6
// [Ja Jb]^T U^-1 [Ja Jb] (pose a first).
Eigen::Matrix<double, 6, 6> odometryFactorInformation(const Pose2& a, const Pose2& b, const Eigen::Matrix3d& U);
// The information of one range-bearing observation with covariance R of `landmark` (mm, world)
// from the true pose: H^T R^-1 H. Throws GeometryError when the landmark is at the robot.
Eigen::Matrix3d rangeBearingInformation(const Pose2& pose, const Eigen::Vector2d& landmark, const Eigen::Matrix2d& R);
// The information of one observation's pixels (it must have pixels and a pixel sigma) from the
// true pose under a pixel observation model. Throws GeometryError when the landmark is not in
// front of the cameras there.
Eigen::Matrix3d pixelInformation(const Pose2& pose, const Observation& obs, const Landmark& landmark,
                                 const ObservationModelConfig& model);

// Builds the information of `steps` at the true poses `truth` (same length). The first step is
// the initial time (its odometry is not used, as in every estimator); prior_covariance is P0 of
// the initial belief (unused when options.prior is false). Throws stereoloc::Error on mismatched
// lengths, an empty trajectory, a prior or U that is not positive definite, unknown landmark ids.
TrajectoryInformation trajectoryInformation(const std::vector<Step>& steps, const std::vector<Pose2>& truth,
                                            const FieldMap& map, const OdometryParams& odometry,
                                            const Eigen::Matrix3d& prior_covariance,
                                            const CrlbOptions& options = CrlbOptions());
// The same for a dataset with ground truth at every step (throws stereoloc::Error otherwise).
TrajectoryInformation trajectoryInformation(const Dataset& dataset, const Eigen::Matrix3d& prior_covariance,
                                            const CrlbOptions& options = CrlbOptions());

// Per-pose bounds (see the header comment). Throw stereoloc::Error naming the pose when the
// information is singular there (e.g. no prior and no observation fixes the trajectory).
std::vector<Eigen::Matrix3d> smoothingBound(const TrajectoryInformation& info);
std::vector<Eigen::Matrix3d> filteringBound(const TrajectoryInformation& info);
std::vector<Eigen::Matrix3d> fixedLagBound(const TrajectoryInformation& info, int lag);

}  // namespace stereoloc
