#pragma once
// The stereo pixel calibration factor with the rectified rows' misalignment dv as a block of its
// own: residuals, frames and units as factors/stereo_pixel_calibration_factor.h, whose "Row
// offset" paragraph gives the model: the right column moves by s dv, s the observation's slide
// gain (Observation::slide_gain). Blocks: pose (3), stereo calibration q (6), optionally the
// whitened image errors e (12, factors/stereo_pixel_image_calibration_factor.h), and dv (1, px).
// The batch smoother and the sliding window estimate dv when the noise model states the rows'
// misalignment (UnmodelledNoise::row_offset_sigma_px, rowOffsetSigma in
// solvers/self_calibration.h), with that sigma as its prior.
#include <ceres/cost_function.h>

#include <Eigen/Core>
#include <cmath>
#include <optional>
#include <string>

#include "factors/stereo_pixel_calibration_factor.h"

namespace stereoloc {

struct StereoPixelRowCalibrationFactor {
  using ImageErrorVector = stereo_pixel_calibration::ImageErrorVector;
  StereoPixelRowCalibrationFactor(const StereoRig& rig, const Eigen::Vector3d& landmark, const StereoPixels& pixels,
                                  double slide_gain, double pan, const Eigen::Matrix4d& sqrt_information,
                                  PixelResiduals residuals, const ImageErrorVector* image_sigmas,
                                  const BodyRate& rate)
      : model_(rig, landmark, pixels, pan, sqrt_information, residuals, image_sigmas, rate, slide_gain) {}

  // Without the image block: (pose, q, dv).
  template <typename T>
  bool operator()(const T* pose, const T* calib, const T* row, T* residual) const {
    return model_.evaluate<T>(pose, calib, nullptr, row, residual);
  }
  // With it: (pose, q, e, dv).
  template <typename T>
  bool operator()(const T* pose, const T* calib, const T* image, const T* row, T* residual) const {
    return model_.evaluate<T>(pose, calib, image, row, residual);
  }

  static constexpr int kRowSize = 1;

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
