#pragma once
// Observation errors that repeat over consecutive sightings, and the sigmas that make a stream of
// such sightings carry, fused as if independent, the information it holds.
//
// A real sensor reading the same landmark from nearly the same place errs nearly the same way
// (MR.CLAM's barcode camera: consecutive ranges of one landmark correlate at 0.7-0.9, docs/
// results.md). Every estimator here treats sightings as independent, so a burst of n sightings
// counts as n where it holds the information of a few: the pose covariance comes out too narrow
// and the burst outweighs a fresh landmark. The model: the correlation of two errors dt apart
//   rho(dt) = at_zero * exp(-dt / time_constant_s),
// one for sightings of the same landmark, one for sightings of different landmarks (a common
// error, e.g. of the camera's heading). For a Markov (exponentially correlated) sequence the
// information about a constant is (1/sigma^2) [1 + sum_k (1 - rho_k) / (1 + rho_k)], rho_k the
// correlation with the previous sample; so multiplying each sighting's variance by
// (1 + rho_k) / (1 - rho_k) gives independent fusion exactly that information
// (docs/estimators.md, "Errors that repeat over sightings").
#include <cstddef>
#include <vector>

#include "src/core/types.h"

namespace stereoloc {

struct ErrorCorrelation {
  double at_zero = 0.0;          // correlation just after a sighting, in [0, 1]
  double time_constant_s = 1.0;  // s, > 0
  double at(double dt_s) const;  // rho(dt); 0 for a negative or infinite dt
};

// The largest correlation a sighting is inflated for: the variance factor (1 + rho)/(1 - rho)
// is 39 there (two sightings closer than that are not worth less than 1/39 of one).
constexpr double kMaxErrorCorrelation = 0.95;

// (1 + rho) / (1 - rho) for rho in [0, 1], rho capped at kMaxErrorCorrelation; throws
// stereoloc::Error outside [0, 1].
double correlationVarianceFactor(double rho);

// One error of one sighting: its time, what it saw (landmark id) and the error (any unit).
struct ErrorSample {
  double t_s = 0.0;
  int key = 0;
  double error = 0.0;
};

struct ErrorCorrelationFit {
  ErrorCorrelation correlation;
  size_t pairs = 0;    // pairs of samples the fit used
  double rms = 0.0;    // of the inlier errors about their median (the normalisation)
};

// Fits rho(dt) over every pair of samples at most max_lag_s apart, of the same key (same_key)
// or of different keys. The errors are centred on their median; samples farther from it than
// 5 robust sigmas (1.4826 MAD) are left out; a pair's product is normalised by the inliers' mean
// square. Least squares of the products against rho(dt): the pairs binned by lag, tau on a
// log grid from 0.05 s to max_lag_s, at_zero in closed form per tau, clamped to [0, 1]. Fewer than 10 pairs, or a zero spread: no correlation (at_zero 0).
// Throws stereoloc::Error for a non-finite sample or a max_lag_s that is not positive.
ErrorCorrelationFit fitErrorCorrelation(std::vector<ErrorSample> samples, bool same_key, double max_lag_s);

struct ObservationCorrelation {
  ErrorCorrelation range_same, range_other;      // of the range error
  ErrorCorrelation bearing_same, bearing_other;  // of the bearing error
};

// Multiplies each observation's covariance row/column of range by the square root of the range
// factor and of bearing by that of the bearing factor (so R's correlation coefficient is kept),
// the factor of rho = max(rho_same(dt since this landmark's previous sighting), rho_other(dt
// since the previous sighting of another landmark)). Steps in time order; within a step the
// observations are taken in order (two landmarks seen at once are dt = 0 apart). The first
// sighting of the stream keeps its covariance. Throws stereoloc::Error for steps out of time
// order or an observation without a landmark id.
void inflateForCorrelatedErrors(std::vector<Step>& steps, const ObservationCorrelation& correlation);

}  // namespace stereoloc
