#pragma once
// The validation gate and lost-tracking policy of thesis section 5.1.3, shared by every tracker
// (EKF, particle filter, sliding window) so that they declare "lost" under the same rule.
#include <Eigen/Core>

#include "src/core/gaussian.h"

namespace stereoloc {

struct GateConfig {
  double probability = 0.99;  // chi-square probability of the gate (5.20), 2 dof
  int lost_after = 3;         // this many consecutive gated observations declare the robot lost
};

// (5.20): accept an innovation nu with covariance S when nu^T S^-1 nu <= chi2_{dof}(probability).
class ValidationGate {
 public:
  explicit ValidationGate(const GateConfig& config = GateConfig(), int dof = 2)
      : config_(config), threshold_(chi2Quantile(config.probability, dof)) {}

  double threshold() const { return threshold_; }
  const GateConfig& config() const { return config_; }
  bool accepts(double mahalanobis_squared) const { return mahalanobis_squared <= threshold_; }

  // Records the outcome of one gate test; returns true when the run of consecutive rejections
  // has reached lost_after (the caller then re-initialises from a global fix and calls reset()).
  bool record(bool accepted) {
    consecutive_rejections_ = accepted ? 0 : consecutive_rejections_ + 1;
    return consecutive_rejections_ >= config_.lost_after;
  }
  int consecutiveRejections() const { return consecutive_rejections_; }
  void reset() { consecutive_rejections_ = 0; }

 private:
  GateConfig config_;
  double threshold_;
  int consecutive_rejections_ = 0;
};

}  // namespace stereoloc
