#pragma once
// The rig a stereo self-calibration implies (solvers/self_calibration.h): the given rig with the
// estimated corrections folded into the camera calibration, so that the frontend, rectifying raw
// pairs with it, measures pixels the given rig's projection explains.
//
// The estimate q = (dbeta, k, delta_d, delta_u, phi, psi) says that the given rectification puts a
// landmark at columns u_l = o_u + delta_u + delta_d / 2 - F (y - k b/2) / x and
// u_r = o_u + delta_u - delta_d / 2 - F (1 + phi) (y + k b/2) / x, with F = f (1 + psi), of a
// rig tilted by beta + dbeta (factors/stereo_pixel_calibration_factor.h). Folded in:
//   tilt       beta + dbeta (robot mounting);
//   baseline   T, P2(0,3) and Q scaled by k (the rectified rig's baseline is k b);
//   columns    the RAW principal points move by (delta_u +- delta_d / 2) f_raw / f, and the right
//              camera's raw focal length (x) scales by 1 + phi and both cameras' (x and y) by
//              1 + psi: a raw column error of the camera is what the rectified offset is (a
//              principal-point error), and the rectification (R1, R2, P1, P2) stays the
//              given one, so the rectified rig keeps its focal length and principal point.
//              Lens distortion and the rectifying rotation make the correction exact only
//              near the image centre (their local scale at the image edge differs by up to
//              ~15 % for k1 = -0.2).
//   rows       with the row block (CalibrationEstimate::row), the right raw principal point's row
//              moves by dv fy_raw / f, so the rectified rows of the pair align;
//   image      with the image block (CalibrationEstimate::image): each camera's lens error added
//              to its distortion, the right camera's rotation into its rectifying rotation R2
//              (and R), its yaw's constant column shift taken from the right raw principal
//              point (the block's yaw is the rotation less the shift the disparity offset holds).
// A rig without an OpenCV calibration gets the ideal one of its pinhole parameters first.
#include "solvers/self_calibration.h"
#include "src/core/stereo_rig.h"

namespace stereoloc {

// Returns `given` unchanged when the estimate has no stereo part.
StereoRig selfCalibratedRig(const StereoRig& given, const CalibrationEstimate& estimate);

}  // namespace stereoloc
