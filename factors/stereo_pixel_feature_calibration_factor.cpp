#include "factors/stereo_pixel_feature_calibration_factor.h"

#include "factors/slide_gain_factor_create.h"

namespace stereoloc {

ceres::CostFunction* StereoPixelFeatureCalibrationFactor::Create(const StereoRig& rig, const Eigen::Vector3d& landmark,
                                                                 const StereoPixels& pixels, double slide_gain,
                                                                 double pan, const Eigen::Matrix4d& pixel_covariance,
                                                                 PixelResiduals residuals,
                                                                 const ImageErrorVector* image_sigmas,
                                                                 const BodyRate& rate) {
  return stereo_pixel_calibration::createWithSlideGain<StereoPixelFeatureCalibrationFactor, 1, kOffsetSize>(
      "stereo pixel feature calibration factor", rig, landmark, pixels, slide_gain, pan, pixel_covariance, residuals,
      image_sigmas, rate);
}

}  // namespace stereoloc
