#pragma once
// Stripe ends: where a marking's centre line really stops. The segment stage places a line's
// ends where its edge pixels stop, and an edge of the carpet, a robot's shadow or the carpet in
// front of a robot can carry an edge on past the stripe's end (a photograph's stripe ends in
// a blurred, uneven surround; a rendered one in a clean step). Here the centre line of each
// marking is sampled every 1 px; at a sample the stripe is present when the luma on the
// centre line is above the darker of the two sides, 0.5 width + side_px across, by at least
// min_fraction of the stripe's contrast, or above the line's floor level by that much (so a
// crossing or a T-bar, bright on both sides, keeps it). The contrast and floor level are
// medians over the line. An end whose first min_run_px samples lack the stripe moves inward
// to where the stripe has been present on two consecutive samples; a piece at an end shorter
// than the gap behind it (a bright board beyond a robot) is dropped with the gap.
#include <opencv2/core/mat.hpp>
#include <cstdint>
#include <vector>

#include "frontend/features.h"

namespace stereoloc::frontend {

struct StripeEndParams {
  bool enabled = false;        // off: the ends stay where the edge pixels put them
  double side_px = 2.0;        // px outside the stripe's edge where the floor is sampled
  double min_fraction = 0.5;   // of the line's median stripe contrast
  double min_run_px = 3.0;     // px without the stripe at an end before it moves
  double min_contrast = 6.0;   // grey levels: below, the line's stripe cannot be judged
};

// Buffers of trimStripeEnds, kept between calls so that a warmed-up frontend does not allocate.
struct StripeEndScratch {
  std::vector<float> centre, dark, bright, contrast, floor;
  std::vector<uint8_t> present;
};

// Moves the ends of the marking lines of `lines` (see above); other lines are left alone. luma:
// CV_8UC1, the image the lines were found in.
void trimStripeEnds(const cv::Mat& luma, const StripeEndParams& params, std::vector<LineFeature>& lines,
                    StripeEndScratch& scratch);

}  // namespace stereoloc::frontend
