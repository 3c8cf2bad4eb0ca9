#include "factors/stereo_pixel_image_calibration_factor.h"

#include <ceres/autodiff_cost_function.h>

namespace stereoloc {

ceres::CostFunction* StereoPixelImageCalibrationFactor::Create(const StereoRig& rig, const Eigen::Vector3d& landmark,
                                                               const StereoPixels& pixels, double pan,
                                                               const Eigen::Matrix4d& pixel_covariance,
                                                               PixelResiduals residuals, const ImageErrorVector& sigmas,
                                                               const BodyRate& rate) {
  constexpr const char* kWho = "stereo pixel image calibration factor";
  stereo_pixel::checkInputs(kWho, pixels, pan, landmark);
  auto* functor =
      new StereoPixelImageCalibrationFactor(rig, landmark, pixels, pan,
                                            stereo_pixel_calibration::imageBlockSqrtInformation(
                                                kWho, rig, pixels, pixel_covariance, residuals, &sigmas, rate),
                                            residuals, sigmas, rate);
  constexpr int kQ = StereoPixelCalibrationFactor::kCalibrationSize;
  if (residuals == PixelResiduals::All)
    return new ceres::AutoDiffCostFunction<StereoPixelImageCalibrationFactor, 4, 3, kQ, kImageErrorSize>(functor);
  return new ceres::AutoDiffCostFunction<StereoPixelImageCalibrationFactor, 2, 3, kQ, kImageErrorSize>(functor);
}

}  // namespace stereoloc
