#include "factors/composed_odometry_calibration_factor.h"

#include <ceres/jet.h>

#include <Eigen/Cholesky>
#include <Eigen/LU>
#include <cmath>
#include <utility>

namespace stereoloc {

ceres::CostFunction* ComposedOdometryCalibrationFactor::Create(const std::vector<std::pair<double, double>>& readings,
                                                               const std::vector<WheelIncrements>& noise_travel,
                                                               const std::vector<OdometryParams>& params) {
  if (readings.empty()) throw Error("composed odometry calibration factor: no readings");
  if (params.size() != readings.size() || noise_travel.size() != readings.size())
    throw Error("composed odometry calibration factor: one noise travel and odometry model per reading expected");
  std::vector<Reading> r;
  for (size_t i = 0; i < readings.size(); ++i) {
    params[i].validate();
    const auto [ml, mr] = readings[i];
    const WheelIncrements& t = noise_travel[i];
    if (!std::isfinite(ml) || !std::isfinite(mr) || !std::isfinite(t.d_left) || !std::isfinite(t.d_right))
      throw Error("composed odometry calibration factor: readings and noise travel must be finite");
    if (params[i].control_variance_floor != params[0].control_variance_floor)
      throw Error("composed odometry calibration factor: the steps' control variance floors differ");
    const Eigen::Matrix2d W = wheelCovariance(t.d_left, t.d_right, params[i]);
    r.push_back(Reading{ml, mr, W(0, 0), W(1, 1)});
  }
  const Eigen::Vector3d floor = params[0].control_variance_floor;
  if (!(floor.minCoeff() > 0))
    throw Error("composed odometry calibration factor: the control variance floor must be positive");
  return new ComposedOdometryCalibrationFactor(std::move(r), floor);
}

bool ComposedOdometryCalibrationFactor::Evaluate(double const* const* parameters, double* residuals,
                                                 double** jacobians) const {
  using Jet = ceres::Jet<double, 3>;
  using M3 = Eigen::Matrix<Jet, 3, 3>;
  using V3 = Eigen::Matrix<Jet, 3, 1>;
  const double* a = parameters[0];
  const double* b = parameters[1];
  const Jet calib[3] = {Jet(parameters[2][0], 0), Jet(parameters[2][1], 1), Jet(parameters[2][2], 2)};
  V3 g;
  M3 P;
  if (!propagate(calib, &g, &P)) return false;
  // Upper S with S^T S = P^-1: the transposed lower Cholesky factor of the information.
  const M3 info = P.inverse();
  const Eigen::LLT<M3> llt(0.5 * (info + info.transpose()));
  if (llt.info() != Eigen::Success) return false;
  const M3 S = llt.matrixU();
  double rel[3];
  betweenT(a, b, rel);
  V3 e;
  e << Jet(rel[0]) - g[0], Jet(rel[1]) - g[1], wrapAngle<Jet>(Jet(rel[2]) - g[2]);
  const V3 r = S * e;
  for (int i = 0; i < 3; ++i) residuals[i] = r[i].a;
  if (!jacobians) return true;
  // rel = (R(theta_a)^T (t_b - t_a), theta_b - theta_a): its Jacobians in the poses.
  const double ca = std::cos(a[2]), sa = std::sin(a[2]);
  const double dx = b[0] - a[0], dy = b[1] - a[1];
  Eigen::Matrix3d J_rel_b;
  J_rel_b << ca, sa, 0.0, -sa, ca, 0.0, 0.0, 0.0, 1.0;
  Eigen::Matrix3d J_rel_a = -J_rel_b;
  J_rel_a(0, 2) = -sa * dx + ca * dy;
  J_rel_a(1, 2) = -ca * dx - sa * dy;
  Eigen::Matrix3d S_value;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) S_value(i, j) = S(i, j).a;
  using RowMajor3 = Eigen::Matrix<double, 3, 3, Eigen::RowMajor>;
  if (jacobians[0]) {
    Eigen::Map<RowMajor3> J_r_a(jacobians[0]);
    J_r_a = S_value * J_rel_a;
  }
  if (jacobians[1]) {
    Eigen::Map<RowMajor3> J_r_b(jacobians[1]);
    J_r_b = S_value * J_rel_b;
  }
  if (jacobians[2]) {
    Eigen::Map<RowMajor3> J_r_c(jacobians[2]);
    for (int i = 0; i < 3; ++i) J_r_c.row(i) = r[i].v.transpose();
  }
  return true;
}

}  // namespace stereoloc
