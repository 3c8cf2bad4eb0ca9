#pragma once
// A cost function whose last parameter block holds only some entries of the inner function's
// last block, the others held at zero: the sliding window gives a feature only the offsets the
// noise model states (a goal corner's column offset b_c, not its u_r offset b_d), and an entry
// without a prior or data would leave a direction of zero information in the window's normal
// equations. Residuals and the other blocks' Jacobians are the inner function's; the last
// block's Jacobian is its columns of the kept entries.
#include <ceres/cost_function.h>

#include <memory>
#include <utility>
#include <vector>

#include "src/core/error.h"

namespace stereoloc {

class HeldEntries final : public ceres::CostFunction {
 public:
  // Takes ownership of `inner`; `entries`: the kept entries' indices in its last block, increasing.
  HeldEntries(ceres::CostFunction* inner, std::vector<int> entries) : inner_(inner), entries_(std::move(entries)) {
    const std::vector<int32_t>& b = inner_->parameter_block_sizes();
    if (b.empty()) throw Error("held entries: the inner function has no parameter block");
    full_ = b.back();
    for (size_t e = 0; e < entries_.size(); ++e)
      if (entries_[e] < 0 || entries_[e] >= full_ || (e > 0 && entries_[e] <= entries_[e - 1]))
        throw Error("held entries: entry indices must increase within the last block");
    if (entries_.empty()) throw Error("held entries: no entry kept");
    set_num_residuals(inner_->num_residuals());
    *mutable_parameter_block_sizes() = b;
    mutable_parameter_block_sizes()->back() = static_cast<int32_t>(entries_.size());
  }
  bool Evaluate(double const* const* p, double* r, double** J) const override {
    const size_t nb = parameter_block_sizes().size();
    const size_t n = entries_.size();
    std::vector<double> full(static_cast<size_t>(full_), 0.0);
    for (size_t e = 0; e < n; ++e) full[static_cast<size_t>(entries_[e])] = p[nb - 1][e];
    std::vector<const double*> blocks(p, p + nb);
    blocks.back() = full.data();
    if (!J || !J[nb - 1]) return inner_->Evaluate(blocks.data(), r, J);
    const int m = num_residuals();
    std::vector<double> J_full(static_cast<size_t>(m * full_));
    std::vector<double*> jac(J, J + nb);
    jac.back() = J_full.data();
    if (!inner_->Evaluate(blocks.data(), r, jac.data())) return false;
    for (int row = 0; row < m; ++row)
      for (size_t e = 0; e < n; ++e)
        J[nb - 1][static_cast<size_t>(row) * n + e] = J_full[static_cast<size_t>(row * full_ + entries_[e])];
    return true;
  }

 private:
  std::unique_ptr<ceres::CostFunction> inner_;
  std::vector<int> entries_;
  int full_ = 0;
};

}  // namespace stereoloc
