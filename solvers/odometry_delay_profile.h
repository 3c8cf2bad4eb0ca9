#pragma once
// The odometry's delay against the camera (src/core/odometry_delay.h) estimated from the data
// alone, by the batch smoother: its least-squares cost as a function of the delay, every pose
// and calibration parameter re-estimated at each delay (the profile likelihood of the delay).
// A grid over the search interval finds the least cost; a parabola through the points around it
// (the grid's neighbours and two at half the spacing) gives the estimate at its vertex and the
// standard deviation from its curvature, cost ~ (delay - estimate)^2 / (2 sigma^2) + const.
// MR.CLAM's robots: 0.24 s, where the motion capture says 0.25-0.29 s (docs/results.md).
//
// Why a profile rather than a parameter block: the delay moves every step's reading by the
// difference of the wheel speeds at the interval's ends, a parameter of the odometry stream
// rather than of a factor; a dozen batch solves (about 0.2 s each for a 15 minute log) cost
// less than re-timing the stream inside every odometry factor and its Jacobians.
#include <functional>
#include <utility>
#include <vector>

#include "solvers/batch_smoother.h"
#include "src/core/field_map.h"
#include "src/core/odometry_model.h"
#include "src/core/types.h"

namespace stereoloc {

struct OdometryDelaySearch {
  double min_s = -0.5, max_s = 1.0;  // s, the delays searched
  double step_s = 0.1;               // s, the grid's spacing (refined to half of it at the least)
  double prior_sigma_s = 0.5;        // s, a zero-mean prior on the delay, added to the cost; 0: none
  void validate() const;             // throws stereoloc::Error naming the field
};

struct OdometryDelayEstimate {
  double delay_s = 0.0;  // s, the odometry runs this late
  double sigma_s = 0.0;  // s, from the profile's curvature (the batch's noise model taken as stated)
  std::vector<std::pair<double, double>> profile;  // (delay s, cost with the prior), by delay
};

// cost_at(delay): the least 1/2 sum |r|^2 of the problem at that delay. Throws stereoloc::Error
// when the least cost lies at the edge of the search, or the profile is not convex around it
// (the data do not determine the delay: a robot driving at constant speeds).
OdometryDelayEstimate profileOdometryDelay(const std::function<double(double)>& cost_at,
                                           const OdometryDelaySearch& search = {});

// The batch smoother's final cost on `steps` with their odometry delayed by delay_s.
double batchCostWithOdometryDelay(const FieldMap& map, const OdometryParams& odometry, const BatchSmootherConfig& config,
                                  const std::vector<Step>& steps, double delay_s);

}  // namespace stereoloc
