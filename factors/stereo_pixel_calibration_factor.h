#pragma once
// Stereo pixel factor with the stereo calibration as parameters (self-calibration): the head
// tilt, the baseline and the pixel offsets of the pair as the robot really has them, against
// the rig the user measured.
//
//   r = S (pi(p, l; q) - z)                                4 residuals (u_l, v_l, u_r, v_r) or
//                                                          2 (u_l, u_r) with PixelResiduals::Columns
//
// p: robot pose (x, y, theta), world frame (mm, mm, rad). l: landmark (x, y, z), world, mm.
// q = (dbeta, k, delta_d, delta_u, phi, psi): calibration block; dbeta the tilt correction
// (rad, added to the rig's tilt beta; > 0 looks further down), k the baseline scale
// (dimensionless, nominally 1), delta_d the disparity offset and delta_u the column offset (px,
// nominally 0), phi the right camera's focal length error relative to the left's and psi the
// left camera's focal length error (dimensionless, nominally 0). pi: the projection of
// factors/stereo_pixel_factor.h with C0 -> C1 (pan) -> C2 (offset, height, tilt beta + dbeta),
// then, with F = f (1 + psi),
//   u_l = o_u + delta_u + delta_d / 2 - F (y - k b/2) / x,
//   u_r = o_u + delta_u - delta_d / 2 - F (1 + phi) (y + k b/2) / x,   v = o_v - F z / x,
// so the disparity u_l - u_r is F k b / x + delta_d (+ phi F (y + k b/2) / x) and the mean
// column moves by delta_u.
// Why these: range is f b / disparity (3.4), so a baseline error is a range scale error and a
// disparity offset a range error growing with range^2 (a difference of the principal points,
// or a relative yaw eps of the cameras, f eps: 0.1 deg is ~0.5 px at f = 277 px, a large
// fraction of the disparity of a far landmark); a focal length difference of the two cameras
// is a disparity error proportional to the bearing's tangent (0.7 % of 277 px: 1.1 px at 30 deg);
// delta_u is a bearing offset (mean principal point, head pan); a focal length error common to
// both cameras (psi; 0.5 % of 277 px is 0.8 px at 30 deg) scales the tangent of every bearing,
// which a baseline scale cannot absorb: F k b is the range scale, F alone the bearing scale, so
// a known map separates the two; the tilt sets where the floor
// and the landmarks appear in the rows and, through the (3.4) -> (3.5) rotation, the range of
// every point below or above the camera. The columns enter through an equivalent point in C2:
// any (u_l, u_r) is the projection of y' = (2 o_u - u_l - u_r) x / (2 f) with half baseline
// (u_l - u_r) x / (2 f), so v is unchanged and the shared residual code applies.
// z: measured pixels; S: the upper square-root information of their covariance, as in
// factors/stereo_pixel_factor.h.
// Evaluation fails when the landmark is not in front of the cameras.
#include <ceres/autodiff_cost_function.h>

#include <Eigen/Core>
#include <cmath>

#include "factors/stereo_pixel_factor.h"
#include "src/core/error.h"
#include "src/core/stereo_rig.h"

namespace stereoloc {

struct StereoPixelCalibrationFactor {
  StereoPixelCalibrationFactor(const StereoRig& rig, const Eigen::Vector3d& landmark, const StereoPixels& pixels,
                               double pan, const Eigen::Matrix4d& sqrt_information, PixelResiduals residuals)
      : landmark_(landmark), sqrt_info_(sqrt_information), rows_(residuals == PixelResiduals::All) {
    pan_cos_ = std::cos(pan);
    pan_sin_ = std::sin(pan);
    t_ = Eigen::Vector3d(rig.params().offset_x_mm, 0.0, rig.params().camera_height_mm);
    tilt_ = rig.params().tilt_rad;
    f_ = rig.focal();
    ou_ = rig.principalU();
    ov_ = rig.principalV();
    half_baseline_ = 0.5 * rig.params().baseline_mm;
    z_ << pixels.u_left, pixels.v_left, pixels.u_right, pixels.v_right;
  }

