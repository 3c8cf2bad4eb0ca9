#pragma once
// checkFactorJacobians: the one-line check that a cost function's Jacobians agree with central
// differences (src/core/numeric_diff.h) of its own residuals. Used by every factor test:
//   const FactorCheck c = checkFactorJacobians(*cost, {pose_a, pose_b});
//   EXPECT_TRUE(c.ok) << c.message;
// The residuals are differentiated with respect to the ambient parameters; for the poses of
// stereoloc the manifold (factors/pose_manifold.h) has identity Plus/Minus Jacobians, so these
// are the tangent-space Jacobians too. Evaluation failures count as a failed check.
#include <ceres/cost_function.h>

#include <Eigen/Core>
#include <sstream>
#include <string>
#include <vector>

#include "src/core/numeric_diff.h"

namespace stereoloc {

struct FactorCheck {
  bool ok = false;
  double max_relative_error = 0.0;  // relativeJacobianError over all parameter blocks
  std::string message;              // names the block and prints both Jacobians on failure
  explicit operator bool() const { return ok; }
};

inline FactorCheck checkFactorJacobians(const ceres::CostFunction& cost, const std::vector<const double*>& parameters,
                                        double tolerance = 1e-6, double step = 1e-6) {
  using RowMajor = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
  FactorCheck out;
  const std::vector<int32_t>& sizes = cost.parameter_block_sizes();
  const int m = cost.num_residuals();
  if (parameters.size() != sizes.size()) {
    out.message = "checkFactorJacobians: expected " + std::to_string(sizes.size()) + " parameter blocks, got " +
                  std::to_string(parameters.size());
    return out;
  }
  std::vector<std::vector<double>> values(sizes.size());
  std::vector<const double*> ptrs(sizes.size());
  std::vector<RowMajor> analytic(sizes.size());
  std::vector<double*> jac(sizes.size());
  for (size_t b = 0; b < sizes.size(); ++b) {
    values[b].assign(parameters[b], parameters[b] + sizes[b]);
    ptrs[b] = values[b].data();
    analytic[b].resize(m, sizes[b]);
    jac[b] = analytic[b].data();
  }
  Eigen::VectorXd r0(m);
  if (!cost.Evaluate(ptrs.data(), r0.data(), jac.data())) {
    out.message = "checkFactorJacobians: evaluation failed at the given point";
    return out;
  }
  if (!r0.allFinite()) {
    out.message = "checkFactorJacobians: residual not finite";
    return out;
  }
  out.ok = true;
  std::ostringstream msg;
  for (size_t b = 0; b < sizes.size(); ++b) {
    Eigen::MatrixXd numeric(m, sizes[b]);
    bool evaluated = true;
    for (int j = 0; j < sizes[b]; ++j) {
      const double x = values[b][j];
      const double h = step * std::max(1.0, std::fabs(x));
      Eigen::VectorXd rp(m), rm(m);
      values[b][j] = x + h;
      evaluated = evaluated && cost.Evaluate(ptrs.data(), rp.data(), nullptr);
      values[b][j] = x - h;
      evaluated = evaluated && cost.Evaluate(ptrs.data(), rm.data(), nullptr);
      values[b][j] = x;
      numeric.col(j) = (rp - rm) / (2.0 * h);
    }
    const Eigen::MatrixXd a = analytic[b];
    const double err = evaluated && a.allFinite() ? relativeJacobianError(a, numeric) : 1e300;
    out.max_relative_error = std::max(out.max_relative_error, err);
    if (!(err <= tolerance)) {
      out.ok = false;
      msg << "parameter block " << b << ": relative Jacobian error " << err << " > " << tolerance
          << "\nanalytic:\n"
          << a << "\nnumeric:\n"
          << numeric << "\n";
    }
  }
  out.message = out.ok ? "ok" : msg.str();
  return out;
}

}  // namespace stereoloc
