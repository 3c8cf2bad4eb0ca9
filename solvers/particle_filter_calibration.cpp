// The particle filter's self-calibration: each particle's wheels, stereo head and their kernel,
// the calibrated views the gate and the global fixes take, the estimate the set gives
// (solvers/particle_filter.h, "Self-calibration"; docs/estimators.md).
#include "solvers/particle_filter.h"

#include <Eigen/Cholesky>
#include <Eigen/LU>
#include <cmath>
#include <optional>

#include "solvers/calibrated_models.h"
#include "src/core/angles.h"
#include "src/core/error.h"
#include "src/core/gaussian.h"
#include "src/core/measurement_model.h"

namespace stereoloc {
namespace {

// A factor L with L L^T = C for a covariance that is positive semi-definite up to round-off (a
// prior sigma may be 0: that value is then given).
template <typename Matrix>
Matrix semiDefiniteFactor(const Matrix& C) {
  const Matrix sym = 0.5 * (C + C.transpose());
  const Eigen::LDLT<Matrix> ldlt(sym);
  const Matrix L = ldlt.matrixL();
  return ldlt.transpositionsP().transpose() * L * ldlt.vectorD().cwiseMax(0.0).cwiseSqrt().asDiagonal();
}

}  // namespace

void ParticleFilter::setUpCalibration() {
  const SelfCalibrationConfig& k = config_.calibration;
  if (k.range || k.field || k.consider)
    throw Error("particle filter: self-calibrates the odometry and stereo blocks only (range, field and consider are the other estimators')");
  if (!(config_.calibration_discount > 0 && config_.calibration_discount <= 1))
    throw Error("particle filter: calibration_discount must be in (0, 1]");
  if (!k.odometry && !k.stereo) return;
  k.validate();
  if (config_.proposal != ParticleProposal::LinearisedOptimal)
    throw Error("particle filter: self-calibration needs the linearised optimal proposal");
  if (k.odometry) {
    wheels_at_ = cal_dim_;
    cal_dim_ += 3;
  }
  if (k.stereo) {
    head_at_ = cal_dim_;
    cal_dim_ += 6;
  }
  cal_mean_.resize(cal_dim_);
  Eigen::VectorXd sigma(cal_dim_);
  if (wheels_at_ >= 0) {
    cal_mean_.segment<3>(wheels_at_) = Eigen::Vector3d(1.0, 1.0, odometry_.wheel_base_mm);
    sigma.segment<3>(wheels_at_) = wheelPriorSigma(k, odometry_.wheel_base_mm);
  }
  if (head_at_ >= 0) {
    cal_mean_.segment<6>(head_at_) = CalibrationEstimate().head;
    sigma.segment<6>(head_at_) = stereoPriorSigma(k);
  }
  cal_cov_ = sigma.cwiseAbs2().asDiagonal();
}

void ParticleFilter::drawCalibration(size_t begin, size_t end) {
  if (cal_dim_ == 0) return;
  const size_t K = static_cast<size_t>(cal_dim_);
  cal_.resize(x_.size() * K);
  const Eigen::MatrixXd L = semiDefiniteFactor(cal_cov_);
  Eigen::VectorXd e(cal_dim_), d(cal_dim_);
  for (size_t i = begin; i < end; ++i) {
    for (int j = 0; j < cal_dim_; ++j) e(j) = normal_(rng_);
    d.noalias() = L * e;
    Eigen::Map<Eigen::VectorXd>(cal_.data() + i * K, cal_dim_) = cal_mean_ + d;
  }
}

void ParticleFilter::summariseCalibration() {
  if (cal_dim_ == 0 || x_.empty()) return;
  // The joint (pose, calibration) covariance, the pose about mean_ (summarise()), the heading's
  // deviations wrapped: the kernel moves both together, so it keeps their correlation.
  const Eigen::Index n = static_cast<Eigen::Index>(x_.size());
  Eigen::MatrixXd z(3 + cal_dim_, n);
  for (Eigen::Index i = 0; i < n; ++i) {
    const size_t k = static_cast<size_t>(i);
    z(0, i) = x_[k] - mean_.x;
    z(1, i) = y_[k] - mean_.y;
    z(2, i) = angleDiff(th_[k], mean_.theta);
  }
  z.bottomRows(cal_dim_) = Eigen::Map<const Eigen::MatrixXd>(cal_.data(), cal_dim_, n);
  const Eigen::Map<const Eigen::VectorXd> w(w_.data(), n);
  cal_mean_ = z.bottomRows(cal_dim_) * w;
  z.bottomRows(cal_dim_).colwise() -= cal_mean_;
  const Eigen::MatrixXd C = z * w.asDiagonal() * z.transpose();
  joint_cov_ = 0.5 * (C + C.transpose());
  cal_cov_ = joint_cov_.bottomRightCorner(cal_dim_, cal_dim_);
}

void ParticleFilter::jitterCalibration() {
  if (cal_dim_ == 0 || !(config_.calibration_discount < 1)) return;
  // Liu and West (2001), sec. 3.3: the kernel locations are shrunk by a towards the mean and the
  // kernel's variance is h^2 C with h^2 = 1 - a^2, so the mixture keeps the mean m and covariance
  // C. On the joint (pose, calibration) state: a calibration moved alone would no longer fit its
  // pose, and the next weights would cull the moved ones, shrinking the calibration's spread.
  const double delta = config_.calibration_discount, a = (3.0 * delta - 1.0) / (2.0 * delta);
  const Eigen::MatrixXd L = semiDefiniteFactor(Eigen::MatrixXd((1.0 - a * a) * joint_cov_));
  const size_t K = static_cast<size_t>(cal_dim_);
  Eigen::VectorXd e(3 + cal_dim_), d(3 + cal_dim_);
  for (size_t i = 0; i < x_.size(); ++i) {
    for (int j = 0; j < 3 + cal_dim_; ++j) e(j) = normal_(rng_);
    d.noalias() = L * e;
    setParticle(i, mean_.x + a * (x_[i] - mean_.x) + d(0), mean_.y + a * (y_[i] - mean_.y) + d(1),
                wrapAngle(mean_.theta + a * angleDiff(th_[i], mean_.theta) + d(2)));
    Eigen::Map<Eigen::VectorXd> c(cal_.data() + i * K, cal_dim_);
    c = cal_mean_ + a * (c - cal_mean_) + d.tail(cal_dim_);
  }
}

void ParticleFilter::walkWheels(double d_left, double d_right) {
  const UnmodelledNoise& noise = config_.observation_model.unmodelled;
  if (wheels_at_ < 0 || !noise.wheelsDrift()) return;
  const Eigen::Vector3d sd = wheelDriftVariance(noise, d_left, d_right, odometry_.wheel_base_mm).cwiseSqrt();
  const size_t K = static_cast<size_t>(cal_dim_);
  for (size_t i = 0; i < x_.size(); ++i) {
    double* c = cal_.data() + i * K + wheels_at_;
    for (int j = 0; j < 3; ++j) c[j] += sd(j) * normal_(rng_);
  }
}

OdometryParams ParticleFilter::stepOdometry(double d_left, double d_right) const {
  const double slip = config_.observation_model.unmodelled.slip_rel_sigma;
  return cal_dim_ > 0 && slip > 0 ? withSlip(odometry_, d_left, d_right, slip) : odometry_;
}

Observation ParticleFilter::calibratedForGate(const Observation& obs, const Landmark& landmark) const {
  if (head_at_ < 0) return obs;
  const Eigen::Matrix4d C_px = pixelCovarianceFor(obs, landmark, config_.observation_model);
  return calibratedObservation(obs, config_.observation_model.rig, cal_mean_.segment<6>(head_at_),
                               cal_cov_.block<6, 6>(head_at_, head_at_), C_px);
}

std::optional<CalibrationEstimate> ParticleFilter::calibration() const {
  if (cal_dim_ == 0) return std::nullopt;
  CalibrationEstimate e;
  e.odometry = wheels_at_ >= 0;
  e.stereo = head_at_ >= 0;
  e.wheels = Eigen::Vector3d(1.0, 1.0, odometry_.wheel_base_mm);
  if (e.odometry) {
    e.wheels = cal_mean_.segment<3>(wheels_at_);
    e.wheels_covariance = cal_cov_.block<3, 3>(wheels_at_, wheels_at_);
  }
  if (e.stereo) {
    e.head = cal_mean_.segment<6>(head_at_);
    e.head_covariance = cal_cov_.block<6, 6>(head_at_, head_at_);
  }
  return e;
}

Eigen::VectorXd ParticleFilter::particleCalibration(int i) const {
  if (i < 0 || i >= size()) throw Error("particle filter: no particle " + std::to_string(i));
  if (cal_dim_ == 0) return Eigen::VectorXd();
  return Eigen::Map<const Eigen::VectorXd>(cal_.data() + static_cast<size_t>(i) * static_cast<size_t>(cal_dim_), cal_dim_);
}

Step ParticleFilter::seenThroughCalibration(const Step& step) const {
  if (head_at_ < 0) return step;
  Step out = step;
  for (Observation& o : out.observations) {
    Landmark kind;
    kind.type = o.type;
    try {
      o = calibratedForGate(o, kind);
    } catch (const GeometryError&) {
      // the set's calibration puts it behind the cameras: the fix takes it as measured
    }
  }
  return out;
}

std::optional<PoseFix> ParticleFilter::reanchoringFix(const Step& step, const StepObservations& used) const {
  if (cal_dim_ == 0 || !config_.global_fix) return std::nullopt;
  const std::optional<PoseFix> fix = config_.global_fix(seenThroughCalibration(step), map_);
  if (!fix || !fix->pose.isFinite() || !fix->covariance.allFinite() ||
      Eigen::LLT<Eigen::Matrix3d>(fix->covariance).info() != Eigen::Success)
    return std::nullopt;
  const Eigen::Vector3d nu = minus(fix->pose, used.predicted);
  const Eigen::LDLT<Eigen::Matrix3d> ldlt(used.predicted_covariance + fix->covariance);
  if (ldlt.info() != Eigen::Success) return std::nullopt;
  // The self-calibrating EKF's bound (solvers/ekf.cpp): the 0.999 gate, at least 1000.
  const double d2 = nu.dot(ldlt.solve(nu));
  if (!(d2 <= std::max(chi2Quantile(0.999, 3), 1000.0))) return std::nullopt;
  return fix;
}

void ParticleFilter::weightByFix(const PoseFix& fix) {
  const Eigen::Matrix3d F = (0.5 * (fix.covariance + fix.covariance.transpose())).inverse();
  for (size_t i = 0; i < x_.size(); ++i) {
    const Eigen::Vector3d e(fix.pose.x - x_[i], fix.pose.y - y_[i], angleDiff(fix.pose.theta, th_[i]));
    logw_[i] += std::max(-0.5 * e.dot(F * e), log_floor_);
  }
  uniform_weights_ = false;
  normalise();
}

}  // namespace stereoloc
