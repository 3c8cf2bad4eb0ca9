#pragma once
// Stripe ends: where a marking's centre line really stops. The segment stage places a line's
// ends where its edge pixels stop; on photographs the stripe can stop before or after them.
//
// Trim (enabled): an edge of the carpet, a robot's shadow or the carpet in front of a robot can
// carry an edge on past the stripe's end (a photograph's stripe ends in a blurred, uneven
// surround; a rendered one in a clean step). The centre line of each marking is sampled every
// 1 px; at a sample the stripe is present when the luma on the centre line is above the
// brighter of the two sides, 0.5 width + side_px across, by at least min_fraction of the
// stripe's contrast, or above the line's floor level by that much (so a crossing or a T-bar,
// bright on both sides, keeps it). The contrast and floor level are medians over the line. An
// end whose first min_run_px samples lack the stripe moves inward to where the stripe has been
// present on two consecutive samples; a piece at an end shorter than the gap behind it (a
// bright board beyond a robot) is dropped with the gap.
//
// Extension (extend_px > 0): the opposite case. A far stripe narrows and fades towards its far
// end, so its edges drop below the gradient threshold or leave the fitting band several px
// before the stripe stops (the far halfway line meeting the far touch line, a goal-area line
// running on to the image border). Each end (after the trim) is followed outwards along the
// centre line, 1 px a step, while the stripe stands out from its sides (centre luma minus the
// mean of the two side samples) by at least min_fraction of that contrast's median over the
// extend_ref_px just inside the end (a local reference: the contrast fades along a far
// stripe); it stops where the stripe has been missing for min_run_px samples, at a crossing or
// bar (bright on both sides), or where a sample leaves the image, and the end goes half a
// sample beyond the last sample with the stripe. That is the rule by which data/real's labels
// place a free end (data/real/README.md). A floor edge carrying on past the stripe has one
// bright and one dark side and the centre between them, so it does not extend an end.
#include <opencv2/core/mat.hpp>
#include <cstdint>
#include <vector>

#include "frontend/features.h"

namespace stereoloc::frontend {

struct StripeEndParams {
  bool enabled = false;        // trim; off: the ends stay where the edge pixels put them
  double side_px = 2.0;        // px outside the stripe's edge where the floor is sampled
  double min_fraction = 0.5;   // of the line's median stripe contrast
  double min_run_px = 3.0;     // px without the stripe at an end before it moves
  double min_contrast = 6.0;   // grey levels: below, the line's stripe cannot be judged
  double extend_px = 0.0;      // px an end may move outwards along the stripe; 0: no extension
  double extend_ref_px = 15.0;  // px inside an end over which its reference contrast is taken
};

// Buffers of trimStripeEnds, kept between calls so that a warmed-up frontend does not allocate.
struct StripeEndScratch {
  std::vector<float> centre, dark, bright, contrast, floor;
  std::vector<uint8_t> present;
  std::vector<uint16_t> bin;  // the medians' bin of each value
  std::vector<float> pick;    // ... and the values in the median's bin
};

// Trims and extends the ends of the marking lines of `lines` (see above); other lines are left
// alone. luma: CV_8UC1, the image the lines were found in.
void trimStripeEnds(const cv::Mat& luma, const StripeEndParams& params, std::vector<LineFeature>& lines,
                    StripeEndScratch& scratch);

}  // namespace stereoloc::frontend
