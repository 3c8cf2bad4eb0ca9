#pragma once
// The stereo pixel calibration factor with a third block: the images' fixed errors e (the lens
// distortion estimate's error of each camera, the right camera's rotation against the left, the
// error of the right camera's exposure offset), the same in every image of a run. Residuals, frames, units and the model of e: see
// factors/stereo_pixel_calibration_factor.h ("Image errors"); e is whitened (parameter i is
// e_i sigma_i), so its prior is the identity. The batch smoother estimates e with the stereo
// block when SelfCalibrationConfig::image_errors is on.
#include <ceres/cost_function.h>

#include <Eigen/Core>
#include <string>

#include "factors/stereo_pixel_calibration_factor.h"

namespace stereoloc {

struct StereoPixelImageCalibrationFactor {
  using ImageErrorVector = stereo_pixel_calibration::ImageErrorVector;
  StereoPixelImageCalibrationFactor(const StereoRig& rig, const Eigen::Vector3d& landmark, const StereoPixels& pixels,
                                    double pan, const Eigen::Matrix4d& sqrt_information, PixelResiduals residuals,
                                    const ImageErrorVector& sigmas, const BodyRate& rate)
      : model_(rig, landmark, pixels, pan, sqrt_information, residuals, &sigmas, rate) {}

  template <typename T>
  bool operator()(const T* pose, const T* calib, const T* image, T* residual) const {
    return model_.evaluate<T>(pose, calib, image, residual);
  }

  static constexpr int kImageErrorSize = stereo_pixel_calibration::kImageErrorSize;

  // Blocks: pose (3), stereo calibration q (6), whitened image errors e (12). `sigmas`: the
  // 1-sigma of each image error (>= 0; the lens terms dimensionless, the rotations rad, the
  // exposure offset s); `rate`: the robot's motion at the image (bodyRate).
  static ceres::CostFunction* Create(const StereoRig& rig, const Eigen::Vector3d& landmark, const StereoPixels& pixels,
                                     double pan, const Eigen::Matrix4d& pixel_covariance, PixelResiduals residuals,
                                     const ImageErrorVector& sigmas, const BodyRate& rate);

 private:
  StereoPixelCalibrationModel model_;
};

}  // namespace stereoloc
