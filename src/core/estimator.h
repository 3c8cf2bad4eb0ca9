#pragma once
// The one interface of every tracker (EKF, particle filter, sliding window, batch): feed Steps
// in order, read the current Estimate after each; finish() returns the final trajectory
// (smoothed, for the smoothers; the per-step estimates, for the filters).
#include <string>
#include <vector>

#include "src/core/types.h"

namespace stereoloc {

class Estimator {
 public:
  virtual ~Estimator() = default;
  virtual std::string name() const = 0;
  // Processes one step; steps must arrive with strictly increasing step numbers.
  virtual Estimate process(const Step& step) = 0;
  virtual std::vector<Estimate> finish() = 0;
};

}  // namespace stereoloc
