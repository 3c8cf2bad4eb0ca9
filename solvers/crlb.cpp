#include "solvers/crlb.h"

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <limits>
#include <memory>

#include "src/core/error.h"
#include "src/core/measurement_model.h"

namespace stereoloc {
namespace {

// The inverse of a symmetric positive definite 3x3 information block. The rank test is the one
// of chainMarginalCovariances (smoother_common.h): reciprocal condition relative to the block's
// scale above 1e-14, as ceres::Covariance uses.
Eigen::Matrix3d invertInformation(const Eigen::Matrix3d& M, const char* what, size_t pose) {
  const Eigen::Matrix3d S = 0.5 * (M + M.transpose());
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(S);
  const double scale = std::max(S.cwiseAbs().maxCoeff(), std::numeric_limits<double>::min());
  if (!S.allFinite() || eig.info() != Eigen::Success || !(eig.eigenvalues()(0) > 1e-14 * scale))
    throw Error(std::string("crlb: ") + what + " at pose " + std::to_string(pose) +
                " is singular (the data do not determine the trajectory there)");
  const Eigen::Matrix3d inv =
      eig.eigenvectors() * eig.eigenvalues().cwiseInverse().asDiagonal() * eig.eigenvectors().transpose();
  return 0.5 * (inv + inv.transpose());
}

void checkShape(const TrajectoryInformation& info) {
  const size_t n = info.steps.size();
  if (n == 0) throw Error("crlb: empty trajectory");
  if (info.unary.size() != n || info.odometry_prev.size() != n || info.odometry_cross.size() != n ||
      info.odometry_curr.size() != n)
    throw Error("crlb: inconsistent trajectory information (block counts differ)");
}

// The filtered information J_k (Tichavsky et al. 1998): the information on pose k from the data
// up to and including step k.
std::vector<Eigen::Matrix3d> filteredInformation(const TrajectoryInformation& info) {
  checkShape(info);
  const size_t n = info.size();
  std::vector<Eigen::Matrix3d> J(n);
  J[0] = info.unary[0];
  for (size_t k = 1; k < n; ++k) {
    const Eigen::Matrix3d inv = invertInformation(J[k - 1] + info.odometry_prev[k], "the filtered information", k - 1);
    const Eigen::Matrix3d& D12 = info.odometry_cross[k];
    const Eigen::Matrix3d Jk = info.unary[k] + info.odometry_curr[k] - D12.transpose() * inv * D12;
    J[k] = 0.5 * (Jk + Jk.transpose());
  }
  return J;
}

}  // namespace

std::string toString(OdometryCovarianceAt at) { return at == OdometryCovarianceAt::Truth ? "truth" : "measured"; }

OdometryCovarianceAt odometryCovarianceAtFromString(const std::string& name) {
  for (OdometryCovarianceAt a : {OdometryCovarianceAt::Truth, OdometryCovarianceAt::Measured})
    if (toString(a) == name) return a;
  throw Error("unknown odometry covariance point '" + name + "' (expected truth or measured)");
}

TrajectoryInformation TrajectoryInformation::zero(const std::vector<long>& steps) {
  TrajectoryInformation t;
  t.steps = steps;
  const size_t n = steps.size();
  t.unary.assign(n, Eigen::Matrix3d::Zero());
  t.odometry_prev.assign(n, Eigen::Matrix3d::Zero());
  t.odometry_cross.assign(n, Eigen::Matrix3d::Zero());
  t.odometry_curr.assign(n, Eigen::Matrix3d::Zero());
  return t;
}

TrajectoryInformation& TrajectoryInformation::operator+=(const TrajectoryInformation& o) {
  checkShape(*this);
  checkShape(o);
  if (steps != o.steps) throw Error("crlb: cannot add the information of different trajectories");
  for (size_t k = 0; k < size(); ++k) {
    unary[k] += o.unary[k];
    odometry_prev[k] += o.odometry_prev[k];
    odometry_cross[k] += o.odometry_cross[k];
    odometry_curr[k] += o.odometry_curr[k];
  }
  observations_used += o.observations_used;
  observations_skipped += o.observations_skipped;
  compass_used += o.compass_used;
  return *this;
}

void TrajectoryInformation::chainBlocks(std::vector<Eigen::Matrix3d>* D, std::vector<Eigen::Matrix3d>* B) const {
  checkShape(*this);
  const size_t n = size();
  D->assign(n, Eigen::Matrix3d::Zero());
  B->assign(n, Eigen::Matrix3d::Zero());
  for (size_t k = 0; k < n; ++k) {
    (*D)[k] = unary[k] + odometry_curr[k];
    if (k + 1 < n) (*D)[k] += odometry_prev[k + 1];
    if (k > 0) (*B)[k] = odometry_cross[k];
  }
}

Eigen::MatrixXd TrajectoryInformation::dense() const {
  std::vector<Eigen::Matrix3d> D, B;
  chainBlocks(&D, &B);
  const Eigen::Index n = static_cast<Eigen::Index>(size());
  Eigen::MatrixXd H = Eigen::MatrixXd::Zero(3 * n, 3 * n);
  for (Eigen::Index k = 0; k < n; ++k) {
    H.block<3, 3>(3 * k, 3 * k) = D[static_cast<size_t>(k)];
    if (k > 0) {
      H.block<3, 3>(3 * (k - 1), 3 * k) = B[static_cast<size_t>(k)];
      H.block<3, 3>(3 * k, 3 * (k - 1)) = B[static_cast<size_t>(k)].transpose();
    }
  }
  return H;
}

Eigen::Matrix<double, 6, 6> odometryFactorInformation(const Pose2& a, const Pose2& b, const Eigen::Matrix3d& U) {
  // e = between(a, b) [-] u: the subtraction of the constant u (angle wrapped) has the identity
  // Jacobian, so de/da = J_between_a and de/db = J_between_b (pose2.h convention).
  Matrix3d Ja, Jb;
  between(a, b, &Ja, &Jb);
  Eigen::Matrix<double, 3, 6> J;
  J << Ja, Jb;
  const Eigen::Matrix3d Us = 0.5 * (U + U.transpose());
  Eigen::LLT<Eigen::Matrix3d> llt(Us);
  if (llt.info() != Eigen::Success || !Us.allFinite()) throw Error("crlb: odometry covariance U is not positive definite");
  const Eigen::Matrix<double, 6, 6> I = J.transpose() * llt.solve(J);
  return 0.5 * (I + I.transpose());
}

Eigen::Matrix3d rangeBearingInformation(const Pose2& pose, const Eigen::Vector2d& landmark, const Eigen::Matrix2d& R) {
  Matrix23d H;
  predictRangeBearing(pose, landmark, &H);  // (5.27); GeometryError at the landmark
  const Eigen::Matrix2d Rs = 0.5 * (R + R.transpose());
  Eigen::LLT<Eigen::Matrix2d> llt(Rs);
  if (llt.info() != Eigen::Success || !Rs.allFinite())
    throw Error("crlb: observation covariance R is not positive definite");
  const Eigen::Matrix3d I = H.transpose() * llt.solve(H);
  return 0.5 * (I + I.transpose());
}

Eigen::Matrix3d pixelInformation(const Pose2& pose, const Observation& obs, const Landmark& landmark,
                                 const ObservationModelConfig& model) {
  // The Jacobian of the whitened residual does not depend on the measured pixels (they enter
  // additively), so the factor built from the observation gives J at the true pose.
  const std::unique_ptr<ceres::CostFunction> cost(makeObservationFactor(obs, landmark, model));
  const int m = cost->num_residuals();
  Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor> J(m, 3);
  Eigen::VectorXd r(m);
  const double p[3] = {pose.x, pose.y, pose.theta};
  const double* params[1] = {p};
  double* jac[1] = {J.data()};
  if (!cost->Evaluate(params, r.data(), jac) || !J.allFinite())
    throw GeometryError("crlb: the landmark is not in front of the cameras at the true pose");
  const Eigen::Matrix3d I = J.transpose() * J;
  return 0.5 * (I + I.transpose());
}

TrajectoryInformation trajectoryInformation(const std::vector<Step>& steps, const std::vector<Pose2>& truth,
                                            const FieldMap& map, const OdometryParams& odometry,
                                            const Eigen::Matrix3d& prior_covariance, const CrlbOptions& options) {
  if (steps.empty()) throw Error("crlb: empty trajectory");
  if (truth.size() != steps.size())
    throw Error("crlb: " + std::to_string(truth.size()) + " true poses for " + std::to_string(steps.size()) + " steps");
  odometry.validate();
  std::vector<long> numbers;
  for (size_t k = 0; k < steps.size(); ++k) {
    if (k > 0 && steps[k].step <= steps[k - 1].step)
      throw Error("crlb: step " + std::to_string(steps[k].step) + " does not follow step " +
                  std::to_string(steps[k - 1].step));
    if (!truth[k].isFinite()) throw Error("crlb: true pose at step " + std::to_string(steps[k].step) + " is not finite");
    numbers.push_back(steps[k].step);
  }
  TrajectoryInformation info = TrajectoryInformation::zero(numbers);
  if (options.prior) {
    const Eigen::Matrix3d P0 = 0.5 * (prior_covariance + prior_covariance.transpose());
    Eigen::LLT<Eigen::Matrix3d> llt(P0);
    if (!P0.allFinite() || llt.info() != Eigen::Success)
      throw Error("crlb: the prior covariance is not positive definite");
    info.unary[0] += llt.solve(Eigen::Matrix3d::Identity());
  }
  for (size_t k = 0; k < steps.size(); ++k) {
    const Step& st = steps[k];
    const std::string at = "crlb: step " + std::to_string(st.step);
    if (options.odometry && k > 0) {
      double dl = st.d_left, dr = st.d_right;
      if (options.odometry_covariance == OdometryCovarianceAt::Truth) {
        const Arc arc = arcBetween(truth[k - 1], truth[k]);
        const WheelIncrements w = wheelIncrementsForArc(arc.length, arc.dtheta, odometry.wheel_base_mm);
        dl = w.d_left;
        dr = w.d_right;
      }
      if (!std::isfinite(dl) || !std::isfinite(dr)) throw Error(at + ": wheel increment is not finite");
      const Eigen::Matrix<double, 6, 6> I = odometryFactorInformation(truth[k - 1], truth[k],
                                                                       controlCovariance(dl, dr, odometry));  // (B.10)
      info.odometry_prev[k] = I.topLeftCorner<3, 3>();
      info.odometry_cross[k] = I.topRightCorner<3, 3>();
      info.odometry_curr[k] = I.bottomRightCorner<3, 3>();
    }
    if (options.compass && st.compass) {
      if (!(std::isfinite(st.compass_sigma) && st.compass_sigma > 0))
        throw Error(at + ": compass_sigma must be a positive number");
      info.unary[k](2, 2) += 1.0 / (st.compass_sigma * st.compass_sigma);
      ++info.compass_used;
    }
    if (!options.observations) continue;
    for (size_t i = 0; i < st.observations.size(); ++i) {
      const Observation& o = st.observations[i];
      if (o.landmark_id < 0) {
        ++info.observations_skipped;
        continue;
      }
      const Landmark* lm = map.find(o.landmark_id);
      if (!lm)
        throw Error(at + ": observation " + std::to_string(i) + ": unknown landmark id " + std::to_string(o.landmark_id));
      try {
        if (options.observation_model.model != ObservationModel::RangeBearing && o.pixels)
          info.unary[k] += pixelInformation(truth[k], o, *lm, options.observation_model);
        else
          info.unary[k] += rangeBearingInformation(truth[k], lm->xy(), o.covariance);
        ++info.observations_used;
      } catch (const GeometryError&) {
        ++info.observations_skipped;  // the true pose is on the landmark: no bearing, no information
      } catch (const Error& e) {
        throw Error(at + ": observation " + std::to_string(i) + ": " + e.what());
      }
    }
  }
  return info;
}

TrajectoryInformation trajectoryInformation(const Dataset& d, const Eigen::Matrix3d& prior_covariance,
                                            const CrlbOptions& options) {
  if (d.groundtruth.size() != d.steps.size())
    throw Error("crlb: dataset '" + d.name + "' has no ground truth for every step");
  std::vector<Pose2> truth;
  truth.reserve(d.steps.size());
  for (size_t k = 0; k < d.steps.size(); ++k) {
    if (!d.groundtruth[k])
      throw Error("crlb: dataset '" + d.name + "': no ground truth at step " + std::to_string(d.steps[k].step));
    truth.push_back(*d.groundtruth[k]);
  }
  return trajectoryInformation(d.steps, truth, d.map, d.odometry, prior_covariance, options);
}

std::vector<Eigen::Matrix3d> filteringBound(const TrajectoryInformation& info) {
  const std::vector<Eigen::Matrix3d> J = filteredInformation(info);
  std::vector<Eigen::Matrix3d> bound(J.size());
  for (size_t k = 0; k < J.size(); ++k) bound[k] = invertInformation(J[k], "the filtered information", k);
  return bound;
}

std::vector<Eigen::Matrix3d> fixedLagBound(const TrajectoryInformation& info, int lag) {
  if (lag < 0) throw Error("crlb: the lag must be >= 0");
  const std::vector<Eigen::Matrix3d> J = filteredInformation(info);
  const size_t n = J.size();
  // Lambda_j^-1 and G_j of the truncated chains: they do not depend on where the chain ends.
  std::vector<Eigen::Matrix3d> lambda_inv(n), G(n);
  for (size_t j = 0; j + 1 < n; ++j) {
    lambda_inv[j] = invertInformation(J[j] + info.odometry_prev[j + 1], "the filtered information", j);
    G[j] = lambda_inv[j] * info.odometry_cross[j + 1];
  }
  std::vector<Eigen::Matrix3d> end_cov(n);  // J_m^-1: the last pose of a chain ending at m
  for (size_t m = 0; m < n; ++m) end_cov[m] = invertInformation(J[m], "the filtered information", m);
  std::vector<Eigen::Matrix3d> bound(n);
  const size_t L = static_cast<size_t>(lag);
  if (L + 1 >= n) {  // the smoothing bound: one backward pass
    bound[n - 1] = end_cov[n - 1];
    for (size_t j = n - 1; j-- > 0;) {
      const Eigen::Matrix3d S = lambda_inv[j] + G[j] * bound[j + 1] * G[j].transpose();
      bound[j] = 0.5 * (S + S.transpose());
    }
    return bound;
  }
  for (size_t k = 0; k < n; ++k) {
    const size_t m = std::min(k + L, n - 1);
    Eigen::Matrix3d S = end_cov[m];
    for (size_t j = m; j-- > k;) S = lambda_inv[j] + G[j] * S * G[j].transpose();
    bound[k] = 0.5 * (S + S.transpose());
  }
  return bound;
}

std::vector<Eigen::Matrix3d> smoothingBound(const TrajectoryInformation& info) {
  checkShape(info);
  return fixedLagBound(info, static_cast<int>(std::min<size_t>(info.size(), 1u << 30)));
}

}  // namespace stereoloc
