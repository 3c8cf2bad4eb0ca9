#pragma once
// Finding a stereo calibration's checkerboard pairs on disk (`stereoloc calibrate`):
//
//   a folder   left<key> and right<key> images paired by <key>, one '_' or '-' after the prefix
//              ignored: left_01.png + right_01.png, or left01.jpg + right01.jpg as OpenCV's
//              samples name them; files that are not images (by extension) are passed over,
//              an image without its partner is an error
//   a list     an OpenCV image list (the cv::FileStorage file, XML, YAML or JSON, that OpenCV's
//              samples/cpp/stereo_calib.cpp reads): a sequence of file names, left and right
//              alternating, relative to the list's folder; its node `imagelist`, or the first
//              sequence when there is none of that name
//
// Images are read as 8-bit grey; sizes are checked by calibrateStereoFromTargets.
#include <string>
#include <vector>

#include "src/calib/stereo_target_calibration.h"

namespace stereoloc {

// Pairs in the folder's key order or the list's order, each named by its left image's path.
// Throws Error naming the file (and the list's entry) for a missing partner, an unreadable
// image, a list that cannot be parsed, has no sequence of names, or an odd number of them.
std::vector<TargetPair> readTargetPairs(const std::string& folder_or_list);

}  // namespace stereoloc
