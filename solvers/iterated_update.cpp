#include "solvers/iterated_update.h"

#include <Eigen/Cholesky>
#include <Eigen/LU>
#include <cmath>
#include <limits>

#include "src/core/error.h"
#include "src/core/measurement_model.h"

namespace stereoloc {
namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

// h and H at x^ [+] delta; nullopt where the bearing is undefined.
struct Linearisation {
  Eigen::Vector2d nu;  // z [-] h
  Matrix23d H;
};

std::optional<Linearisation> linearise(const Pose2& prior, const Eigen::Vector2d& z, const Eigen::Vector2d& landmark,
                                       const Eigen::Vector3d& delta) {
  Linearisation l;
  try {
    l.nu = rangeBearingInnovation(z, predictRangeBearing(plus(prior, delta), landmark, &l.H));  // (5.27)
  } catch (const GeometryError&) {
    return std::nullopt;
  }
  if (!l.nu.allFinite() || !l.H.allFinite()) return std::nullopt;
  return l;
}

// c(delta) of the header, from the Cholesky factors of P and R.
class MapCost {
 public:
  MapCost(const Pose2& prior, const Eigen::Matrix3d& P, const Eigen::Vector2d& z, const Eigen::Matrix2d& R,
          const Eigen::Vector2d& landmark)
      : prior_(prior), z_(z), landmark_(landmark), llt_P_(P), llt_R_(R) {
    defined_ = llt_P_.info() == Eigen::Success && llt_R_.info() == Eigen::Success;
  }
  bool defined() const { return defined_; }
  const Eigen::LLT<Eigen::Matrix3d>& lltP() const { return llt_P_; }
  const Eigen::LLT<Eigen::Matrix2d>& lltR() const { return llt_R_; }
  double operator()(const Eigen::Vector3d& delta) const {
    const std::optional<Linearisation> l = linearise(prior_, z_, landmark_, delta);
    if (!l) return kInf;
    const double c = llt_P_.matrixL().solve(delta).squaredNorm() + llt_R_.matrixL().solve(l->nu).squaredNorm();
    return std::isfinite(c) ? c : kInf;
  }

 private:
  Pose2 prior_;
  Eigen::Vector2d z_, landmark_;
  Eigen::LLT<Eigen::Matrix3d> llt_P_;
  Eigen::LLT<Eigen::Matrix2d> llt_R_;
  bool defined_ = false;
};

}  // namespace

std::optional<RangeBearingInnovation> rangeBearingInnovationAt(const Pose2& pose, const Eigen::Matrix3d& P,
                                                               const Eigen::Vector2d& z, const Eigen::Matrix2d& R,
                                                               const Eigen::Vector2d& landmark) {
  const std::optional<Linearisation> l = linearise(pose, z, landmark, Eigen::Vector3d::Zero());
  if (!l) return std::nullopt;
  RangeBearingInnovation g;
  g.innovation = l->nu;  // wrapped before gating
  g.J_h_pose = l->H;
  g.covariance = l->H * P * l->H.transpose() + R;  // (5.14)
  g.mahalanobis_squared = l->nu.dot(g.covariance.inverse() * l->nu);  // (5.20)
  if (!std::isfinite(g.mahalanobis_squared)) return std::nullopt;
  return g;
}

std::optional<MapResidual> rangeBearingMapResidual(const Pose2& prior, const Eigen::Matrix3d& P,
                                                   const Eigen::Vector2d& z, const Eigen::Matrix2d& R,
                                                   const Eigen::Vector2d& landmark, const Eigen::Vector3d& delta) {
  const MapCost cost(prior, P, z, R, landmark);
  const std::optional<Linearisation> l = linearise(prior, z, landmark, delta);
  if (!cost.defined() || !l) return std::nullopt;
  MapResidual m;
  const auto LP = cost.lltP().matrixL();
  const auto LR = cost.lltR().matrixL();
  m.r.head<3>() = LP.solve(delta);
  m.r.tail<2>() = LR.solve(l->nu);
  m.J_r_delta.topRows<3>() = LP.solve(Eigen::Matrix3d::Identity());
  m.J_r_delta.bottomRows<2>() = -LR.solve(l->H);  // d nu / d delta = -H
  return m;
}

std::optional<RangeBearingPosterior> updateRangeBearingBelief(const Pose2& prior, const Eigen::Matrix3d& P,
                                                              const Eigen::Vector2d& z, const Eigen::Matrix2d& R,
                                                              const Eigen::Vector2d& landmark,
                                                              const IteratedUpdateOptions& options) {
  if (options.max_iterations < 1 || !(options.tolerance >= 0) || options.max_step_halvings < 0)
    throw Error("iterated update: max_iterations must be >= 1, tolerance and max_step_halvings >= 0");
  std::optional<Linearisation> lin = linearise(prior, z, landmark, Eigen::Vector3d::Zero());
  if (!lin) return std::nullopt;  // the bearing is undefined at the prior: nothing to fuse
  const auto gain = [&](const Matrix23d& H) -> Eigen::Matrix<double, 3, 2> {
    const Eigen::Matrix<double, 3, 2> PHt = P * H.transpose();
    return PHt * (H * PHt + R).inverse();  // (5.19)
  };
  Eigen::Matrix<double, 3, 2> K = gain(lin->H);
  Eigen::Vector3d delta = Eigen::Vector3d::Zero();
  RangeBearingPosterior post;
  const MapCost cost(prior, P, z, R, landmark);
  if (options.max_iterations == 1) {
    delta = K * lin->nu;  // (5.15)
    post.iterations = 1;
  } else {
    double c = cost.defined() ? cost(delta) : kInf;
    for (int it = 0; it < options.max_iterations; ++it) {
      const Eigen::Vector3d step = K * (lin->nu + lin->H * delta) - delta;  // Gauss-Newton, Kalman form
      if (!step.allFinite()) break;
      Eigen::Vector3d next = delta + step;
      std::optional<Linearisation> next_lin;
      if (cost.defined()) {
        // Step control: the first of a = 1, 1/2, ... that lowers the MAP cost.
        double a = 1.0;
        bool lowered = false;
        for (int halving = 0; halving <= options.max_step_halvings; ++halving, a *= 0.5) {
          next = delta + a * step;
          const double cn = cost(next);
          if (cn < c) {
            c = cn;
            lowered = true;
            break;
          }
        }
        if (!lowered) break;  // delta is a minimum to within the shortest step
      }
      next_lin = linearise(prior, z, landmark, next);
      if (!next_lin) break;  // only without step control: a defined cost implies a defined h
      const double moved = (next - delta).cwiseAbs().maxCoeff();
      delta = next;
      lin = next_lin;
      K = gain(lin->H);
      ++post.iterations;
      if (moved <= options.tolerance) break;
    }
  }
  post.pose = plus(prior, delta);
  const Eigen::Matrix3d IKH = Eigen::Matrix3d::Identity() - K * lin->H;
  const Eigen::Matrix3d Pn = IKH * P * IKH.transpose() + K * R * K.transpose();  // (5.17)
  post.covariance = 0.5 * (Pn + Pn.transpose());
  post.map_cost = cost.defined() ? cost(delta) : kInf;
  return post;
}

}  // namespace stereoloc
