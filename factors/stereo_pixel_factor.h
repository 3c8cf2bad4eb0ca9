#pragma once
// Stereo pixel factor: a known landmark seen by the stereo rig, compared in the images, where
// the sensor's noise lives (thesis 3.4-3.7 run forwards, as a factor).
//
//   r = S (pi(p, l) - z)                             4 residuals (u_l, v_l, u_r, v_r), px / px
//                                                    or 2 (u_l, u_r) with PixelResiduals::Columns
//
// p: robot pose (x, y, theta), world frame (mm, mm, rad). l: landmark (x, y, z), world frame,
// mm. pi: the rig's projection (StereoRig::project, src/core/stereo_rig.h) of l expressed in the
// robot frame C0, with the head pan of the observation: C0 -> C1 (pan) -> C2 (offset, height,
// tilt) -> u_l = o_u - f (y - b/2) / x, u_r = o_u - f (y + b/2) / x, v = o_v - f z / x.
// z: the measured pixels; C: their covariance (px^2, Observation::pixel_covariance, order u_l,
// v_l, u_r, v_r; src/core/measurement_model.h); S: the upper Cholesky factor of the information
// C^-1 (S^T S = C^-1), or of the inverse of C's (u_l, u_r) block with Columns. The frontend's
// left and right column errors are strongly correlated (a corner's sub-pixel error is common to
// both images), so S is not diagonal; sigma^2 I gives the thesis's independent pixels (5.28).
//
// Why a pixel factor beside the range-bearing factor (factors/range_bearing_factor.h): the
// range-bearing form (3.6, 3.7, 5.32) converts each observation before estimation. The
// conversion range = f b / d is nonlinear in the disparity d, and R (5.32) is evaluated at the
// measured pixels, so an observation whose disparity came out large gets a small range AND a
// small variance (R_rr grows with range^4): the weights correlate with the errors, and the
// estimate is biased towards short ranges. Here the prediction is made at the estimate and the
// residual is linear in the noise, which is the maximum-likelihood form of the sensor model.
// Columns uses the same data as the range-bearing form of an untilted rig (u_l, u_r determine
// range and bearing; a tilted rig's triangulation 3.4 also uses v);
// All adds the rows, which carry range through the known heights of camera and landmark (a
// point below the cameras appears lower the nearer it is) — information the range-bearing
// form discards, valid as long as the rig's height and tilt are known.
//
// Evaluation fails (returns false, Ceres then shrinks the step) when the landmark is not in
// front of the cameras at the evaluated pose.
#include <ceres/cost_function.h>

#include <Eigen/Core>
#include <cmath>
#include <string>

#include "src/core/error.h"
#include "src/core/measurement_model.h"
#include "src/core/stereo_rig.h"

