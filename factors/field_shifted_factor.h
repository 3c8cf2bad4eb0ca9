#pragma once
// A sighting factor whose landmark stands where the field's true dimensions put it: the
// smoothers' field self-calibration (`--calibrate stereo,field`, solvers/self_calibration.h).
//
//   r(x, b_1..b_k, f) = r_inner(x - [J_l f; 0], b_1..b_k)
//
// x = (x, y, theta) the robot pose in the world frame (mm, mm, rad); b_1..b_k the inner factor's
// calibration blocks, passed through; f the change of the nine field dimensions (mm,
// kFieldDimensions of src/core/field_map.h), one more block after them; J_l = d(landmark x, y)/d f
// (FieldMap::fieldJacobians).
// Why a shifted pose: every sighting model here sees the landmark only through its position
// relative to the robot in the world frame, l - p, so moving the landmark by J_l f is moving
// the robot by -J_l f: the inner factor is used as it is, whatever its calibration blocks.
// Jacobians: J_r_x = J_inner_x (the shift does not depend on x; the pose manifold's Plus is the
// identity on (x, y)), J_r_b = J_inner_b, J_r_f = -J_inner_x[:, 0:2] J_l.
#include <ceres/cost_function.h>

#include <Eigen/Core>
#include <memory>
#include <vector>

#include "src/core/error.h"
#include "src/core/field_map.h"

namespace stereoloc {

class FieldShiftedFactor final : public ceres::CostFunction {
 public:
  using LandmarkJacobian = Eigen::Matrix<double, 2, kFieldDimensionCount>;

  // inner: blocks (pose, b_1..b_k), k >= 0; takes ownership.
  FieldShiftedFactor(ceres::CostFunction* inner, const LandmarkJacobian& J_landmark_field)
      : inner_(inner), J_l_(J_landmark_field) {
    const std::vector<int32_t>& b = inner_->parameter_block_sizes();
    if (b.empty() || b[0] != 3) throw Error("field-shifted factor: the inner factor's first block must be the pose");
    set_num_residuals(inner_->num_residuals());
    *mutable_parameter_block_sizes() = b;
    mutable_parameter_block_sizes()->push_back(kFieldDimensionCount);
  }

  bool Evaluate(double const* const* p, double* r, double** J) const override {
    const size_t k = inner_->parameter_block_sizes().size();  // the field's block index
    const Eigen::Map<const Eigen::Matrix<double, kFieldDimensionCount, 1>> f(p[k]);
    const Eigen::Vector2d shift = J_l_ * f;
    const double pose[3] = {p[0][0] - shift.x(), p[0][1] - shift.y(), p[0][2]};
    std::vector<const double*> blocks(p, p + k);
    blocks[0] = pose;
    if (!J) return inner_->Evaluate(blocks.data(), r, nullptr);
    const int m = num_residuals();
    using RowMajor = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
    RowMajor J_x(m, 3);
    std::vector<double*> jac(J, J + k);
    jac[0] = J_x.data();  // needed for the field's Jacobian even when the pose's is not asked for
    if (!inner_->Evaluate(blocks.data(), r, jac.data())) return false;
    if (J[0]) Eigen::Map<RowMajor>(J[0], m, 3) = J_x;
    if (J[k]) Eigen::Map<RowMajor>(J[k], m, kFieldDimensionCount) = -J_x.leftCols<2>() * J_l_;
    return true;
  }

 private:
  std::unique_ptr<ceres::CostFunction> inner_;
  LandmarkJacobian J_l_;
};

}  // namespace stereoloc