  template <typename T>
  bool operator()(const T* pose, const T* calib, T* residual) const {
    using std::cos;
    using std::sin;
    // C0: R(theta)^T (l_xy - t_xy), height unchanged; C1: Rz(pan)^T; then minus the offset t.
    const T dx = T(landmark_[0]) - pose[0], dy = T(landmark_[1]) - pose[1];
    const T c = cos(pose[2]), s = sin(pose[2]);
    const T x0 = c * dx + s * dy, y0 = -s * dx + c * dy;
    const T x1 = T(pan_cos_) * x0 + T(pan_sin_) * y0 - T(t_[0]);
    const T y1 = -T(pan_sin_) * x0 + T(pan_cos_) * y0;
    const T z1 = T(landmark_[2]) - T(t_[2]);
    // C2 = R_y(beta)^T C1 (stereo_rig.h: R_tilt = [c 0 s; 0 1 0; -s 0 c]).
    const T beta = T(tilt_) + calib[0];
    const T cb = cos(beta), sb = sin(beta);
    const T x2 = cb * x1 - sb * z1, z2 = sb * x1 + cb * z1;
    if (!(x2 > T(stereo_pixel::kMinDepth))) return false;
    const T hb = calib[1] * T(half_baseline_);
    const T f = T(f_) * (T(1.0) + calib[5]);
    // Columns relative to o_u.
    const T cl = calib[3] + 0.5 * calib[2] - f * (y1 - hb) / x2;
    const T cr = calib[3] - 0.5 * calib[2] - f * (T(1.0) + calib[4]) * (y1 + hb) / x2;
    const T per_px = x2 / T(f_);  // mm in C2 per pixel of column at this depth, for the shared code's f
    const T y2 = -0.5 * (cl + cr) * per_px;
    const T half_baseline = 0.5 * (cl - cr) * per_px;
    // The rows through the same F: the shared code projects with the nominal f, so z scales.
    return stereo_pixel::whitenedResiduals(x2, y2, (T(1.0) + calib[5]) * z2, half_baseline, f_, ou_, ov_, sqrt_info_,
                                           rows_, z_, residual);
  }

  static constexpr int kCalibrationSize = 6;  // (dbeta, k, delta_d, delta_u, phi, psi)

  // Blocks: pose (3), stereo calibration (dbeta, k, delta_d, delta_u, phi, psi) (6).
  static ceres::CostFunction* Create(const StereoRig& rig, const Eigen::Vector3d& landmark, const StereoPixels& pixels,
                                     double pan, const Eigen::Matrix4d& pixel_covariance, PixelResiduals residuals) {
    constexpr const char* kWho = "stereo pixel calibration factor";
    stereo_pixel::checkInputs(kWho, pixels, pan, landmark);
    auto* functor = new StereoPixelCalibrationFactor(
        rig, landmark, pixels, pan,
        stereo_pixel::sqrtInformation(kWho, pixel_covariance, residuals == PixelResiduals::All), residuals);
    if (residuals == PixelResiduals::All)
      return new ceres::AutoDiffCostFunction<StereoPixelCalibrationFactor, 4, 3, kCalibrationSize>(functor);
    return new ceres::AutoDiffCostFunction<StereoPixelCalibrationFactor, 2, 3, kCalibrationSize>(functor);
  }
  // The same with independent pixels of noise sigma (px, > 0).
  static ceres::CostFunction* Create(const StereoRig& rig, const Eigen::Vector3d& landmark, const StereoPixels& pixels,
                                     double pan, double sigma, PixelResiduals residuals) {
    return Create(rig, landmark, pixels, pan,
                  stereo_pixel::covarianceFromSigma("stereo pixel calibration factor", sigma), residuals);
  }

 private:
  Eigen::Vector3d landmark_;
  Eigen::Matrix4d sqrt_info_;
  bool rows_;
  double pan_cos_ = 1, pan_sin_ = 0, tilt_ = 0;
  Eigen::Vector3d t_;
  double f_ = 0, ou_ = 0, ov_ = 0, half_baseline_ = 0;
  Eigen::Vector4d z_;
};

}  // namespace stereoloc
