#pragma once
// The joint least-squares problem of a stereo calibration from checkerboard pairs: every pair's
// board corners in both images against their projections through both cameras, over both
// cameras' intrinsics, the right camera's pose against the left and every board pose
// (src/calib/stereo_target_calibration.h solves it and takes its covariance).
//
//   left   pi(K1, D1, r_v, t_v; X)                    X_left  = R_v X + t_v
//   right  pi(K2, D2, r (+) r_v, R t_v + T; X)        X_right = R (R_v X + t_v) + T
// pi is cv::projectPoints (rotation vectors, OpenCV's distortion model). The Jacobian
// J_residual_parameters comes from cv::projectPoints' own Jacobians, chained through
// cv::composeRT's for the right camera (tested against central differences). Units: px, mm, rad.
#include <Eigen/Core>
#include <opencv2/core.hpp>
#include <vector>

namespace stereoloc {

// The parameters, in the order of the Jacobian's columns:
//   per camera c: fx, fy (one f when same_focal), cx, cy, the distortion coefficients;
//   R's rotation vector r and T; per pair v, the board's pose in the left camera, r_v and t_v.
struct StereoTargetLayout {
  bool same_focal = false;
  int distortion = 4;  // coefficients per camera
  int pairs = 0;
  int intrinsics() const { return (same_focal ? 3 : 4) + distortion; }
  int camera(int c) const { return c * intrinsics(); }
  int focalX(int c) const { return camera(c); }
  int principalX(int c) const { return camera(c) + (same_focal ? 1 : 2); }
  int relative() const { return 2 * intrinsics(); }  // r, then T
  int view(int v) const { return relative() + 6 + 6 * v; }  // r_v, then t_v
  int size() const { return view(pairs); }
};

struct StereoTargetParameters {
  cv::Mat K[2], D[2];  // CV_64F; D is 1 x layout.distortion
  cv::Vec3d r, T;
  std::vector<cv::Vec3d> rv, tv;

  // The parameters moved by dx (layout's order; additive in every coordinate, fx = fy moved
  // together when same_focal).
  StereoTargetParameters plus(const StereoTargetLayout& layout, const Eigen::VectorXd& dx) const;
};

// The columns of a cv::projectPoints Jacobian (rvec 3, tvec 3, fx, fy, cx, cy, distortion) in
// the layout's order for one camera's intrinsics (fx + fy when same_focal): rows x intrinsics().
Eigen::MatrixXd intrinsicColumns(const cv::Mat& projection_jacobian, const StereoTargetLayout& layout);

// Pair v's residuals e (projected - measured, px: left then right, x and y per corner, 4 N) and,
// with J non-null, J_residual_parameters (4 N x layout.size()).
void stereoTargetResiduals(const StereoTargetParameters& p, const StereoTargetLayout& layout, int v,
                           const std::vector<cv::Point3d>& object, const std::vector<cv::Point2f>& left,
                           const std::vector<cv::Point2f>& right, Eigen::VectorXd& e, Eigen::MatrixXd* J);

}  // namespace stereoloc
