#pragma once
// The stereoloc dataset: a directory with dataset.yaml, odometry.csv, optional compass.csv,
// observations.csv, optional groundtruth.csv, map.yaml, rig.yaml and optional images/.
// The format is documented in docs/dataset_format.md. Units: mm, rad, s.
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "src/core/field_map.h"
#include "src/core/odometry_model.h"
#include "src/core/pose2.h"
#include "src/core/stereo_rig.h"
#include "src/core/types.h"

namespace stereoloc {

constexpr int kDatasetFormatVersion = 1;

struct Dataset {
  std::string name;                 // scenario name or source
  FieldMap map;
  StereoRig rig;                    // rig.params().pixel_sigma is the sigma of pixel observations
  OdometryParams odometry;
  double compass_sigma = 0;         // rad, 0 = no compass
  // Observations in range-bearing form WITH covariance R (from pixels via observationFromPixels
  // with the rig's pixel_sigma, or from the dataset's sigmas). Step 0 is the initial pose; its
  // odometry is normally (0, 0).
  std::vector<Step> steps;
  std::vector<std::optional<Pose2>> groundtruth;  // same length as steps
  std::optional<Pose2> initial_pose;              // true pose at step 0 when known
  bool has_images = false;
  std::string description;          // free text (scenario, trial, seed, noise), in dataset.yaml
};

// Reads and validates a dataset directory. Throws stereoloc::Error "FILE:LINE: reason" (or
// "FILE: key: reason" for YAML) on any malformed input: wrong column count, non-numeric field,
// NaN/inf, steps out of order, unknown landmark id, missing referenced file.
Dataset loadDataset(const std::string& dir);

// Writes a dataset into `dir`: everything goes into a temporary directory beside it, which is
// renamed to `dir` at the end, so an interrupted run leaves no half dataset. Refuses a
// non-empty existing `dir` unless `force` (then the old directory is replaced). `extra`, when
// given, is called with the temporary directory before the rename (e.g. to add images/).
// Same Dataset => byte-identical files.
using DatasetExtraWriter = std::function<void(const std::string& tmp_dir)>;
void saveDataset(const Dataset& d, const std::string& dir, bool force);
void saveDataset(const Dataset& d, const std::string& dir, bool force, const DatasetExtraWriter& extra);

// File names inside a dataset directory.
std::string imageFileName(const std::string& kind, long step);  // "images/left_000012.png" etc.

}  // namespace stereoloc
