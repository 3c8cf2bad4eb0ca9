#include "factors/stereo_pixel_factor.h"

#include <ceres/autodiff_cost_function.h>

#include <Eigen/Cholesky>
#include <cmath>
#include <string>

namespace stereoloc {

ceres::CostFunction* StereoPixelFactor::Create(const StereoRig& rig, const Eigen::Vector3d& landmark,
                                               const StereoPixels& pixels, double pan,
                                               const Eigen::Matrix4d& pixel_covariance, PixelResiduals residuals) {
  constexpr const char* kWho = "stereo pixel factor";
  stereo_pixel::checkInputs(kWho, pixels, pan, landmark);
  auto* functor = new StereoPixelFactor(
      rig, landmark, pixels, pan,
      stereo_pixel::sqrtInformation(kWho, pixel_covariance, residuals == PixelResiduals::All), residuals);
  if (residuals == PixelResiduals::All) return new ceres::AutoDiffCostFunction<StereoPixelFactor, 4, 3>(functor);
  return new ceres::AutoDiffCostFunction<StereoPixelFactor, 2, 3>(functor);
}

ceres::CostFunction* StereoPixelFactor::Create(const StereoRig& rig, const Eigen::Vector3d& landmark,
                                               const StereoPixels& pixels, double pan, double sigma,
                                               PixelResiduals residuals) {
  return Create(rig, landmark, pixels, pan, stereo_pixel::covarianceFromSigma("stereo pixel factor", sigma), residuals);
}

namespace stereo_pixel {

Eigen::Matrix4d sqrtInformation(const char* who, const Eigen::Matrix4d& C, bool rows) {
  checkPixelCovariance(C, who);
  Eigen::Matrix4d S = Eigen::Matrix4d::Zero();
  if (rows) {
    const Eigen::Matrix4d info = Eigen::LLT<Eigen::Matrix4d>(C).solve(Eigen::Matrix4d::Identity());
    S = Eigen::LLT<Eigen::Matrix4d>(0.5 * (info + info.transpose())).matrixU();
  } else {
    Eigen::Matrix2d C2;
    C2 << C(0, 0), C(0, 2), C(2, 0), C(2, 2);
    const Eigen::Matrix2d info = Eigen::LLT<Eigen::Matrix2d>(C2).solve(Eigen::Matrix2d::Identity());
    S.topLeftCorner<2, 2>() = Eigen::LLT<Eigen::Matrix2d>(0.5 * (info + info.transpose())).matrixU();
  }
  if (!S.allFinite()) throw Error(std::string(who) + ": pixel covariance is not positive definite");
  return S;
}

void checkInputs(const char* who, const StereoPixels& pixels, double pan, const Eigen::Vector3d& landmark) {
  if (!(std::isfinite(pixels.u_left) && std::isfinite(pixels.v_left) && std::isfinite(pixels.u_right) &&
        std::isfinite(pixels.v_right) && std::isfinite(pan) && landmark.allFinite()))
    throw Error(std::string(who) + ": pixels, pan and landmark must be finite");
}

Eigen::Matrix4d covarianceFromSigma(const char* who, double sigma) {
  if (!(std::isfinite(sigma) && sigma > 0)) throw Error(std::string(who) + ": sigma must be a positive number");
  return sigma * sigma * Eigen::Matrix4d::Identity();
}

}  // namespace stereo_pixel

StereoPixelFactor::StereoPixelFactor(const StereoRig& rig, const Eigen::Vector3d& landmark, const StereoPixels& pixels,
                                     double pan, const Eigen::Matrix4d& sqrt_information, PixelResiduals residuals)
    : landmark_(landmark), sqrt_info_(sqrt_information), rows_(residuals == PixelResiduals::All) {
  // p_C2 = R_tilt^T (Rz(pan)^T p_C0 - t), t = (x_c, 0, h): a constant affine map per observation.
  const double c = std::cos(pan), s = std::sin(pan);
  Eigen::Matrix3d Rz_T;
  Rz_T << c, s, 0, -s, c, 0, 0, 0, 1;
  M_ = rig.tiltRotation().transpose() * Rz_T;
  m_ = rig.tiltRotation().transpose() * Eigen::Vector3d(rig.params().offset_x_mm, 0.0, rig.params().camera_height_mm);
  f_ = rig.focal();
  ou_ = rig.principalU();
  ov_ = rig.principalV();
  half_baseline_ = 0.5 * rig.params().baseline_mm;
  z_ << pixels.u_left, pixels.v_left, pixels.u_right, pixels.v_right;
}

}  // namespace stereoloc
