#pragma once
// The odometry's delay against the camera (src/core/odometry_delay.h) estimated from the data
// alone, by the batch smoother: its least-squares cost as a function of the delay, every pose
// and calibration parameter re-estimated at each delay (the profile likelihood of the delay).
// A grid over the search interval finds the least cost; around it the spacing is halved (two
// more solves), and the parabola through the least of the three and its neighbours half a step
// away gives the estimate at its vertex and a standard deviation from its curvature,
// cost ~ (delay - estimate)^2 / (2 sigma^2) + const. That one is a statement about noise; the
// steps' resolution is added to it (OdometryDelayEstimate).
// MR.CLAM's robots: 0.24 s, where the motion capture says 0.25-0.29 s (docs/results.md).
//
// Why a profile rather than a parameter block: the delay moves every step's reading by the
// difference of the wheel speeds at the interval's ends, a parameter of the odometry stream
// rather than of a factor; eighteen batch solves (about 0.3 s each for a 15 minute log) cost
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
  double delay_s = 0.0;          // s, the odometry runs this late
  double sigma_s = 0.0;          // s, the profile's and the resolution's in quadrature
  double profile_sigma_s = 0.0;  // s, from the profile's curvature (the batch's noise model as stated)
  // s, what the steps cannot tell: a reading says how far a wheel went over its step, not when
  // within it, and the re-timing takes the speed as constant over the step; a delay is resolved
  // to about a step, uniformly: the median step interval / sqrt(12). 0 from profileOdometryDelay.
  double resolution_s = 0.0;
  std::vector<std::pair<double, double>> profile;  // (delay s, cost with the prior), by delay
};

// cost_at(delay): the least 1/2 sum |r|^2 of the problem at that delay. Throws stereoloc::Error
// when the least cost lies at the edge of the search, or the profile is not convex around it
// (the data do not determine the delay: a robot driving at constant speeds).
OdometryDelayEstimate profileOdometryDelay(const std::function<double(double)>& cost_at,
                                           const OdometryDelaySearch& search = {});

// The batch smoother's final cost on `steps` with their odometry delayed by delay_s, over the
// same residuals at every delay: the sightings of identified landmarks only (the solve pairs
// the others itself, and which it pairs would change with the delay), one unbroken odometry
// chain (a kidnap cut that the filter pass makes at one delay and not at the next moves the cost
// by hundreds). Throws stereoloc::Error when the batch finds no solution.
double batchCostWithOdometryDelay(const FieldMap& map, const OdometryParams& odometry, const BatchSmootherConfig& config,
                                  const std::vector<Step>& steps, double delay_s);

// profileOdometryDelay of batchCostWithOdometryDelay, with the steps' resolution.
OdometryDelayEstimate estimateOdometryDelay(const FieldMap& map, const OdometryParams& odometry,
                                            const BatchSmootherConfig& config, const std::vector<Step>& steps,
                                            const OdometryDelaySearch& search = {});

}  // namespace stereoloc
