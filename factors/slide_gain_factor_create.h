#pragma once
// For the factors' source files: Create of a stereo pixel calibration functor F that takes the
// sighting's slide gain (the row and feature calibration factors). F is built from (rig,
// landmark, pixels, slide gain, pan, S, residuals, image sigmas, rate); the blocks are pose (3),
// stereo calibration q (6), the whitened image errors e (12) when `image_sigmas` is set, then
// the functor's own blocks `Extra...`. Checks and whitening as imageBlockSqrtInformation.
#include <ceres/autodiff_cost_function.h>

#include <Eigen/Core>
#include <cmath>
#include <string>

#include "factors/stereo_pixel_calibration_factor.h"
#include "src/core/error.h"

namespace stereoloc::stereo_pixel_calibration {

template <typename F, int... Extra>
ceres::CostFunction* createWithSlideGain(const char* who, const StereoRig& rig, const Eigen::Vector3d& landmark,
                                         const StereoPixels& pixels, double slide_gain, double pan,
                                         const Eigen::Matrix4d& pixel_covariance, PixelResiduals residuals,
                                         const ImageErrorVector* image_sigmas, const BodyRate& rate) {
  stereo_pixel::checkInputs(who, pixels, pan, landmark);
  if (!std::isfinite(slide_gain)) throw Error(std::string(who) + ": slide gain must be finite");
  auto* functor = new F(rig, landmark, pixels, slide_gain, pan,
                        imageBlockSqrtInformation(who, rig, pixels, pixel_covariance, residuals, image_sigmas, rate),
                        residuals, image_sigmas, rate);
  constexpr int kQ = StereoPixelCalibrationFactor::kCalibrationSize;
  constexpr int kE = kImageErrorSize;
  if (image_sigmas) {
    if (residuals == PixelResiduals::All) return new ceres::AutoDiffCostFunction<F, 4, 3, kQ, kE, Extra...>(functor);
    return new ceres::AutoDiffCostFunction<F, 2, 3, kQ, kE, Extra...>(functor);
  }
  if (residuals == PixelResiduals::All) return new ceres::AutoDiffCostFunction<F, 4, 3, kQ, Extra...>(functor);
  return new ceres::AutoDiffCostFunction<F, 2, 3, kQ, Extra...>(functor);
}

}  // namespace stereoloc::stereo_pixel_calibration
