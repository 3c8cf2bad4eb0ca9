#include "factors/stereo_pixel_calibration_factor.h"

#include <ceres/autodiff_cost_function.h>
#include <ceres/jet.h>

#include <Eigen/LU>
#include <cmath>
#include <string>

namespace stereoloc {

ceres::CostFunction* StereoPixelCalibrationFactor::Create(const StereoRig& rig, const Eigen::Vector3d& landmark,
                                                          const StereoPixels& pixels, double pan,
                                                          const Eigen::Matrix4d& pixel_covariance,
                                                          PixelResiduals residuals) {
  constexpr const char* kWho = "stereo pixel calibration factor";
  stereo_pixel::checkInputs(kWho, pixels, pan, landmark);
  auto* functor = new StereoPixelCalibrationFactor(
      rig, landmark, pixels, pan,
      stereo_pixel::sqrtInformation(kWho, pixel_covariance, residuals == PixelResiduals::All), residuals);
  if (residuals == PixelResiduals::All)
    return new ceres::AutoDiffCostFunction<StereoPixelCalibrationFactor, 4, 3, kCalibrationSize>(functor);
  return new ceres::AutoDiffCostFunction<StereoPixelCalibrationFactor, 2, 3, kCalibrationSize>(functor);
}

ceres::CostFunction* StereoPixelCalibrationFactor::Create(const StereoRig& rig, const Eigen::Vector3d& landmark,
                                                          const StereoPixels& pixels, double pan, double sigma,
                                                          PixelResiduals residuals) {
  return Create(rig, landmark, pixels, pan, stereo_pixel::covarianceFromSigma("stereo pixel calibration factor", sigma),
                residuals);
}

namespace stereo_pixel_calibration {

void checkRate(const char* who, const BodyRate& rate) {
  if (!(std::isfinite(rate.forward_mm_s) && std::isfinite(rate.yaw_rad_s)))
    throw Error(std::string(who) + ": body rate must be finite");
}

Eigen::Matrix4d withExposureRateNoise(const Eigen::Matrix4d& C, const StereoRig& rig, const StereoPixels& px,
                                      const ImageErrorVector& sigmas, const BodyRate& rate) {
  const double x = (px.u_right - rig.principalU()) / rig.focal();
  const double g = rig.focal() * (1.0 + x * x) * rate.yaw_sigma_rad_s * sigmas[kExposureOffsetEntry];
  Eigen::Matrix4d out = C;
  out(2, 2) += g * g;
  return out;
}

Eigen::Matrix4d imageBlockSqrtInformation(const char* who, const StereoRig& rig, const StereoPixels& px,
                                          const Eigen::Matrix4d& pixel_covariance, PixelResiduals residuals,
                                          const ImageErrorVector* sigmas, const BodyRate& rate) {
  checkRate(who, rate);
  if (sigmas && !(sigmas->allFinite() && sigmas->minCoeff() >= 0))
    throw Error(std::string(who) + ": image error sigmas must be finite and >= 0");
  return stereo_pixel::sqrtInformation(
      who, sigmas ? withExposureRateNoise(pixel_covariance, rig, px, *sigmas, rate) : pixel_covariance,
      residuals == PixelResiduals::All);
}

ColumnResponse columnResponse(const StereoRig& rig, const StereoPixels& px, const ImageErrorVector* sigmas,
                              const BodyRate& rate) {
  ColumnResponse out;
  const StereoCalibration* cal = rig.calibration().get();
  out.raw = cal && cal->needsRemap();
  out.image = sigmas != nullptr;
  if (out.image) {
    out.exposure_ahead_mm = rate.forward_mm_s * (*sigmas)[kExposureOffsetEntry];
    out.exposure_turn_rad = rate.yaw_rad_s * (*sigmas)[kExposureOffsetEntry];
  }
  if (!out.raw && !out.image) return out;
  const double f = rig.focal(), ou = rig.principalU(), ov = rig.principalV();
  const double u[2] = {px.u_left, px.u_right}, v[2] = {px.v_left, px.v_right};
  for (int c = 0; c < 2; ++c) {
    const double xr = (u[c] - ou) / f, yr = (v[c] - ov) / f;
    // Without a calibration the rectified camera is the raw one: K = (f, o), no distortion.
    Eigen::Matrix3d K = Eigen::Matrix3d::Identity(), R = Eigen::Matrix3d::Identity();
    K(0, 0) = K(1, 1) = f;
    K(0, 2) = ou;
    K(1, 2) = ov;
    double k4[4] = {0, 0, 0, 0}, rest[8] = {0, 0, 0, 0, 0, 0, 0, 0};
    int n = 4;
    if (cal) {
      const cv::Mat& Kc = c == 0 ? cal->K1 : cal->K2;
      const cv::Mat& Rc = c == 0 ? cal->R1 : cal->R2;
      const cv::Mat& Dc = c == 0 ? cal->D1 : cal->D2;
      for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) {
          K(i, j) = Kc.at<double>(i, j);
          R(i, j) = Rc.at<double>(i, j);
        }
      n = static_cast<int>(Dc.total());
      for (int i = 0; i < n && i < 12; ++i) (i < 4 ? k4[i] : rest[i - 4]) = Dc.at<double>(i);
    }
    // x_u = norm(R^T (x_r, y_r, 1)) and its Jacobian d x_u / d (x_r, y_r).
    const Eigen::Vector3d X = R.transpose() * Eigen::Vector3d(xr, yr, 1.0);
    const Eigen::Matrix<double, 3, 2> dX = R.transpose().leftCols<2>();
    Eigen::Matrix2d J_norm;
    for (int j = 0; j < 2; ++j) {
      J_norm(0, j) = (dX(0, j) * X.z() - X.x() * dX(2, j)) / (X.z() * X.z());
      J_norm(1, j) = (dX(1, j) * X.z() - X.y() * dX(2, j)) / (X.z() * X.z());
    }
    // The distortion and its derivatives in (x, y) and (k1, k2, p1, p2).
    using J6 = ceres::Jet<double, 6>;
    const J6 x(X.x() / X.z(), 0), y(X.y() / X.z(), 1);
    const J6 kj[4] = {J6(k4[0], 2), J6(k4[1], 3), J6(k4[2], 4), J6(k4[3], 5)};
    J6 xd, yd;
    distort(x, y, kj, rest, n, &xd, &yd);
    Eigen::Matrix2d J_dist;
    J_dist << xd.v[0], xd.v[1], yd.v[0], yd.v[1];
    const Eigen::Matrix2d K2 = K.topLeftCorner<2, 2>();
    const Eigen::Matrix2d A = (K2 * J_dist * J_norm / f).inverse();  // rectified px per raw px
    if (out.raw) {
      out.offset[c] = A(0, 0) * K(0, 0) / f - 1.0;
      out.focal_u[c] = A(0, 0) * K(0, 0) * xd.a - (u[c] - ou);
      out.focal_v[c] = A(0, 1) * K(1, 1) * yd.a;
    }
    if (out.image) {
      const Eigen::RowVector2d a = A.row(0) * K2;
      for (int j = 0; j < 4; ++j) out.lens[c][j] = (a(0) * xd.v[2 + j] + a(1) * yd.v[2 + j]) * (*sigmas)[4 * c + j];
      if (c == 1) {
        out.rotation[0] = f * xr * yr * (*sigmas)[8];
        // The yaw's column shift f (1 + x^2) less the constant the disparity offset takes, which
        // reaches the right column with the raw gain 1 + offset.
        out.rotation[1] = f * (xr * xr - out.offset[1]) * (*sigmas)[9];
        out.rotation[2] = -f * yr * (*sigmas)[10];
      }
    }
  }
  return out;
}

}  // namespace stereo_pixel_calibration

}  // namespace stereoloc
