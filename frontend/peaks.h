#pragma once
// Stage 3: peak detection in the Hough accumulator (Algorithm 1). Instead of n full scans for
// the maximum, one scan collects the local maxima (3x3, theta wrapping) above the threshold,
// sorts them by votes and then applies Algorithm 1's rule in that order: a peak is kept unless
// a stronger kept peak lies within the rectangular window of +-window_theta_bins x
// +-window_rho_bins cells. The result equals Algorithm 1 with that window, at the cost of one
// scan. The window is small on purpose: duplicate peaks of one line are also rejected later,
// because verification (Algorithm 2) removes the pixels a line has used.
#include <vector>

#include "frontend/gbht.h"

namespace stereoloc::frontend {

struct PeakParams {
  int min_votes = 18;         // threshold of Algorithm 1
  int max_peaks = 60;         // n of Algorithm 1
  int window_theta_bins = 2;  // suppression window half-size in theta bins
  int window_rho_bins = 1;    // ... and in rho bins
};

struct HoughPeak {
  int theta_bin = 0, rho_bin = 0, votes = 0;
  double theta = 0, rho = 0;  // line of the cell centre (features.h convention)
};

// Fills `peaks` (cleared first), strongest first.
void detectPeaks(const HoughAccumulator& acc, const PeakParams& params, std::vector<HoughPeak>& peaks);

}  // namespace stereoloc::frontend
