#include "solvers/particle_filter.h"

#include <Eigen/Cholesky>
#include <Eigen/LU>
#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <unordered_set>
#include <utility>

#include "src/core/error.h"
#include "solvers/calibrated_models.h"
#include "solvers/fast_trig.h"
#include "src/core/gaussian.h"
#include "src/core/measurement_model.h"

namespace stereoloc {

std::string toString(ResamplingScheme scheme) {
  switch (scheme) {
    case ResamplingScheme::Systematic: return "systematic";
    case ResamplingScheme::SortedRoulette: return "sorted_roulette";
  }
  return "systematic";
}

ResamplingScheme resamplingSchemeFromString(const std::string& name) {
  for (ResamplingScheme s : {ResamplingScheme::Systematic, ResamplingScheme::SortedRoulette})
    if (toString(s) == name) return s;
  throw Error("unknown resampling scheme '" + name + "' (expected systematic or sorted_roulette)");
}

std::string toString(ParticleProposal proposal) {
  switch (proposal) {
    case ParticleProposal::Prior: return "prior";
    case ParticleProposal::LinearisedOptimal: return "linearised_optimal";
  }
  return "prior";
}

ParticleProposal particleProposalFromString(const std::string& name) {
  for (ParticleProposal p : {ParticleProposal::Prior, ParticleProposal::LinearisedOptimal})
    if (toString(p) == name) return p;
  throw Error("unknown particle proposal '" + name + "' (expected prior or linearised_optimal)");
}

ZigguratNormal::ZigguratNormal() {
  // Layer edges of the 128-layer ziggurat of N(0,1)'s density shape f(x) = exp(-x^2/2): every
  // layer (and the base strip + tail) has area V.
  const double R = 3.442619855899, V = 9.91256303526217e-3;
  auto f = [](double x) { return std::exp(-0.5 * x * x); };
  x_[0] = V / f(R);
  x_[1] = R;
  for (int i = 1; i < 127; ++i) x_[i + 1] = std::sqrt(-2.0 * std::log(V / x_[i] + f(x_[i])));
  x_[128] = 0.0;
  for (int i = 0; i <= 128; ++i) f_[i] = f(x_[i]);
  f_[0] = 0.0;  // the base strip starts at height 0
}

double ZigguratNormal::slowPath(std::mt19937_64& rng, int i, bool negative, double x) {
  auto uniform = [&rng] { return (static_cast<double>(rng() >> 11) + 0.5) * 0x1.0p-53; };  // (0, 1)
  for (;;) {
    if (i == 0) {  // the tail beyond R = x_[1] (Marsaglia's method)
      const double R = x_[1];
      for (;;) {
        const double t = -std::log(uniform()) / R, y = -std::log(uniform());
        if (2.0 * y >= t * t) return negative ? -(R + t) : R + t;
      }
    }
    // Wedge of layer i: accept when a uniform height in the layer lies under the density.
    if (f_[i] + uniform() * (f_[i + 1] - f_[i]) < std::exp(-0.5 * x * x)) return negative ? -x : x;
    // Rejected: start again with a fresh deviate.
    const uint64_t b = rng();
    i = static_cast<int>(b & 127u);
    negative = (b & 128u) != 0;
    x = static_cast<double>(b >> 11) * 0x1.0p-53 * x_[i];
    if (x < x_[i + 1]) return negative ? -x : x;
  }
}

namespace {

void systematicResampleInto(const std::vector<double>& weights, int n, std::mt19937_64& rng, std::vector<int>& idx) {
  idx.assign(static_cast<size_t>(std::max(n, 0)), 0);
  if (weights.empty() || n <= 0) return;
  const double step = 1.0 / n;
  double pointer = std::uniform_real_distribution<double>(0.0, step)(rng);
  double cumulative = weights[0];
  size_t j = 0;
  const size_t last = weights.size() - 1;
  for (int i = 0; i < n; ++i) {
    while (pointer > cumulative && j < last) cumulative += weights[++j];
    idx[static_cast<size_t>(i)] = static_cast<int>(j);
    pointer += step;
  }
}

}  // namespace

std::vector<int> systematicResample(const std::vector<double>& weights, int n, std::mt19937_64& rng) {
  std::vector<int> idx;
  systematicResampleInto(weights, n, rng, idx);
  return idx;
}

std::vector<int> sortedRouletteResample(const std::vector<double>& weights, int n, std::mt19937_64& rng) {
  std::vector<int> idx(static_cast<size_t>(std::max(n, 0)));
  if (weights.empty() || n <= 0) return idx;
  std::vector<int> order(weights.size());
  std::iota(order.begin(), order.end(), 0);
  // Algorithm 6: sort so that w(i) > w(i+1); stable, so ties keep a reproducible order.
  std::stable_sort(order.begin(), order.end(), [&](int a, int b) { return weights[a] > weights[b]; });
  std::vector<double> cumulative(weights.size());
  double sum = 0.0;
  for (size_t k = 0; k < order.size(); ++k) cumulative[k] = (sum += weights[static_cast<size_t>(order[k])]);
  std::uniform_real_distribution<double> u(0.0, sum);
  for (int i = 0; i < n; ++i) {
    const size_t k = static_cast<size_t>(std::upper_bound(cumulative.begin(), cumulative.end(), u(rng)) - cumulative.begin());
    idx[static_cast<size_t>(i)] = order[std::min(k, order.size() - 1)];
  }
  return idx;
}

namespace {

std::string where(const Step& step, size_t index) {
  return "step " + std::to_string(step.step) + ": observation " + std::to_string(index);
}

void checkObservation(const Step& step, size_t index, const Observation& obs) {
  validateObservation(obs, where(step, index));
}

}  // namespace

ParticleFilter::ParticleFilter(const FieldMap& map, const OdometryParams& odometry, ParticleFilterConfig config,
                               uint64_t seed)
    : map_(map),
      odometry_(odometry),
      config_(std::move(config)),
      rng_(seed),
      gate_(config_.gate, 2),
      bank_(map, odometry, config_.hypotheses) {
  odometry_.validate();
  if (config_.particles < 1) throw Error("particle filter: particles must be at least 1");
  if (config_.kld.enabled) {
    const KldSamplingConfig& k = config_.kld;
    if (!(k.epsilon > 0 && k.quantile > 0.5 && k.quantile < 1 && k.bin_xy_mm > 0 && k.bin_theta_rad > 0))
      throw Error("particle filter: KLD-sampling needs epsilon > 0, quantile in (0.5, 1) and positive bin sizes");
    if (k.min_particles < 1 || k.min_particles > config_.particles)
      throw Error("particle filter: KLD-sampling min_particles must be in [1, particles]");
  }
  if (config_.reinjected < 0 || config_.reinjected > config_.particles)
    throw Error("particle filter: reinjected must be in [0, particles]");
  if (!(config_.likelihood_floor > 0 && config_.likelihood_floor <= 1))
    throw Error("particle filter: likelihood_floor must be in (0, 1]");
  if (!(config_.resample_ess_fraction >= 0 && config_.resample_ess_fraction <= 1))
    throw Error("particle filter: resample_ess_fraction must be in [0, 1]");
  if (!(config_.regularisation_ess_fraction >= 0 && config_.regularisation_ess_fraction <= 1))
    throw Error("particle filter: regularisation_ess_fraction must be in [0, 1]");
  if (!std::isfinite(config_.regularisation_bandwidth))
    throw Error("particle filter: regularisation_bandwidth must be a number (< 0: automatic, 0: off)");
  const Bounds& b = map_.bounds();
  if (!(b.xmax > b.xmin && b.ymax > b.ymin)) throw Error("particle filter: map bounds are empty");
  log_floor_ = std::log(config_.likelihood_floor);
  setUpCalibration();
  if (!config_.global_fix) config_.global_fix = defaultGlobalFix();
  switch (config_.init.mode) {
    case InitMode::Known: initialiseGaussian(config_.init.pose, config_.init.covariance); break;
    case InitMode::Random: initialiseUniform(); break;
    case InitMode::Global: break;
  }
}

void ParticleFilter::drawGaussian(size_t begin, size_t end, const Pose2& pose, const Eigen::Matrix3d& covariance) {
  if (!pose.isFinite() || !covariance.allFinite()) throw Error("particle filter: initial belief is not finite");
  const Eigen::Matrix3d sym = 0.5 * (covariance + covariance.transpose());
  // A semi-definite covariance (e.g. zero) is allowed: the LDLT factor handles it.
  Eigen::LDLT<Eigen::Matrix3d> ldlt(sym);
  if (ldlt.info() != Eigen::Success || !(ldlt.vectorD().array() >= -1e-12 * (sym.norm() + 1.0)).all())
    throw Error("particle filter: initial covariance is not positive semi-definite");
  const Eigen::Matrix3d L = ldlt.transpositionsP().transpose() * Eigen::Matrix3d(ldlt.matrixL()) *
                            ldlt.vectorD().cwiseMax(0.0).cwiseSqrt().asDiagonal();
  for (size_t i = begin; i < end; ++i) {
    const double a = normal_(rng_), b = normal_(rng_), c = normal_(rng_);
    const Eigen::Vector3d d = L * Eigen::Vector3d(a, b, c);
    setParticle(i, pose.x + d.x(), pose.y + d.y(), wrapAngle(pose.theta + d.z()));
  }
  drawCalibration(begin, end);
}

void ParticleFilter::finishInitialisation() {
  const size_t n = x_.size();
  logw_.assign(n, -std::log(static_cast<double>(n)));
  w_.assign(n, 1.0 / static_cast<double>(n));
  uniform_weights_ = true;
  initialised_ = true;
  gate_.reset();
  summarise(&mean_, &cov_);
  summariseCalibration();
}

void ParticleFilter::initialiseGaussian(const Pose2& pose, const Eigen::Matrix3d& covariance) {
  const size_t n = static_cast<size_t>(config_.particles);
  resizeParticles(n);
  drawGaussian(0, n, pose, covariance);
  finishInitialisation();
}

void ParticleFilter::initialiseMixture(const std::vector<PoseHypothesis>& components, const std::vector<double>& weights) {
  if (components.empty() || components.size() != weights.size())
    throw Error("particle filter: a mixture needs one weight per component and at least one component");
  const size_t n = static_cast<size_t>(config_.particles);
  std::vector<size_t> counts(components.size());
  size_t total = 0;
  for (size_t i = 0; i < components.size(); ++i) {
    counts[i] = static_cast<size_t>(std::floor(weights[i] * static_cast<double>(n) + 0.5));
    total += counts[i];
  }
  while (total > n) {  // rounding: take the excess from the largest counts
    const size_t k = static_cast<size_t>(std::max_element(counts.begin(), counts.end()) - counts.begin());
    --counts[k];
    --total;
  }
  counts[static_cast<size_t>(std::max_element(weights.begin(), weights.end()) - weights.begin())] += n - total;
  resizeParticles(n);
  size_t begin = 0;
  for (size_t i = 0; i < components.size(); ++i) {
    drawGaussian(begin, begin + counts[i], components[i].pose, components[i].covariance);
    begin += counts[i];
  }
  finishInitialisation();
}

void ParticleFilter::initialiseUniform() {
  const size_t n = static_cast<size_t>(config_.particles);
  resizeParticles(n);
  const Bounds& b = map_.bounds();
  std::uniform_real_distribution<double> ux(b.xmin, b.xmax), uy(b.ymin, b.ymax), ut(-kPi, kPi);
  for (size_t i = 0; i < n; ++i) {
    const double x = ux(rng_), y = uy(rng_), t = ut(rng_);
    setParticle(i, x, y, t);
  }
  drawCalibration(0, n);
  logw_.assign(n, -std::log(static_cast<double>(n)));
  w_.assign(n, 1.0 / static_cast<double>(n));
  uniform_weights_ = true;
  initialised_ = true;
  gate_.reset();
  summarise(&mean_, &cov_);
  summariseCalibration();
}

void ParticleFilter::resizeParticles(size_t n) {
  x_.resize(n);
  y_.resize(n);
  th_.resize(n);
  c_.resize(n);
  s_.resize(n);
  cal_.resize(n * static_cast<size_t>(cal_dim_));
}

void ParticleFilter::predict(double d_left, double d_right) {
  const OdometryParams params = stepOdometry(d_left, d_right);
  const Eigen::Matrix2d Sv = wheelCovariance(d_left, d_right, params);  // (B.6)
  const double sl = std::sqrt(Sv(0, 0)), sr = std::sqrt(Sv(1, 1));
  const Eigen::Vector3d sf = params.control_variance_floor.cwiseSqrt();
  const double w = odometry_.wheel_base_mm;
  const size_t n = x_.size();
  double* const px = x_.data();
  double* const py = y_.data();
  double* const pt = th_.data();
  double* const pc = c_.data();
  double* const ps = s_.data();
  if (!config_.sample_wheel_increments) {
    const Eigen::Vector3d nominal = controlVector(d_left, d_right, w);  // (B.4), (B.5)
    const Eigen::Matrix3d U = controlCovariance(d_left, d_right, params);  // (B.18), floor included
    const Eigen::LLT<Eigen::Matrix3d> llt(U);
    if (llt.info() != Eigen::Success) throw Error("particle filter: control covariance is not positive definite");
    const Eigen::Matrix3d L = llt.matrixL();
    for (size_t i = 0; i < n; ++i) {
      // Through the particle's own wheel calibration (B.8) when it carries one.
      const double* k = wheels_at_ >= 0 ? wheelsOf(i) : nullptr;
      const Eigen::Vector3d u0 = k ? controlVector(k[0] * d_left, k[1] * d_right, k[2]) : nominal;
      const double a = normal_(rng_), b = normal_(rng_), c3 = normal_(rng_);
      const double ux = u0.x() + L(0, 0) * a;
      const double uy = u0.y() + L(1, 0) * a + L(1, 1) * b;
      const double ut = u0.z() + L(2, 0) * a + L(2, 1) * b + L(2, 2) * c3;
      const double c = pc[i], s = ps[i];  // (B.16), with the cached cos/sin of the heading
      px[i] += c * ux - s * uy;
      py[i] += s * ux + c * uy;
      pt[i] = wrapAngle(pt[i] + ut);
      fast_trig::sinCos(pt[i], &ps[i], &pc[i]);
    }
    walkWheels(d_left, d_right);
    return;
  }
  for (size_t i = 0; i < n; ++i) {
    const double* k = wheels_at_ >= 0 ? wheelsOf(i) : nullptr;
    const double dl = (k ? k[0] : 1.0) * (sl > 0 ? d_left + sl * normal_(rng_) : d_left);
    const double dr = (k ? k[1] : 1.0) * (sr > 0 ? d_right + sr * normal_(rng_) : d_right);
    Eigen::Vector3d u = controlVector(dl, dr, k ? k[2] : w);  // (B.4), (B.5)
    if (sf.x() > 0) u.x() += sf.x() * normal_(rng_);
    if (sf.y() > 0) u.y() += sf.y() * normal_(rng_);
    if (sf.z() > 0) u.z() += sf.z() * normal_(rng_);
    const double c = pc[i], s = ps[i];  // (B.16), with the cached cos/sin of the heading
    px[i] += c * u.x() - s * u.y();
    py[i] += s * u.x() + c * u.y();
    pt[i] = wrapAngle(pt[i] + u.z());
    fast_trig::sinCos(pt[i], &ps[i], &pc[i]);
  }
  walkWheels(d_left, d_right);
}

void ParticleFilter::weight(const std::vector<Observation>& observations, const std::vector<Eigen::Vector2d>& landmarks,
                            const std::optional<double>& compass, double compass_sigma) {
  if (observations.size() != landmarks.size()) throw Error("particle filter: one landmark per observation expected");
  const size_t n = x_.size();
  const double* const px = x_.data();
  const double* const py = y_.data();
  const double* const pc = c_.data();
  const double* const ps = s_.data();
  double* const lw = logw_.data();
  const double log_floor = log_floor_;
  for (size_t k = 0; k < observations.size(); ++k) {
    const Eigen::Matrix2d Ri = observations[k].covariance.inverse();
    const double i00 = Ri(0, 0), i01 = 2.0 * Ri(0, 1), i11 = Ri(1, 1);
    const double zr = observations[k].range, zb = observations[k].bearing;
    const double cz = std::cos(zb), sz = std::sin(zb);
    const double lx = landmarks[k].x(), ly = landmarks[k].y();
    for (size_t i = 0; i < n; ++i) {
      // (5.27) and the wrapped innovation nu = z [-] h(p) without evaluating h's atan2 and a
      // wrap: rotate the landmark offset d = l - t into the frame whose x axis points along the
      // measured bearing, phi = theta + psi_z (cos/sin of phi by the angle-sum identities from
      // the cached heading). The offset's angle there is bearing(h) - psi_z, so
      //   nu_psi = psi_z - bearing(h) = atan2(d x e_phi, d . e_phi)  in (-pi, pi],
      // exactly the wrapped bearing innovation (rangeBearingInnovation).
      const double dx = lx - px[i], dy = ly - py[i];
      const double cphi = pc[i] * cz - ps[i] * sz, sphi = ps[i] * cz + pc[i] * sz;
      const double nb = fast_trig::atan2(sphi * dx - cphi * dy, cphi * dx + sphi * dy);
      const double nr = zr - std::sqrt(dx * dx + dy * dy);
      const double e2 = i00 * nr * nr + i01 * nr * nb + i11 * nb * nb;
      lw[i] += std::max(-0.5 * e2, log_floor);  // (5.34) with a floor
    }
  }
  if (compass) {
    if (!std::isfinite(*compass) || !(std::isfinite(compass_sigma) && compass_sigma > 0))
      throw Error("particle filter: compass heading must be finite and its sigma positive");
    const double inv_var = 1.0 / (compass_sigma * compass_sigma);
    for (size_t i = 0; i < n; ++i) {
      const double nu = angleDiff(*compass, th_[i]);
      lw[i] += std::max(-0.5 * nu * nu * inv_var, log_floor);
    }
  }
  uniform_weights_ = false;
  normalise();
}

namespace {

// One sighting as the linearised optimal proposal reads it: the measured range, the measured
// bearing's cosine and sine, the landmark, R, and the log-determinant of the reference density
// (see proposeAndWeight).
struct ProposalSighting {
  double zr, cz, sz, lx, ly;
  Eigen::Matrix2d R;
  double log_det_ref;
};

// A sighting with the stereo block: the measured columns (u_l, u_r), their covariance, the model
// that predicts them through each particle's calibration, and the reference's log-determinant.
struct ColumnSighting {
  CalibratedColumns model;
  Eigen::Vector2d measured;
  Eigen::Matrix2d C;
  double log_det_ref;
};

// The Kalman step of one two-dimensional sighting on the particle's proposal N(m, P) (the trig of
// m's heading in sm, cm, kept current): innovation nu = z - h(m), H = dh / d pose, noise R;
// returns its log-likelihood relative to the reference peak (log_det_ref: the log-determinant of
// the reference density), or log_floor for an outlier, which moves the particle nowhere.
inline double fuseInnovation(const Eigen::Vector2d& nu, const Matrix23d& H, const Eigen::Matrix2d& R,
                             double log_det_ref, double log_floor, Eigen::Vector3d& m, Eigen::Matrix3d& P, double& sm,
                             double& cm) {
  const Eigen::Matrix<double, 3, 2> PHt = P * H.transpose();
  const Eigen::Matrix2d S = H * PHt + R;
  const double det = S(0, 0) * S(1, 1) - S(0, 1) * S(1, 0);
  if (!(det > 0)) return log_floor;
  Eigen::Matrix2d Si;
  Si << S(1, 1) / det, -S(0, 1) / det, -S(1, 0) / det, S(0, 0) / det;
  const double e2 = nu.dot(Si * nu);
  // log N(nu; 0, S) and the floor, both relative to the reference peak.
  const double log_l = -0.5 * e2 - 0.5 * (std::log(det) - log_det_ref);
  if (log_l <= log_floor) return log_floor;
  const Eigen::Matrix<double, 3, 2> K = PHt * Si;
  m += K * nu;
  P -= K * PHt.transpose();
  P = 0.5 * (P + P.transpose());
  m.z() = wrapAngle(m.z());
  fast_trig::sinCos(m.z(), &sm, &cm);
  return log_l;
}

// A range-bearing sighting's Kalman step (fuseInnovation).
inline double fuseProposalSighting(const ProposalSighting& z, double log_floor, Eigen::Vector3d& m, Eigen::Matrix3d& P,
                                   double& sm, double& cm) {
  const double dx = z.lx - m.x(), dy = z.ly - m.y(), q = dx * dx + dy * dy;
  if (!(q > 1.0)) return log_floor;  // within 1 mm of the landmark: no bearing; the floored likelihood
  const double r = std::sqrt(q);
  // Wrapped bearing innovation in the frame of the measured bearing, as in weight().
  const double cphi = cm * z.cz - sm * z.sz, sphi = sm * z.cz + cm * z.sz;
  const Eigen::Vector2d nu(z.zr - r, fast_trig::atan2(sphi * dx - cphi * dy, cphi * dx + sphi * dy));
  Matrix23d H;  // J_z_pose of predictRangeBearing (5.27) at the particle's prediction
  H << -dx / r, -dy / r, 0.0, dy / q, -dx / q, -1.0;
  return fuseInnovation(nu, H, z.R, z.log_det_ref, log_floor, m, P, sm, cm);
}

// A column sighting's Kalman step (fuseInnovation), seen through the particle's calibration q.
inline double fuseColumnSighting(const ColumnSighting& z, const CalibrationEstimate::StereoVector& q, double log_floor,
                                 Eigen::Vector3d& m, Eigen::Matrix3d& P, double& sm, double& cm) {
  Eigen::Vector2d h;
  Matrix23d H;
  if (!z.model(q, m.x(), m.y(), cm, sm, &h, &H)) return log_floor;  // behind the cameras
  return fuseInnovation(z.measured - h, H, z.C, z.log_det_ref, log_floor, m, P, sm, cm);
}

// The compass's Kalman step on N(m, P), as fuseProposalSighting; compass_ref: the variance of
// the reference density.
inline double fuseProposalCompass(double compass, double compass_var, double compass_ref, double log_floor,
                                  Eigen::Vector3d& m, Eigen::Matrix3d& P) {
  const double nu = angleDiff(compass, m.z());
  const double S = P(2, 2) + compass_var;
  const double log_l = -0.5 * nu * nu / S - 0.5 * std::log(S / compass_ref);
  if (log_l <= log_floor) return log_floor;
  const Eigen::Vector3d K = P.col(2) / S;
  m += K * nu;
  P -= K * K.transpose() * S;
  P = 0.5 * (P + P.transpose());
  m.z() = wrapAngle(m.z());
  return log_l;
}

// The lower Cholesky factor of a 3x3 covariance that is positive definite up to round-off
// (a negative pivot reads as zero).
inline Eigen::Matrix3d lowerFactor(const Eigen::Matrix3d& P) {
  Eigen::Matrix3d L = Eigen::Matrix3d::Zero();
  const double l00 = std::sqrt(std::max(P(0, 0), 0.0));
  L(0, 0) = l00;
  L(1, 0) = l00 > 0 ? P(1, 0) / l00 : 0.0;
  L(2, 0) = l00 > 0 ? P(2, 0) / l00 : 0.0;
  const double l11 = std::sqrt(std::max(P(1, 1) - L(1, 0) * L(1, 0), 0.0));
  L(1, 1) = l11;
  L(2, 1) = l11 > 0 ? (P(2, 1) - L(2, 0) * L(1, 0)) / l11 : 0.0;
  L(2, 2) = std::sqrt(std::max(P(2, 2) - L(2, 0) * L(2, 0) - L(2, 1) * L(2, 1), 0.0));
  return L;
}

}  // namespace

void ParticleFilter::proposeAndWeight(const std::optional<Eigen::Vector2d>& wheels,
                                      const std::vector<Observation>& observations,
                                      const std::vector<Eigen::Vector2d>& landmarks, const std::optional<double>& compass,
                                      double compass_sigma, const ParticleProposalKernel& kernel_config) {
  if (observations.size() != landmarks.size()) throw Error("particle filter: one landmark per observation expected");
  if (compass && (!std::isfinite(*compass) || !(std::isfinite(compass_sigma) && compass_sigma > 0)))
    throw Error("particle filter: compass heading must be finite and its sigma positive");
  const Eigen::Vector3d nominal_u = wheels ? controlVector(wheels->x(), wheels->y(), odometry_.wheel_base_mm)  // (B.4), (B.5)
                                           : Eigen::Vector3d::Zero();
  const Eigen::Matrix3d U = wheels ? controlCovariance(wheels->x(), wheels->y(), stepOdometry(wheels->x(), wheels->y()))  // (B.18), floor included
                                   : Eigen::Matrix3d::Zero();
  const double h = kernel_config.h;
  const Pose2& centre = kernel_config.centre;
  const Eigen::Matrix3d& spread = kernel_config.spread;
  const bool kernel = h > 0 && h < 1;
  const double shrink = kernel ? std::sqrt(1.0 - h * h) : 1.0;
  const Eigen::Matrix3d kernel_cov = kernel ? Eigen::Matrix3d(h * h * 0.5 * (spread + spread.transpose()))
                                            : Eigen::Matrix3d::Zero();
  // The likelihood floor is a density common to all particles: f times the peak of the kernel's
  // predictive density H h^2 C H^T + R at the set's mean (R alone without a kernel, as in
  // weight()). Relative to each particle's own peak it would favour the narrow, re-injected
  // particles over the kernel-widened ones wherever both are outliers.
  std::vector<ProposalSighting> sightings;
  std::vector<ColumnSighting> column_sightings;
  sightings.reserve(observations.size());
  for (size_t k = 0; k < observations.size(); ++k) {
    const Observation& o = observations[k];
    if (head_at_ >= 0) {
      // With the stereo block each particle predicts the columns (u_l, u_r) of the landmark
      // through its own calibration, as the self-calibrating EKF updates on them: the rows,
      // which carry the vibration's pitch, are not read, and the landmark's height is the map's.
      const Landmark& lm = map_.at(o.landmark_id);
      const Eigen::Matrix4d C_px = pixelCovarianceFor(o, lm, config_.observation_model);
      Eigen::Matrix2d C;
      C << C_px(0, 0), C_px(0, 2), C_px(2, 0), C_px(2, 2);
      ColumnSighting z{CalibratedColumns(config_.observation_model.rig, lm.position, o.head_pan),
                       Eigen::Vector2d(o.pixels->u_left, o.pixels->u_right), C, std::log(C.determinant())};
      Eigen::Vector2d u_centre;
      Eigen::Matrix<double, 2, 3> Hc;
      if (kernel && z.model(cal_mean_.segment<6>(head_at_), centre.x, centre.y, std::cos(centre.theta),
                            std::sin(centre.theta), &u_centre, &Hc))
        z.log_det_ref = std::log((C + Hc * kernel_cov * Hc.transpose()).determinant());
      column_sightings.push_back(z);
      continue;
    }
    Eigen::Matrix2d ref = o.covariance;
    if (kernel) {
      try {
        Matrix23d Hc;
        predictRangeBearing(centre, landmarks[k], &Hc);
        ref += Hc * kernel_cov * Hc.transpose();
      } catch (const GeometryError&) {
        // the set's mean on the landmark: no bearing there; R alone
      }
    }
    sightings.push_back({o.range, std::cos(o.bearing), std::sin(o.bearing), landmarks[k].x(), landmarks[k].y(),
                         o.covariance, std::log(ref.determinant())});
  }
  const double compass_var = compass ? compass_sigma * compass_sigma : 0.0;
  const double compass_ref = compass_var + kernel_cov(2, 2);
  const double log_floor = log_floor_;
  const size_t n = x_.size();
  // Particles just re-injected uniformly are no draws from the set: no kernel for them.
  std::vector<char> no_kernel(n, 0);
  for (int i : fresh_)
    if (static_cast<size_t>(i) < n) no_kernel[static_cast<size_t>(i)] = 1;
  fresh_.clear();
  for (size_t i = 0; i < n; ++i) {
    // One step's prediction of this particle (B.16): u ~ N(u0, U) enters linearly given the
    // heading, so x_pred ~ N(x (+) u0, G U G^T) exactly, G = blockdiag(rotation(theta), 1).
    const double c0 = c_[i], s0 = s_[i];
    const double* kw = wheels && wheels_at_ >= 0 ? wheelsOf(i) : nullptr;  // the particle's wheels (B.8)
    const Eigen::Vector3d u0 = kw ? controlVector(kw[0] * wheels->x(), kw[1] * wheels->y(), kw[2]) : nominal_u;
    Eigen::Vector3d m(x_[i] + c0 * u0.x() - s0 * u0.y(), y_[i] + s0 * u0.x() + c0 * u0.y(), th_[i] + u0.z());
    Eigen::Matrix3d G;
    G << c0, -s0, 0, s0, c0, 0, 0, 0, 1;
    Eigen::Matrix3d P = G * U * G.transpose();
    if (kernel && !no_kernel[i]) {
      m = Eigen::Vector3d(centre.x + shrink * (m.x() - centre.x), centre.y + shrink * (m.y() - centre.y),
                          centre.theta + shrink * angleDiff(m.z(), centre.theta));
      P += kernel_cov;
    }
    double cm = 0, sm = 0;
    fast_trig::sinCos(m.z(), &sm, &cm);
    double lw = 0.0;
    for (const ProposalSighting& z : sightings) lw += fuseProposalSighting(z, log_floor, m, P, sm, cm);
    if (!column_sightings.empty()) {
      const CalibrationEstimate::StereoVector q =
          Eigen::Map<const CalibrationEstimate::StereoVector>(cal_.data() + i * static_cast<size_t>(cal_dim_) + head_at_);
      for (const ColumnSighting& z : column_sightings) lw += fuseColumnSighting(z, q, log_floor, m, P, sm, cm);
    }
    if (compass) lw += fuseProposalCompass(*compass, compass_var, compass_ref, log_floor, m, P);
    // Draw from N(m, P); P is positive definite (U holds a floor) up to round-off.
    const Eigen::Matrix3d L = lowerFactor(P);
    const double a = normal_(rng_), b = normal_(rng_), c3 = normal_(rng_);
    setParticle(i, m.x() + L(0, 0) * a, m.y() + L(1, 0) * a + L(1, 1) * b,
                wrapAngle(m.z() + L(2, 0) * a + L(2, 1) * b + L(2, 2) * c3));
    logw_[i] += lw;
  }
  if (wheels) walkWheels(wheels->x(), wheels->y());
  uniform_weights_ = false;
  normalise();
}

void ParticleFilter::normalise() {
  // (5.35), (5.36) in the log domain: w = exp(log w - max) / sum.
  const double m = *std::max_element(logw_.begin(), logw_.end());
  double sum = 0.0;
  for (size_t i = 0; i < logw_.size(); ++i) sum += (w_[i] = std::exp(logw_[i] - m));
  const double log_sum = std::log(sum) + m;
  for (size_t i = 0; i < logw_.size(); ++i) {
    w_[i] /= sum;
    logw_[i] -= log_sum;
  }
}

double ParticleFilter::effectiveSampleSize() const {
  double s = 0.0;
  for (double w : w_) s += w * w;
  return s > 0 ? 1.0 / s : 0.0;
}

int kldSampleSize(int bins, double epsilon, double quantile) {
  if (bins < 2) return 1;
  // Fox (2003), eq. (12): the Wilson-Hilferty approximation of chi^2_(k-1, 1-delta) / (2 epsilon).
  const double k1 = bins - 1.0, a = 2.0 / (9.0 * k1);
  const double z = std::sqrt(chi2Quantile(2.0 * quantile - 1.0, 1));  // upper 1 - delta quantile of N(0, 1)
  const double c = 1.0 - a + std::sqrt(a) * z;
  const double n = k1 / (2.0 * epsilon) * c * c * c;
  return n >= std::numeric_limits<int>::max() ? std::numeric_limits<int>::max() : static_cast<int>(std::ceil(n));
}

void ParticleFilter::resample() {
  const int n = config_.kld.enabled ? config_.particles : size();
  std::vector<int>& idx = resample_index_;  // (5.38)
  if (config_.resampling == ResamplingScheme::Systematic) {
    systematicResampleInto(w_, n, rng_, idx);
  } else {
    idx = sortedRouletteResample(w_, n, rng_);
  }
  if (config_.kld.enabled) {
    // KLD-sampling: take the N_max draws in random order (a uniform subset of a resampled set
    // is a resampled set) until their count reaches n(k) of the bins they occupy.
    const KldSamplingConfig& kc = config_.kld;
    for (size_t i = idx.size(); i > 1; --i) {
      const size_t j = static_cast<size_t>(std::uniform_int_distribution<size_t>(0, i - 1)(rng_));
      std::swap(idx[i - 1], idx[j]);
    }
    std::unordered_set<uint64_t> bins;
    int needed = kc.min_particles;
    size_t taken = 0;
    for (; taken < idx.size(); ++taken) {
      if (static_cast<int>(taken) >= needed) break;
      const size_t j = static_cast<size_t>(idx[taken]);
      const auto cell = [](double v, double width) { return static_cast<uint64_t>(static_cast<int64_t>(std::floor(v / width)) & 0x1fffff); };
      const uint64_t key = cell(x_[j], kc.bin_xy_mm) << 42 | cell(y_[j], kc.bin_xy_mm) << 21 |
                           cell(th_[j] + kPi, kc.bin_theta_rad);
      if (bins.insert(key).second) needed = std::max(kc.min_particles, kldSampleSize(static_cast<int>(bins.size()), kc.epsilon, kc.quantile));
    }
    idx.resize(taken);
  }
  const int kept = static_cast<int>(idx.size());
  // The new set may be larger than the old one (KLD-sampling growing back): sized to it first.
  const size_t K = static_cast<size_t>(cal_dim_);
  scratch_x_.resize(idx.size());
  scratch_y_.resize(idx.size());
  scratch_th_.resize(idx.size());
  scratch_c_.resize(idx.size());
  scratch_s_.resize(idx.size());
  scratch_cal_.resize(idx.size() * K);
  for (size_t i = 0; i < idx.size(); ++i) {
    const size_t j = static_cast<size_t>(idx[i]);
    std::copy_n(cal_.data() + j * K, K, scratch_cal_.data() + i * K);
    scratch_x_[i] = x_[j];
    scratch_y_[i] = y_[j];
    scratch_th_[i] = th_[j];
    scratch_c_[i] = c_[j];
    scratch_s_[i] = s_[j];
  }
  x_.swap(scratch_x_);
  y_.swap(scratch_y_);
  th_.swap(scratch_th_);
  c_.swap(scratch_c_);
  s_.swap(scratch_s_);
  cal_.swap(scratch_cal_);
  logw_.assign(x_.size(), -std::log(static_cast<double>(kept)));
  w_.assign(x_.size(), 1.0 / kept);
  uniform_weights_ = true;
}

void ParticleFilter::regularise(const Pose2& mean, const Eigen::Matrix3d& covariance, double h) {
  if (!(h > 0 && h < 1)) return;
  Eigen::LLT<Eigen::Matrix3d> llt(0.5 * (covariance + covariance.transpose()));
  if (llt.info() != Eigen::Success || !covariance.allFinite()) return;  // a degenerate set: nothing to scale by
  const Eigen::Matrix3d L = h * Eigen::Matrix3d(llt.matrixL());
  // Kernel shrinkage (Liu and West, 2001): pulling each particle towards the mean by
  // a = sqrt(1 - h^2) before adding the kernel keeps the mean and the covariance of the set;
  // the plain kernel would inflate the covariance by (1 + h^2) at every resampling and, through
  // the next bandwidth, feed on itself.
  const double a = config_.regularisation_shrinkage ? std::sqrt(1.0 - h * h) : 1.0;
  for (size_t i = 0; i < x_.size(); ++i) {
    const Eigen::Vector3d e(normal_(rng_), normal_(rng_), normal_(rng_));
    const Eigen::Vector3d d = L * e;
    setParticle(i, mean.x + a * (x_[i] - mean.x) + d.x(), mean.y + a * (y_[i] - mean.y) + d.y(),
                wrapAngle(mean.theta + a * angleDiff(th_[i], mean.theta) + d.z()));
  }
}

void ParticleFilter::reinject(int count) {
  // Replaces `count` particles spread evenly over the set (after resampling they are in
  // random order only for the roulette, so a stride keeps the choice independent of weight).
  const int n = size();
  // With KLD-sampling the set shrinks; the re-injected share stays count / particles.
  if (config_.kld.enabled && count > 0 && n < config_.particles)
    count = std::max(1, static_cast<int>(std::lround(static_cast<double>(count) * n / config_.particles)));
  if (count <= 0 || n == 0) return;
  const Bounds& b = map_.bounds();
  std::uniform_real_distribution<double> ux(b.xmin, b.xmax), uy(b.ymin, b.ymax), ut(-kPi, kPi);
  std::uniform_int_distribution<int> offset(0, n - 1);
  const int start = offset(rng_);
  const double stride = static_cast<double>(n) / count;
  for (int k = 0; k < count; ++k) {
    const size_t i = static_cast<size_t>((start + static_cast<int>(k * stride)) % n);
    const double x = ux(rng_), y = uy(rng_), t = ut(rng_);
    setParticle(i, x, y, t);
    drawCalibration(i, i + 1);  // from the set's calibration: a kidnap does not change the robot
    logw_[i] = -std::log(static_cast<double>(n));  // Algorithm 6: a new particle weighs 1/N
    fresh_.push_back(static_cast<int>(i));
  }
  if (!uniform_weights_) normalise();  // after resampling every weight is 1/N already
}

void ParticleFilter::summarise(Pose2* mean, Eigen::Matrix3d* covariance) const {
  double sx = 0, sy = 0, ss = 0, sc = 0;
  for (size_t i = 0; i < x_.size(); ++i) {
    sx += w_[i] * x_[i];
    sy += w_[i] * y_[i];
    ss += w_[i] * s_[i];
    sc += w_[i] * c_[i];
  }
  // Circular mean; when the headings cancel exactly, any heading is as good as another.
  const double mt = (ss == 0.0 && sc == 0.0) ? 0.0 : std::atan2(ss, sc);
  Eigen::Matrix3d C = Eigen::Matrix3d::Zero();
  for (size_t i = 0; i < x_.size(); ++i) {
    const Eigen::Vector3d d(x_[i] - sx, y_[i] - sy, angleDiff(th_[i], mt));
    C.noalias() += w_[i] * d * d.transpose();
  }
  *mean = Pose2(sx, sy, mt);
  *covariance = 0.5 * (C + C.transpose());
}

ParticleFilter::State ParticleFilter::saveState() const {
  State s;
  saveState(s);
  return s;
}

void ParticleFilter::saveState(State& s) const {
  s.rng = rng_;
  s.normal = normal_;
  s.gate = gate_;
  s.x = x_;
  s.y = y_;
  s.th = th_;
  s.c = c_;
  s.s = s_;
  s.logw = logw_;
  s.w = w_;
  s.cal = cal_;
  s.cal_mean = cal_mean_;
  s.cal_cov = cal_cov_;
  s.joint_cov = joint_cov_;
  s.fresh = fresh_;
  s.uniform_weights = uniform_weights_;
  s.initialised = initialised_;
  s.have_step = have_step_;
  s.localised = localised_;
  s.last_step = last_step_;
  s.mean = mean_;
  s.cov = cov_;
  s.hypotheses = bank_.hypotheses();
  s.estimates = estimates_.size();
}

void ParticleFilter::restoreState(const State& s) {
  rng_ = s.rng;
  normal_ = s.normal;
  gate_ = s.gate;
  x_ = s.x;
  y_ = s.y;
  th_ = s.th;
  c_ = s.c;
  s_ = s.s;
  logw_ = s.logw;
  w_ = s.w;
  cal_ = s.cal;
  cal_mean_ = s.cal_mean;
  cal_cov_ = s.cal_cov;
  joint_cov_ = s.joint_cov;
  fresh_ = s.fresh;
  uniform_weights_ = s.uniform_weights;
  initialised_ = s.initialised;
  have_step_ = s.have_step;
  localised_ = s.localised;
  last_step_ = s.last_step;
  mean_ = s.mean;
  cov_ = s.cov;
  bank_.restore(s.hypotheses);
  if (config_.keep_history && estimates_.size() > s.estimates) estimates_.resize(s.estimates);
}

bool ParticleFilter::tryGlobalFix(const Step& step) {
  if (!config_.global_fix) return false;
  const std::optional<PoseFix> fix = config_.global_fix(seenThroughCalibration(step), map_);
  if (!fix || !fix->pose.isFinite() || !fix->covariance.allFinite()) return false;
  try {
    initialiseGaussian(fix->pose, fix->covariance);
  } catch (const Error&) {
    return false;  // a fix with an unusable covariance is no fix
  }
  return true;
}

Estimate ParticleFilter::process(const Step& step) {
  validateStep(step);
  const bool first = !have_step_;
  have_step_ = true;
  last_step_ = step.step;
  if (!initialised_)
    return recordEstimate(step, tryGlobalFix(step) ? EstimateStatus::Reinitialised : EstimateStatus::Uninitialised);
  if (const std::optional<EstimateStatus> status = startFromWideBelief(step, first)) return recordEstimate(step, *status);
  // The optimal proposal predicts and corrects in one pass once the observations are known.
  const bool optimal = config_.proposal == ParticleProposal::LinearisedOptimal;
  if (!first && !optimal) predict(step.d_left, step.d_right);
  StepObservations used = identifyObservations(step, first);
  const std::optional<PoseFix> anchor = used.lost ? reanchoringFix(step, used) : std::nullopt;
  if (optimal && (!used.lost || anchor)) {
    // An observation outside the belief's gate is floored for the whole set, so the re-injected
    // particles would weigh as much as the set's and smear the estimate over the field. While
    // not lost it is dropped; once lost, every observation goes to the particles so that the
    // re-injected ones that fit can take over (5.1.3).
    size_t kept = 0;
    for (size_t k = 0; k < used.observations.size(); ++k) {
      if (!used.accepted[k]) continue;
      used.observations[kept] = used.observations[k];
      used.landmarks[kept] = used.landmarks[k];
      ++kept;
    }
    used.observations.resize(kept);
    used.landmarks.resize(kept);
    used.accepted.assign(kept, 1);
  }
  if (used.lost && !anchor && tryGlobalFix(step)) return recordEstimate(step, EstimateStatus::Reinitialised);
  const bool use_compass = step.compass && config_.use_compass;
  const bool observed = !used.observations.empty() || use_compass;
  correct(step, first, used, use_compass);
  if (anchor) weightByFix(*anchor);
  summarise(&mean_, &cov_);  // (5.37), before resampling: the weighted set is the posterior
  summariseCalibration();
  if (observed || anchor) {
    resampleIfDegenerate();
    if (!optimal) reinject(config_.reinjected);
  }
  fresh_.clear();
  if (anchor) {
    gate_.reset();
    return recordEstimate(step, EstimateStatus::Reinitialised);
  }
  if (used.lost) return recordEstimate(step, EstimateStatus::Lost);
  return recordEstimate(step, observed ? EstimateStatus::Tracking : EstimateStatus::Predicted);
}

void ParticleFilter::validateStep(const Step& step) const {
  if (have_step_ && step.step <= last_step_)
    throw Error("particle filter: step " + std::to_string(step.step) + " does not follow step " +
                std::to_string(last_step_));
  validateStepOdometryAndCompass(step, "particle filter: step " + std::to_string(step.step));
  for (size_t i = 0; i < step.observations.size(); ++i) {
    checkObservation(step, i, step.observations[i]);
    if (head_at_ >= 0 && !step.observations[i].pixels)
      throw Error("particle filter: " + where(step, i) + ": the stereo calibration needs the sighting's pixels");
  }
}

Estimate ParticleFilter::recordEstimate(const Step& step, EstimateStatus status) {
  Estimate e = stepEstimate(step, mean_, initialised_ ? cov_ : Eigen::Matrix3d::Zero(), status);
  e.particles = initialised_ ? size() : 0;
  if (!config_.keep_history) estimates_.clear();
  estimates_.push_back(e);
  return e;
}

namespace {

double positionSpread(const Eigen::Matrix3d& P) { return std::sqrt(std::max(P(0, 0), P(1, 1))); }

}  // namespace

// While the belief is wider than the hand-over sigma: a global fix narrower than the belief
// takes over, or before the filter first localised, the bank of hypotheses (5.1.4). Returns the
// step's status when one of them decided the step.
std::optional<EstimateStatus> ParticleFilter::startFromWideBelief(const Step& step, bool first) {
  const bool wide = config_.handover_sigma_mm > 0 && positionSpread(cov_) > config_.handover_sigma_mm;
  if (wide && !step.observations.empty() && config_.global_fix) {
    const std::optional<PoseFix> fix = config_.global_fix(seenThroughCalibration(step), map_);
    if (fix && fix->pose.isFinite() && fix->covariance.allFinite() && positionSpread(fix->covariance) < positionSpread(cov_)) {
      try {
        initialiseGaussian(fix->pose, fix->covariance);
        bank_.clear();
        return EstimateStatus::Reinitialised;
      } catch (const Error&) {
        // a fix with an unusable covariance is no fix: go on with the set
      }
    }
  }
  // The bank only serves a wide start: once localised, a filter that widens again (a stretch
  // without sightings, a few stray particles) still carries its own belief, which a bank built
  // from one ambiguous sighting would throw away.
  if (!wide) localised_ = true;
  if (wide && !localised_ && config_.multi_hypothesis_start) {
    bank_.process(step, first);
    if (!bank_.empty()) {
      const PoseFix m = bank_.mixture();
      if (positionSpread(m.covariance) > config_.handover_sigma_mm) {
        // The set stays as it is (a uniform set is unchanged by the motion); the estimate is the
        // mixture's.
        mean_ = m.pose;
        cov_ = m.covariance;
        return step.observations.empty() ? EstimateStatus::Predicted : EstimateStatus::Tracking;
      }
      initialiseMixture(bank_.hypotheses(), bank_.weights());
      bank_.clear();
      return EstimateStatus::Reinitialised;
    }
  }
  return std::nullopt;
}

// Identifies the observations; unidentified ones are associated with the predicted estimate
// (the previous summary pushed through the odometry model, as the EKF would predict it), and
// each is tested against the summary's gate (5.20): status only, the likelihood floor handles
// outliers.
ParticleFilter::StepObservations ParticleFilter::identifyObservations(const Step& step, bool first) {
  PosePrediction prior{mean_, cov_};
  if (!first && wheels_at_ >= 0) {
    prior = predictCalibratedStep(mean_, cov_, step.d_left, step.d_right, cal_mean_.segment<3>(wheels_at_),
                                  stepOdometry(step.d_left, step.d_right));
  } else if (!first) {
    prior = predictPose(mean_, cov_, step.d_left, step.d_right, stepOdometry(step.d_left, step.d_right));
  }
  StepObservations used;
  used.predicted = prior.pose;
  used.predicted_covariance = prior.covariance;
  std::vector<int> taken;
  for (const Observation& o : step.observations)
    if (o.landmark_id >= 0) taken.push_back(o.landmark_id);
  int tested = 0;
  for (size_t i = 0; i < step.observations.size(); ++i) {
    const Observation& obs = step.observations[i];
    const Landmark* lm = nullptr;
    if (obs.landmark_id >= 0) {
      lm = map_.find(obs.landmark_id);
      if (!lm) throw Error(where(step, i) + ": unknown landmark id " + std::to_string(obs.landmark_id));
    }
    // With the stereo block the gate and the association see the sighting through the set's
    // calibration; one that puts the pixels at no point there is neither.
    std::optional<Observation> seen = obs;
    if (head_at_ >= 0) {
      Landmark kind;
      kind.type = obs.type;
      try {
        seen = calibratedForGate(obs, lm ? *lm : kind);
      } catch (const GeometryError&) {
        seen.reset();
      }
    }
    if (!lm && seen) {
      const AssociationResult a = associate(*seen, prior.pose, prior.covariance, map_, config_.association,
                                            config_.association.exclusive ? taken : std::vector<int>{});
      if (a.landmark_id >= 0) {
        lm = &map_.at(a.landmark_id);
        taken.push_back(a.landmark_id);
      }
    }
    ++tested;
    if (!lm) {
      gate_.record(false);
      continue;
    }
    Matrix23d H;
    bool accepted = false;
    try {
      if (seen) {
        const Eigen::Vector2d zhat = predictRangeBearing(prior.pose, lm->xy(), &H);
        const Eigen::Vector2d nu = rangeBearingInnovation(seen->z(), zhat);
        accepted = gate_.accepts(mahalanobisSquared<2>(nu, H * prior.covariance * H.transpose() + seen->covariance));
      }
    } catch (const GeometryError&) {
      accepted = false;
    }
    gate_.record(accepted);
    Observation identified = obs;
    identified.landmark_id = lm->id;
    used.observations.push_back(identified);
    used.landmarks.push_back(lm->xy());
    used.accepted.push_back(accepted ? 1 : 0);
  }
  used.lost = tested > 0 && gate_.consecutiveRejections() >= config_.gate.lost_after;
  return used;
}

// Weights the set by the step's observations and compass: with the optimal proposal, which also
// moves the particles (re-injecting first), or by the likelihood after the prior's prediction.
void ParticleFilter::correct(const Step& step, bool first, const StepObservations& used, bool use_compass) {
  const bool optimal = config_.proposal == ParticleProposal::LinearisedOptimal;
  const bool observed = !used.observations.empty() || use_compass;
  const std::optional<double> compass = use_compass ? step.compass : std::nullopt;
  if (observed && optimal) {
    // Re-injection before the proposal: the new particles are weighted by this step's
    // observations at once, so that unweighted uniform particles never enter the estimate. Not
    // on compass-only steps: a heading says nothing about where the robot is, so the new
    // particles with the right heading would weigh as much as the set's.
    if (!used.observations.empty()) reinject(config_.reinjected);
    // The kernel's spread: the previous posterior's covariance (one step of transport changes a
    // kernel negligibly), used only while the set is one cluster.
    const double sp = positionSpread(cov_), st = std::sqrt(cov_(2, 2));
    double h = 0.0;
    if (sp < config_.proposal_kernel_max_sigma_mm && st < config_.proposal_kernel_max_sigma_theta)
      h = config_.proposal_kernel_bandwidth >= 0 ? config_.proposal_kernel_bandwidth
                                                 : std::pow(4.0 / (size() * 5.0), 1.0 / 7.0);
    const std::optional<Eigen::Vector2d> wheels =
        first ? std::nullopt : std::optional<Eigen::Vector2d>(Eigen::Vector2d(step.d_left, step.d_right));
    proposeAndWeight(wheels, used.observations, used.landmarks, compass, step.compass_sigma, {h, used.predicted, cov_});
  } else {
    if (optimal && !first) predict(step.d_left, step.d_right);
    if (observed) weight(used.observations, used.landmarks, compass, step.compass_sigma);
  }
}

// Resamples when the effective sample size has fallen below its fraction of the set, and
// regularises when it has fallen further.
void ParticleFilter::resampleIfDegenerate() {
  const double ess = effectiveSampleSize();
  if (ess >= config_.resample_ess_fraction * size() + 1e-9) return;
  resample();
  jitterCalibration();
  if (ess < config_.regularisation_ess_fraction * size()) {
    const double d = 3.0;
    const double h = config_.regularisation_bandwidth >= 0 ? config_.regularisation_bandwidth
                                                           : std::pow(4.0 / (size() * (d + 2.0)), 1.0 / (d + 4.0));
    regularise(mean_, cov_, h);
  }
}

}  // namespace stereoloc
