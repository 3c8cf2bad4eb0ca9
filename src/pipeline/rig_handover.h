#pragma once
// A run on a rig of its user's choosing (`localize --rig`, `refine --rig`, `stream --rig`), such
// as the one an earlier run's self-calibration wrote (`--calibration-out`): the rig replaces the
// dataset's, and the calibration the file hands over (CalibrationHandover,
// solvers/self_calibration.h) goes with it: the wheel estimate onto the odometry, its standard
// deviations as the priors of a further self-calibration (CalibrationHandover::applyPriors).
// Likewise a map (`localize --map`, `refine --map`), such as the field an earlier run measured
// (`--field-out`).
#include <string>

#include "solvers/self_calibration.h"
#include "src/io/dataset.h"

namespace stereoloc {

// Replaces `dataset`'s rig by the rig at `rig_path` and applies the wheel estimate the file hands
// over (applyWheelCalibration); returns the handover. With `images_measured_again` the caller
// runs the frontend on the dataset's images with the new rig afterwards. Otherwise the dataset's
// pixel observations, rectified with its own rig, are kept: they stay valid only where both
// rigs have the same rectified cameras (image size, focal length, principal point, baseline), and
// are then triangulated again with the new rig's mounting; a rig whose rectified cameras differ
// throws Error naming the file. Errors of the file itself name the file and the key.
CalibrationHandover useRig(Dataset& dataset, const std::string& rig_path, bool images_measured_again);

// Replaces `dataset`'s map by the map at `map_path`. Every landmark the dataset's observations
// name must be in it with the same type (the positions may differ: that is the point); throws
// Error naming the file, the landmark and a step that sees it otherwise. With
// `images_measured_again` the caller runs the frontend on the dataset's images with the new map
// afterwards, so the stored observations, to be replaced, are not checked.
void useMap(Dataset& dataset, const std::string& map_path, bool images_measured_again);

// For a rig whose right camera exposes apart from the left (StereoRigParams::exposure_offset_s,
// src/core/exposure_offset.h): every pixel observation of `dataset` moved to the left camera's
// instant with its step's body rate (BodyRateTracker on the dataset's odometry, whose stated
// wheel noise gives the rate's) and triangulated again. Nothing changes for a rig
// without an offset. Call it once, after the observations are final (useRig, the frontend);
// throws Error naming the step and observation where one cannot be triangulated.
void synchroniseExposures(Dataset& dataset);

}  // namespace stereoloc
