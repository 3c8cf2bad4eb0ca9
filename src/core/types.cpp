#include "src/core/types.h"

#include <cmath>
#include <sstream>

#include "src/core/error.h"
#include "src/core/measurement_model.h"

namespace stereoloc {

Observation observationFromPixels(const StereoRig& rig, int landmark_id, LandmarkType type,
                                  const StereoPixels& pixels, double head_pan, const Eigen::Matrix4d& pixel_covariance) {
  Observation o;
  o.landmark_id = landmark_id;
  o.type = type;
  const RangeBearing rb = rig.rangeBearing(pixels, head_pan);  // (5.26)
  o.range = rb.range;
  o.bearing = rb.bearing;
  o.covariance = rangeBearingCovariance(rig, pixels, head_pan, pixel_covariance);  // (5.32)
  o.pixels = pixels;
  o.pixel_covariance = pixel_covariance;
  o.head_pan = head_pan;
  return o;
}

Observation observationFromPixels(const StereoRig& rig, int landmark_id, LandmarkType type,
                                  const StereoPixels& pixels, double head_pan, double pixel_sigma) {
  return observationFromPixels(rig, landmark_id, type, pixels, head_pan, isotropicPixelCovariance(pixel_sigma));
}

Observation observationFromRangeBearing(int landmark_id, LandmarkType type, double range, double bearing,
                                        double sigma_range, double sigma_bearing) {
  if (!(std::isfinite(range) && range > 0)) throw Error("observation: range must be a positive number");
  if (!std::isfinite(bearing)) throw Error("observation: bearing is not finite");
  if (!(std::isfinite(sigma_range) && sigma_range > 0 && std::isfinite(sigma_bearing) && sigma_bearing > 0))
    throw Error("observation: sigmas must be positive numbers");
  Observation o;
  o.landmark_id = landmark_id;
  o.type = type;
  o.range = range;
  o.bearing = wrapAngle(bearing);
  o.covariance << sigma_range * sigma_range, 0.0, 0.0, sigma_bearing * sigma_bearing;
  return o;
}

void validateObservation(const Observation& obs, const std::string& where) {
  if (!std::isfinite(obs.range) || !std::isfinite(obs.bearing)) throw Error(where + ": not finite");
  const Eigen::Matrix2d& R = obs.covariance;
  if (!R.allFinite() || !(R(0, 0) > 0) || !(R(0, 0) * R(1, 1) - R(0, 1) * R(1, 0) > 0) ||
      std::fabs(R(0, 1) - R(1, 0)) > 1e-9 * R.cwiseAbs().maxCoeff())
    throw Error(where + ": covariance R is not symmetric positive definite");
  if (!(obs.single_view_share > 0 && obs.single_view_share <= 1))
    throw Error(where + ": single-view share is not in (0, 1]");
}

bool usableCompassSigma(double sigma_rad) {
  return sigma_rad >= kMinCompassSigmaRad && sigma_rad <= kMaxCompassSigmaRad;  // false for NaN
}

void validateStepOdometryAndCompass(const Step& step, const std::string& where) {
  if (!std::isfinite(step.d_left) || !std::isfinite(step.d_right)) throw Error(where + ": wheel increment is not finite");
  if (std::fabs(step.d_left) > kMaxWheelIncrementMm || std::fabs(step.d_right) > kMaxWheelIncrementMm)
    throw Error(where + ": wheel increment beyond 1 km in one step");
  if (!step.compass) return;
  if (!std::isfinite(*step.compass)) throw Error(where + ": compass is not finite");
  if (!usableCompassSigma(step.compass_sigma)) {
    std::ostringstream sigma;  // %g: a 1e-300 stays 1e-300
    sigma << step.compass_sigma;
    throw Error(where + ": compass_sigma " + sigma.str() + " rad is outside [1e-06, 2 pi]");
  }
}

std::string toString(EstimateStatus status) {
  switch (status) {
    case EstimateStatus::Uninitialised: return "uninitialised";
    case EstimateStatus::Tracking: return "tracking";
    case EstimateStatus::Predicted: return "predicted";
    case EstimateStatus::Lost: return "lost";
    case EstimateStatus::Reinitialised: return "reinitialised";
  }
  return "uninitialised";
}

EstimateStatus estimateStatusFromString(const std::string& name) {
  for (EstimateStatus s : {EstimateStatus::Uninitialised, EstimateStatus::Tracking, EstimateStatus::Predicted,
                           EstimateStatus::Lost, EstimateStatus::Reinitialised})
    if (toString(s) == name) return s;
  throw Error("unknown estimate status '" + name + "'");
}

}  // namespace stereoloc
