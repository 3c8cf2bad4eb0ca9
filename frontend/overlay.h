#pragma once
// A picture of what the frontend found, for a person to check at a glance (`stereoloc detect
// --overlay`, like thesis Fig. 6.1): the input enlarged `scale` times, marking centre lines in
// red, other edges in green, raw marking edges thin orange; L corners as red squares, T
// junctions as blue triangles, X intersections as magenta crosses, goal corners as yellow
// diamonds; a legend in the top-left corner.
#include <opencv2/core/mat.hpp>

#include "frontend/frontend.h"

namespace stereoloc::frontend {

// bgr: the CV_8UC3 image the result was computed from; scale >= 1.
cv::Mat drawDetections(const cv::Mat& bgr, const FrontendResult& result, int scale = 2);

}  // namespace stereoloc::frontend
