#pragma once
// Stage 2: the Gradient-Based Hough Transform (thesis 3.3.1). Each edge pixel votes only for
// the directed line orientations within +-tolerance of its own gradient direction; see
// frontend/features.h for the (directed) line convention. The accumulator covers
// theta in [0, 2 pi) in steps of theta_step and rho measured from the image centre in steps
// of rho_step, so a 320x240 image needs 360 x 135 cells at the thesis's 1 deg / 3 px (6.1).
#include <cstdint>
#include <vector>

#include "frontend/features.h"

namespace stereoloc::frontend {

struct HoughParams {
  double theta_step_deg = 1.0;   // delta theta (6.1); must divide 360
  double rho_step_px = 3.0;      // delta rho (6.1)
  double tolerance_deg = 5.0;    // +- around the gradient direction (6.1)
  bool weight_by_magnitude = false;  // vote min(4, 1 + mag / 256) instead of 1
};

class HoughAccumulator {
 public:
  // Sizes the accumulator for a width x height image; reuses memory when the size is unchanged.
  void configure(int width, int height, const HoughParams& params);
  // Clears and fills the accumulator from the edge pixels whose `used` flag is 0 (all when empty).
  void vote(const std::vector<EdgePixel>& edges, const std::vector<uint8_t>& used);

  int numTheta() const { return n_theta_; }
  int numRho() const { return n_rho_; }
  int at(int theta_bin, int rho_bin) const { return acc_[static_cast<size_t>(theta_bin) * n_rho_ + rho_bin]; }
  const std::vector<uint16_t>& cells() const { return acc_; }
  // Cell centre -> line in the convention of features.h (origin at pixel (0, 0)).
  double theta(int theta_bin) const;
  double rho(int theta_bin, int rho_bin) const;
  const HoughParams& params() const { return params_; }

 private:
  HoughParams params_;
  int w_ = 0, h_ = 0, n_theta_ = 0, n_rho_ = 0, rho0_ = 0, tol_bins_ = 0;
  double cx_ = 0, cy_ = 0;
  std::vector<float> cos_, sin_;
  std::vector<float> ext_cos_, ext_sin_;  // cos_, sin_ over the unwrapped bins -tol .. n_theta + tol
  std::vector<size_t> ext_row_;            // their accumulator row offsets
  std::vector<uint16_t> acc_;  // a cell cannot exceed 4 x 1200 votes in 320x240
};

}  // namespace stereoloc::frontend
