#include "factors/stereo_pixel_feature_calibration_factor.h"

#include <ceres/autodiff_cost_function.h>

namespace stereoloc {

ceres::CostFunction* StereoPixelFeatureCalibrationFactor::Create(const StereoRig& rig, const Eigen::Vector3d& landmark,
                                                                 const StereoPixels& pixels, double slide_gain,
                                                                 double pan, const Eigen::Matrix4d& pixel_covariance,
                                                                 PixelResiduals residuals,
                                                                 const ImageErrorVector* image_sigmas,
                                                                 const BodyRate& rate) {
  constexpr const char* kWho = "stereo pixel feature calibration factor";
  stereo_pixel::checkInputs(kWho, pixels, pan, landmark);
  if (!std::isfinite(slide_gain)) throw Error(std::string(kWho) + ": slide gain must be finite");
  auto* functor =
      new StereoPixelFeatureCalibrationFactor(rig, landmark, pixels, slide_gain, pan,
                                              stereo_pixel_calibration::imageBlockSqrtInformation(
                                                  kWho, rig, pixels, pixel_covariance, residuals, image_sigmas, rate),
                                              residuals, image_sigmas, rate);
  constexpr int kQ = StereoPixelCalibrationFactor::kCalibrationSize;
  constexpr int kE = stereo_pixel_calibration::kImageErrorSize;
  constexpr int kB = kOffsetSize;
  using F = StereoPixelFeatureCalibrationFactor;
  if (image_sigmas) {
    if (residuals == PixelResiduals::All) return new ceres::AutoDiffCostFunction<F, 4, 3, kQ, kE, 1, kB>(functor);
    return new ceres::AutoDiffCostFunction<F, 2, 3, kQ, kE, 1, kB>(functor);
  }
  if (residuals == PixelResiduals::All) return new ceres::AutoDiffCostFunction<F, 4, 3, kQ, 1, kB>(functor);
  return new ceres::AutoDiffCostFunction<F, 2, 3, kQ, 1, kB>(functor);
}

}  // namespace stereoloc
