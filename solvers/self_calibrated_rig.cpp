#include "solvers/self_calibrated_rig.h"

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
  c.K1.at<double>(0, 2) += (du + 0.5 * dd) * c.K1.at<double>(0, 0) / f;
  c.K2.at<double>(0, 2) += (du - 0.5 * dd) * c.K2.at<double>(0, 0) / f;
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
  StereoRigParams p = g;
  p.tilt_rad += dbeta;
  return StereoRig(p, c);
}

}  // namespace stereoloc
