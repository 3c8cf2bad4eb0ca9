#pragma once
// A cost function on (pose, inner calibration blocks...) seen as (pose, g), g one joined global
// block: the batch's chain solver lets a factor touch one global block besides its poses, so the
// stereo, image, row and feature-offset blocks of the self-calibration are one block g
// (solvers/batch_smoother.cpp). Each entry of an inner block sits at its index in g, or is held
// at zero (index -1). Residuals and the pose Jacobian are the inner function's; the Jacobian in
// g scatters the inner blocks' columns to their indices.
#include <ceres/cost_function.h>

#include <algorithm>
#include <memory>
#include <utility>
#include <vector>

#include "src/core/error.h"

namespace stereoloc {

class JoinedGlobalBlocks final : public ceres::CostFunction {
 public:
  // Entry e of inner block k + 1 at indices[k][e] of a joined block of at least `joined_size`;
  // by default the inner blocks follow each other from index 0.
  explicit JoinedGlobalBlocks(ceres::CostFunction* inner, std::vector<std::vector<int>> indices = {},
                              int joined_size = 0)
      : inner_(inner), indices_(std::move(indices)) {
    const std::vector<int32_t>& b = inner_->parameter_block_sizes();
    sizes_.assign(b.begin() + 1, b.end());
    int n = 0;
    if (indices_.empty())
      for (int k : sizes_) {
        indices_.emplace_back();
        for (int e = 0; e < k; ++e) indices_.back().push_back(n++);
      }
    if (indices_.size() != sizes_.size()) throw Error("joined global blocks: one index list per inner block");
    for (size_t k = 0; k < sizes_.size(); ++k) {
      if (indices_[k].size() != static_cast<size_t>(sizes_[k])) throw Error("joined global blocks: one index per entry");
      for (int i : indices_[k]) n = std::max(n, i + 1);
    }
    n = std::max(n, joined_size);
    set_num_residuals(inner_->num_residuals());
    mutable_parameter_block_sizes()->push_back(b[0]);
    mutable_parameter_block_sizes()->push_back(n);
  }
  bool Evaluate(double const* const* p, double* r, double** J) const override {
    std::vector<std::vector<double>> values(sizes_.size());
    std::vector<const double*> blocks{p[0]};
    for (size_t k = 0; k < sizes_.size(); ++k) {
      for (int i : indices_[k]) values[k].push_back(i >= 0 ? p[1][i] : 0.0);
      blocks.push_back(values[k].data());
    }
    if (!J) return inner_->Evaluate(blocks.data(), r, nullptr);
    const int m = num_residuals();
    std::vector<std::vector<double>> parts(sizes_.size());
    std::vector<double*> jac{J[0]};
    for (size_t k = 0; k < sizes_.size(); ++k) {
      if (J[1]) parts[k].resize(static_cast<size_t>(m * sizes_[k]));
      jac.push_back(J[1] ? parts[k].data() : nullptr);
    }
    if (!inner_->Evaluate(blocks.data(), r, jac.data())) return false;
    if (J[1]) {
      const int n = parameter_block_sizes()[1];
      std::fill(J[1], J[1] + m * n, 0.0);
      for (int row = 0; row < m; ++row)
        for (size_t k = 0; k < sizes_.size(); ++k)
          for (int e = 0; e < sizes_[k]; ++e)
            if (indices_[k][static_cast<size_t>(e)] >= 0)
              J[1][row * n + indices_[k][static_cast<size_t>(e)]] += parts[k][static_cast<size_t>(row * sizes_[k] + e)];
    }
    return true;
  }

 private:
  std::unique_ptr<ceres::CostFunction> inner_;
  std::vector<int> sizes_;
  std::vector<std::vector<int>> indices_;
};

}  // namespace stereoloc
