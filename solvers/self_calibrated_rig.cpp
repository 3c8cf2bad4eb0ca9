#include "solvers/self_calibrated_rig.h"

#include <opencv2/calib3d.hpp>

namespace stereoloc {

StereoRig selfCalibratedRig(const StereoRig& given, const CalibrationEstimate& e) {
  if (!e.stereo) return given;
  const double dbeta = e.head[0], k = e.head[1], dd = e.head[2], du = e.head[3], phi = e.head[4],
               psi = e.head[5];
  const StereoRigParams& g = given.params();
  StereoCalibration c = given.calibration()
                            ? *given.calibration()
                            : idealCalibration(g.image_width, g.image_height, given.focal(), given.principalU(),
                                               given.principalV(), g.baseline_mm);
  const double f = c.rectifiedFocal();
  c.K1 = c.K1.clone();
  c.K2 = c.K2.clone();
  // With the image block, the right camera's yaw is folded whole into its rectifying rotation
  // below, so its constant column shift f yaw leaves the right offset.
  const double yaw = e.image ? e.image_errors[9] : 0.0;
  c.K1.at<double>(0, 2) += (du + 0.5 * dd) * c.K1.at<double>(0, 0) / f;
  c.K2.at<double>(0, 2) += (du - 0.5 * dd - f * yaw) * c.K2.at<double>(0, 0) / f;
  // The rows' misalignment dv (right minus left) is a raw right principal-point row error: the
  // given rectification puts a raw row error delta at f delta / fy_raw rectified rows. With the
  // image block, the right camera's pitch goes into R2 below and moves its rows by f pitch (the
  // pitch's (x y, 1 + y^2) pattern, unmodelledPixelCovariance) at the centre; the principal point
  // takes the rest.
  if (e.row) {
    const double pitch = e.image ? e.image_errors[8] : 0.0;
    c.K2.at<double>(1, 2) += (e.row_offset_px - f * pitch) * c.K2.at<double>(1, 1) / f;
  }
  // F = f (1 + psi) for both cameras' columns and rows, the right camera's columns (1 + phi) more.
  c.K1.at<double>(0, 0) *= 1.0 + psi;
  c.K1.at<double>(1, 1) *= 1.0 + psi;
  c.K2.at<double>(0, 0) *= (1.0 + psi) * (1.0 + phi);
  c.K2.at<double>(1, 1) *= 1.0 + psi;
  c.T = c.T * k;
  c.P2 = c.P2.clone();
  c.P2.at<double>(0, 3) *= k;
  if (!c.Q.empty()) {
    c.Q = c.Q.clone();
    c.Q.at<double>(3, 2) /= k;
  }
  if (e.image) {
    // The lens errors into each camera's distortion (true minus given), the right camera's
    // rotation (X_raw = R_rel X, OpenCV axes; the pitch parameter has the sign of its column
    // term, the opposite of the rotation's) into its rectifying rotation R2 R_rel^T and into R,
    // so the rectified rig keeps its focal length and principal point.
    c.D1 = c.D1.clone();
    c.D2 = c.D2.clone();
    for (int j = 0; j < 4; ++j) {
      c.D1.at<double>(j) += e.image_errors[j];
      c.D2.at<double>(j) += e.image_errors[4 + j];
    }
    cv::Mat R_rel;
    cv::Rodrigues(cv::Vec3d(-e.image_errors[8], e.image_errors[9], e.image_errors[10]), R_rel);
    // Products into new matrices: cv::gemm does not take its destination as a source.
    const cv::Mat R2 = c.R2 * R_rel.t(), R = R_rel * c.R;
    c.R2 = R2;
    c.R = R;
  }
  StereoRigParams p = g;
  p.tilt_rad += dbeta;
  // The exposure offset's error is relative to the given rig's offset.
  if (e.image) p.exposure_offset_s += e.image_errors[stereo_pixel_calibration::kExposureOffsetEntry];
  return StereoRig(p, c);
}

}  // namespace stereoloc
