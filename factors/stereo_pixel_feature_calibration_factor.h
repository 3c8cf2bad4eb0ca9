#pragma once
// The stereo pixel row calibration factor with the observed feature's own offsets (b_c, b_d) as a
// further block: residuals, frames and units as factors/stereo_pixel_calibration_factor.h, the
// left column moved by b_c and the right by s dv + b_c + b_d (s the observation's slide gain, dv
// the rows' misalignment). Blocks: pose (3), stereo calibration q (6), optionally the whitened
// image errors e (12), dv (1, px) and (b_c, b_d) (2, px). A feature's column error (its bearing)
// and, for a feature matched along a marking, its u_r error about s dv repeat from sighting to
// sighting (the same edges, similar views, the same misalignment); the batch smoother gives each
// feature these offsets, zero-mean with the noise model's sigmas (featureOffsetSigmas in
// solvers/self_calibration.h), so that the repetition is estimated rather than averaged as if
// it were white.
#include <ceres/cost_function.h>

#include <Eigen/Core>
#include <cmath>
#include <string>

#include "factors/stereo_pixel_calibration_factor.h"

namespace stereoloc {

struct StereoPixelFeatureCalibrationFactor {
  using ImageErrorVector = stereo_pixel_calibration::ImageErrorVector;
  StereoPixelFeatureCalibrationFactor(const StereoRig& rig, const Eigen::Vector3d& landmark, const StereoPixels& pixels,
                                      double slide_gain, double pan, const Eigen::Matrix4d& sqrt_information,
                                      PixelResiduals residuals, const ImageErrorVector* image_sigmas,
                                      const BodyRate& rate)
      : model_(rig, landmark, pixels, pan, sqrt_information, residuals, image_sigmas, rate, slide_gain) {}

  // Without the image block: (pose, q, dv, (b_c, b_d)).
  template <typename T>
  bool operator()(const T* pose, const T* calib, const T* row, const T* offset, T* residual) const {
    return model_.evaluate<T>(pose, calib, nullptr, row, offset, residual);
  }
  // With it: (pose, q, e, dv, (b_c, b_d)).
  template <typename T>
  bool operator()(const T* pose, const T* calib, const T* image, const T* row, const T* offset, T* residual) const {
    return model_.evaluate<T>(pose, calib, image, row, offset, residual);
  }

  static constexpr int kOffsetSize = 2;

  // `slide_gain`: the observation's (finite); `image_sigmas`: the image block's sigmas (each
  // finite and >= 0), or null for the factor without the image block; `rate`: the robot's
  // motion at the image (bodyRate), for the image block's exposure offset.
  static ceres::CostFunction* Create(const StereoRig& rig, const Eigen::Vector3d& landmark, const StereoPixels& pixels,
                                     double slide_gain, double pan, const Eigen::Matrix4d& pixel_covariance,
                                     PixelResiduals residuals, const ImageErrorVector* image_sigmas,
                                     const BodyRate& rate);

 private:
  StereoPixelCalibrationModel model_;
};

}  // namespace stereoloc
