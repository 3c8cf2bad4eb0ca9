#include "frontend/gbht.h"

#include <algorithm>
#include <cmath>

#include "src/core/error.h"

namespace stereoloc::frontend {

void HoughAccumulator::configure(int width, int height, const HoughParams& params) {
  const double n = 360.0 / params.theta_step_deg;
  if (!(params.theta_step_deg > 0) || std::fabs(n - std::round(n)) > 1e-6)
    throw Error("hough.theta_step_deg: must be positive and divide 360");
  if (!(params.rho_step_px > 0)) throw Error("hough.rho_step_px: must be positive");
  if (!(params.tolerance_deg >= 0)) throw Error("hough.tolerance_deg: must not be negative");
  params_ = params;
  w_ = width;
  h_ = height;
  n_theta_ = static_cast<int>(std::lround(n));
  cx_ = 0.5 * (width - 1);
  cy_ = 0.5 * (height - 1);
  const double rho_max = std::hypot(cx_, cy_) + 1.0;
  rho0_ = static_cast<int>(std::ceil(rho_max / params.rho_step_px));
  n_rho_ = 2 * rho0_ + 1;
  tol_bins_ = static_cast<int>(std::lround(params.tolerance_deg / params.theta_step_deg));
  cos_.resize(n_theta_);
  sin_.resize(n_theta_);
  const double step = kTwoPi / n_theta_;
  for (int i = 0; i < n_theta_; ++i) {
    // Pre-divided by rho_step so a vote is one multiply-add per coordinate.
    cos_[i] = static_cast<float>(std::cos(i * step) / params.rho_step_px);
    sin_[i] = static_cast<float>(std::sin(i * step) / params.rho_step_px);
  }
  acc_.assign(static_cast<size_t>(n_theta_) * n_rho_, 0);
  // The votes of a pixel of direction bin b go to bins b - tol .. b + tol, wrapped: the same
  // per-bin values laid out once more over the unwrapped range [-tol, n_theta + tol] (b can
  // be n_theta for an angle just below 2 pi), so the voting loop needs no wrap test.
  const int n_ext = n_theta_ + 1 + 2 * tol_bins_;
  ext_cos_.resize(n_ext);
  ext_sin_.resize(n_ext);
  ext_row_.resize(n_ext);
  for (int j = 0; j < n_ext; ++j) {
    const int t = ((j - tol_bins_) % n_theta_ + n_theta_) % n_theta_;
    ext_cos_[j] = cos_[t];
    ext_sin_[j] = sin_[t];
    ext_row_[j] = static_cast<size_t>(t) * n_rho_;
  }
}

void HoughAccumulator::vote(const std::vector<EdgePixel>& edges, const std::vector<uint8_t>& used) {
  std::fill(acc_.begin(), acc_.end(), 0);
  const float bin_per_rad = static_cast<float>(n_theta_ / kTwoPi);
  const float r0 = static_cast<float>(rho0_) + 0.5f;
  for (size_t i = 0; i < edges.size(); ++i) {
    if (!used.empty() && used[i]) continue;
    const EdgePixel& e = edges[i];
    const float x = e.x - static_cast<float>(cx_), y = e.y - static_cast<float>(cy_);
    const uint16_t wgt = static_cast<uint16_t>(params_.weight_by_magnitude ? std::min(4, 1 + static_cast<int>(e.mag) / 256) : 1);
    const int b = std::min(static_cast<int>(e.angle * bin_per_rad + 0.5f), n_theta_);
    // Unwrapped index j = k + tol of bins k = b - tol .. b + tol (see configure()).
    for (int j = b; j <= b + 2 * tol_bins_; ++j) {
      const int r = static_cast<int>(x * ext_cos_[j] + y * ext_sin_[j] + r0);  // r0 > |rho|/step: positive
      uint16_t& cell = acc_[ext_row_[j] + r];
      cell = static_cast<uint16_t>(cell + wgt);
    }
  }
}

double HoughAccumulator::theta(int theta_bin) const { return theta_bin * kTwoPi / n_theta_; }

double HoughAccumulator::rho(int theta_bin, int rho_bin) const {
  const double t = theta(theta_bin);
  return (rho_bin - rho0_) * params_.rho_step_px + cx_ * std::cos(t) + cy_ * std::sin(t);
}

}  // namespace stereoloc::frontend