namespace stereoloc {

// Which pixel coordinates enter the residual.
enum class PixelResiduals {
  Columns,  // u_l, u_r: range and bearing (the data of the range-bearing form)
  All,      // u_l, v_l, u_r, v_r: also the rows (range from the known heights)
};

// The parts the stereo pixel factors share: the whitened residuals of a point in the rectified
// camera frame C2 (x forward, y left, z up; mm) against the measured pixels z = (u_l, v_l, u_r,
// v_r), and the check of a factor's inputs. Returns false behind (or at) the cameras.
namespace stereo_pixel {
inline constexpr double kMinDepth = 1e-6;  // mm, as StereoRig::project

// The upper square-root information S of the residuals (see the file comment): 4x4 with rows,
// else the 2x2 of (u_l, u_r) in the top-left corner (the rest zero). Throws stereoloc::Error
// "<who>: ..." unless C is finite, symmetric and positive definite.
Eigen::Matrix4d sqrtInformation(const char* who, const Eigen::Matrix4d& C, bool rows);

template <typename T>
bool whitenedResiduals(const T& x2, const T& y2, const T& z2, const T& half_baseline, double f, double ou, double ov,
                       const Eigen::Matrix4d& sqrt_information, bool rows, const Eigen::Vector4d& z, T* residual) {
  if (!(x2 > T(kMinDepth))) return false;
  const T inv_x = T(1.0) / x2;
  const T u_l = T(ou) - T(f) * (y2 - half_baseline) * inv_x;
  const T u_r = T(ou) - T(f) * (y2 + half_baseline) * inv_x;
  const Eigen::Matrix4d& S = sqrt_information;
  if (rows) {
    const T v = T(ov) - T(f) * z2 * inv_x;
    const T e[4] = {u_l - T(z[0]), v - T(z[1]), u_r - T(z[2]), v - T(z[3])};
    for (int i = 0; i < 4; ++i) {
      residual[i] = T(S(i, i)) * e[i];
      for (int j = i + 1; j < 4; ++j) residual[i] += T(S(i, j)) * e[j];
    }
  } else {
    const T e0 = u_l - T(z[0]), e1 = u_r - T(z[2]);
    residual[0] = T(S(0, 0)) * e0 + T(S(0, 1)) * e1;
    residual[1] = T(S(1, 1)) * e1;
  }
  return true;
}

// Throws stereoloc::Error "<who>: ..." unless the pixels, pan and landmark are finite.
void checkInputs(const char* who, const StereoPixels& pixels, double pan, const Eigen::Vector3d& landmark);

// C from a scalar sigma (the thesis's 5.28), with the scalar overloads' error message.
Eigen::Matrix4d covarianceFromSigma(const char* who, double sigma);
}  // namespace stereo_pixel

struct StereoPixelFactor {
  // rig: the stereo rig; landmark: (x, y, z) mm, world; pixels: the measured pixels; pan: head
  // pan at the time of the images (rad); sqrt_information: S of the file comment
  // (stereo_pixel::sqrtInformation).
  StereoPixelFactor(const StereoRig& rig, const Eigen::Vector3d& landmark, const StereoPixels& pixels, double pan,
                    const Eigen::Matrix4d& sqrt_information, PixelResiduals residuals);

  template <typename T>
  bool operator()(const T* pose, T* residual) const {
    using std::cos;
    using std::sin;
    // The landmark in C0: R(theta)^T (l_xy - t_xy), height unchanged (the floor is the plane z = 0).
    const T dx = T(landmark_[0]) - pose[0], dy = T(landmark_[1]) - pose[1];
    const T c = cos(pose[2]), s = sin(pose[2]);
    const T p0[3] = {c * dx + s * dy, -s * dx + c * dy, T(landmark_[2])};
    T p2[3];
    for (int i = 0; i < 3; ++i)
      p2[i] = T(M_(i, 0)) * p0[0] + T(M_(i, 1)) * p0[1] + T(M_(i, 2)) * p0[2] - T(m_[i]);
    return stereo_pixel::whitenedResiduals(p2[0], p2[1], p2[2], T(half_baseline_), f_, ou_, ov_, sqrt_info_, rows_, z_,
                                           residual);
  }

  // pixel_covariance: C of the file comment (px^2, symmetric positive definite).
  static ceres::CostFunction* Create(const StereoRig& rig, const Eigen::Vector3d& landmark, const StereoPixels& pixels,
                                     double pan, const Eigen::Matrix4d& pixel_covariance, PixelResiduals residuals);
  // The same with independent pixels of noise sigma (px, > 0): C = sigma^2 I.
  static ceres::CostFunction* Create(const StereoRig& rig, const Eigen::Vector3d& landmark, const StereoPixels& pixels,
                                     double pan, double sigma, PixelResiduals residuals);

  static constexpr double kMinDepth = stereo_pixel::kMinDepth;

 private:
  Eigen::Vector3d landmark_;
  Eigen::Matrix4d sqrt_info_;
  bool rows_;
  Eigen::Matrix3d M_;
  Eigen::Vector3d m_;
  double f_ = 0, ou_ = 0, ov_ = 0, half_baseline_ = 0;
  Eigen::Vector4d z_;
};

}  // namespace stereoloc
