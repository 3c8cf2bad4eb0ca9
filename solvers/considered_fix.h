#pragma once
// A global fix that is honest about the stereo calibration it was computed with. A fix's
// covariance holds its sightings' noise, but on a real rig the given calibration is itself off
// (baseline, disparity offset, tilt, ...), and that error is common to every sighting of the
// step: it moves the whole fix, which no per-sighting covariance can say. Considered here, not
// estimated: the fix stays where the given calibration puts it; its covariance gains the mean
// squared change of the fix over the calibration's uncertainty, by the Gauss-Hermite rule of
// degree 5 along each principal axis s_j of the calibration's covariance,
//   sum_j 1/6 (f(q0 + sqrt(3) s_j) - f(q0)) (...)^T + 1/6 (f(q0 - sqrt(3) s_j) - f(q0)) (...)^T,
// q the stereo block of the rig that measured the pixels (CalibrationEstimate::head, nominal q0
// = (0, 1, 0, 0, 0, 0)), s_j the principal axes of its covariance Cq (sqrt(lambda_j) v_j; the
// self-calibration's priors), and f(q) the same fix computed again with the step's stereo
// sightings seen through q (calibratedRangeBearing), heading differences wrapped. To first
// order it is J_pose_q Cq J_pose_q^T; the rule also keeps what a linearisation drops: a stereo
// range is r = f b / d, so a disparity offset of 1 px at d = 14 px moves it by -7 % or +8 %, and
// 3 px by -18 % or +27 % (on 400 simulated rigs, fix2's mean NEES 18.9 with its own covariance,
// 5.6 with J Cq J^T by central differences, 3.1 with this). The methods "fix1:consider" and
// "fix2:consider"; measured in docs/estimators.md, "Global fixes".
#include "solvers/global_fix.h"
#include "solvers/self_calibration.h"
#include "src/core/field_map.h"
#include "src/core/stereo_rig.h"
#include "src/core/types.h"

namespace stereoloc {

// `fix` (globalFix(step, map, options)) with the covariance of stereo calibration `Cq` (6x6,
// CalibrationEstimate::head's order and units) considered. Sightings without pixels, and
// unidentified ones, are left as they are. Where the fix at q0 +- sqrt(3) s_j changes its
// landmarks or fails (circles that no longer meet), q0 +- s_j / 10 is taken, linearised; a fix
// that does not survive that comes back Degenerate: within its calibration's uncertainty it is
// not one fix.
// Returns `fix` unchanged when it has no pose or Cq is zero. Throws stereoloc::Error when Cq is
// not finite or its diagonal negative.
GlobalFix considerStereoCalibration(const GlobalFix& fix, const Step& step, const FieldMap& map,
                                    const GlobalFixOptions& options, const StereoRig& rig,
                                    const CalibrationEstimate::StereoMatrix& Cq);

}  // namespace stereoloc
