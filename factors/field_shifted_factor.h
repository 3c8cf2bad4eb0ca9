#pragma once
// A sighting factor whose landmark stands where the field's true dimensions put it: the batch
// smoother's field self-calibration (`--calibrate stereo,field`, solvers/self_calibration.h).
//
//   r(x, G) = r_inner(x - [J_l f; 0], g),   f = G[field_index .. field_index + 9), g = G[0 .. m)
//
// x = (x, y, theta) the robot pose in the world frame (mm, mm, rad); f the change of the nine
// field dimensions (mm, kFieldDimensions of src/core/field_map.h); J_l = d(landmark x, y)/d f
// (FieldMap::landmarkFieldJacobian); g the inner factor's global block (m entries, none for a
// factor on the pose alone), the first entries of the joined global block G.
// Why a shifted pose: every sighting model here sees the landmark only through its position
// relative to the robot in the world frame, l - p, so moving the landmark by J_l f is moving
// the robot by -J_l f: the inner factor is used as it is, whatever its calibration blocks.
// Jacobians: J_r_x = J_inner_x (the shift does not depend on x; the pose manifold's Plus is the
// identity on (x, y)), J_r_f = -J_inner_x[:, 0:2] J_l, J_r_g = J_inner_g.
#include <ceres/cost_function.h>

#include <Eigen/Core>
#include <algorithm>
#include <memory>
#include <vector>

#include "src/core/error.h"
#include "src/core/field_map.h"

namespace stereoloc {

class FieldShiftedFactor final : public ceres::CostFunction {
 public:
  using LandmarkJacobian = Eigen::Matrix<double, 2, kFieldDimensionCount>;

  // inner: blocks (pose) or (pose, g); takes ownership. joined_size: entries of G, at least
  // field_index + kFieldDimensionCount and the inner g's size.
  FieldShiftedFactor(ceres::CostFunction* inner, const LandmarkJacobian& J_landmark_field, int field_index, int joined_size)
      : inner_(inner), J_l_(J_landmark_field), field_index_(field_index) {
    const std::vector<int32_t>& b = inner_->parameter_block_sizes();
    if (b.empty() || b.size() > 2 || b[0] != 3) throw Error("field-shifted factor: the inner factor must be on (pose[, g])");
    inner_global_ = b.size() == 2 ? b[1] : 0;
    if (field_index < inner_global_ || joined_size < field_index + kFieldDimensionCount)
      throw Error("field-shifted factor: the field entries must follow the inner block inside the joined block");
    set_num_residuals(inner_->num_residuals());
    mutable_parameter_block_sizes()->push_back(3);
    mutable_parameter_block_sizes()->push_back(joined_size);
  }

  bool Evaluate(double const* const* p, double* r, double** J) const override {
    const Eigen::Map<const Eigen::Matrix<double, kFieldDimensionCount, 1>> f(p[1] + field_index_);
    const Eigen::Vector2d shift = J_l_ * f;
    const double pose[3] = {p[0][0] - shift.x(), p[0][1] - shift.y(), p[0][2]};
    const double* blocks[2] = {pose, p[1]};
    const int m = num_residuals();
    if (!J) return inner_->Evaluate(blocks, r, nullptr);
    using RowMajor = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
    RowMajor J_x(m, 3), J_g(m, std::max(inner_global_, 1));
    double* jac[2] = {J_x.data(), J[1] && inner_global_ > 0 ? J_g.data() : nullptr};
    if (!inner_->Evaluate(blocks, r, jac)) return false;
    if (J[0]) Eigen::Map<RowMajor>(J[0], m, 3) = J_x;
    if (J[1]) {
      const int n = parameter_block_sizes()[1];
      Eigen::Map<RowMajor> out(J[1], m, n);
      out.setZero();
      if (inner_global_ > 0) out.leftCols(inner_global_) = J_g;
      out.middleCols(field_index_, kFieldDimensionCount) = -J_x.leftCols<2>() * J_l_;
    }
    return true;
  }

 private:
  std::unique_ptr<ceres::CostFunction> inner_;
  LandmarkJacobian J_l_;
  int field_index_;
  int inner_global_ = 0;
};

}  // namespace stereoloc
