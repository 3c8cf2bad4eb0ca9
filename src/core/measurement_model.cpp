#include "src/core/measurement_model.h"

#include <Eigen/Cholesky>

#include "src/core/error.h"

namespace stereoloc {

Eigen::Vector2d predictRangeBearing(const Pose2& pose, const Eigen::Vector2d& landmark, Matrix23d* J_z_pose) {
  const double dx = landmark.x() - pose.x, dy = landmark.y() - pose.y;
  const double q = dx * dx + dy * dy;
  if (!(q > 1e-12)) throw GeometryError("range-bearing: landmark coincides with the robot position");
  const double r = std::sqrt(q);
  if (J_z_pose) {
    *J_z_pose << -dx / r, -dy / r, 0.0,  //
        dy / q, -dx / q, -1.0;
  }
  return Eigen::Vector2d(r, wrapAngle(std::atan2(dy, dx) - pose.theta));
}

Eigen::Matrix4d stereoPixelCovariance(double sigma_u, double sigma_v, double sigma_d, double corr_ud) {
  auto positive = [](double v, const char* name) {
    if (!(std::isfinite(v) && v > 0)) throw Error(std::string("stereo pixel covariance: ") + name + " must be positive");
  };
  positive(sigma_u, "sigma_u");
  positive(sigma_v, "sigma_v");
  positive(sigma_d, "sigma_d");
  if (!(std::isfinite(corr_ud) && std::fabs(corr_ud) < 1))
    throw Error("stereo pixel covariance: corr_ud must lie in (-1, 1)");
  Eigen::Vector4d sd(sigma_u, sigma_v, sigma_d, kRowDifferenceSigma);
  Eigen::Matrix4d C_uvd = sd.asDiagonal();
  C_uvd = C_uvd * C_uvd;
  C_uvd(0, 2) = C_uvd(2, 0) = corr_ud * sigma_u * sigma_d;
  // (u_l, v_l, u_r, v_r) = A (u, v, d, delta).
  Eigen::Matrix4d A;
  A << 1, 0, 0, 0,  //
      0, 1, 0, 0,   //
      1, 0, -1, 0,  //
      0, 1, 0, 1;
  const Eigen::Matrix4d C = A * C_uvd * A.transpose();
  return 0.5 * (C + C.transpose());
}

Eigen::Matrix4d isotropicPixelCovariance(double sigma) {
  if (!(std::isfinite(sigma) && sigma > 0)) throw Error("pixel sigma must be a positive number");
  return sigma * sigma * Eigen::Matrix4d::Identity();
}

void checkPixelCovariance(const Eigen::Matrix4d& C, const std::string& where) {
  if (!C.allFinite()) throw Error(where + ": pixel covariance is not finite");
  if ((C - C.transpose()).cwiseAbs().maxCoeff() > 1e-9 * C.cwiseAbs().maxCoeff())
    throw Error(where + ": pixel covariance is not symmetric");
  const Eigen::LLT<Eigen::Matrix4d> llt(C);
  if (llt.info() != Eigen::Success || !(C.diagonal().minCoeff() > 0))
    throw Error(where + ": pixel covariance is not positive definite");
}

Eigen::Matrix2d rangeBearingCovariance(const StereoRig& rig, const StereoPixels& px, double pan,
                                       const Eigen::Matrix4d& pixel_covariance) {
  checkPixelCovariance(pixel_covariance, "range-bearing covariance");
  StereoRig::Matrix24d J;
  rig.rangeBearing(px, pan, &J);
  const Eigen::Matrix2d R = J * pixel_covariance * J.transpose();  // (5.32)
  return 0.5 * (R + R.transpose());
}

}  // namespace stereoloc
