#include "solvers/smoother_common.h"

#include <Eigen/Cholesky>
#include <Eigen/LU>
#include <Eigen/Eigenvalues>
#include <limits>
#include <cmath>

#include <algorithm>
#include <random>
#include <utility>

#include "factors/range_bearing_factor.h"
#include "factors/stereo_pixel_factor.h"
#include "src/core/angles.h"
#include "src/core/error.h"
#include "src/core/measurement_model.h"
#include "src/core/yaml_util.h"

namespace stereoloc {
namespace {

// The measurement model (5.27); a landmark under the robot is reported at range 0 (never seen).
Eigen::Vector2d predictRangeBearingNoThrow(const Pose2& pose, const Eigen::Vector2d& landmark) {
  try {
    return predictRangeBearing(pose, landmark);
  } catch (const GeometryError&) {
    return Eigen::Vector2d::Zero();
  }
}

}  // namespace

std::string toString(RobustLoss loss) {
  switch (loss) {
    case RobustLoss::None: return "none";
    case RobustLoss::Huber: return "huber";
    case RobustLoss::Cauchy: return "cauchy";
  }
  return "none";
}

RobustLoss robustLossFromString(const std::string& name) {
  for (RobustLoss l : {RobustLoss::None, RobustLoss::Huber, RobustLoss::Cauchy})
    if (toString(l) == name) return l;
  throw Error("unknown robust loss '" + name + "' (expected none, huber or cauchy)");
}

std::string toString(ObservationModel model) {
  switch (model) {
    case ObservationModel::RangeBearing: return "range_bearing";
    case ObservationModel::PixelColumns: return "pixel_columns";
    case ObservationModel::Pixels: return "pixels";
  }
  return "range_bearing";
}

ObservationModel observationModelFromString(const std::string& name) {
  for (ObservationModel m : {ObservationModel::RangeBearing, ObservationModel::PixelColumns, ObservationModel::Pixels})
    if (toString(m) == name) return m;
  throw Error("unknown observation model '" + name + "' (expected range_bearing, pixel_columns or pixels)");
}


namespace {
const std::pair<const char*, double UnmodelledNoise::*> kNoiseKeys[] = {
    {"k1_sigma", &UnmodelledNoise::k1_sigma},
    {"k2_sigma", &UnmodelledNoise::k2_sigma},
    {"tangential_sigma", &UnmodelledNoise::tangential_sigma},
    {"pitch_sigma_rad", &UnmodelledNoise::pitch_sigma_rad},
    {"roll_sigma_rad", &UnmodelledNoise::roll_sigma_rad},
    {"relative_rotation_sigma_rad", &UnmodelledNoise::relative_rotation_sigma_rad},
    {"marking_disparity_sigma_px", &UnmodelledNoise::marking_disparity_sigma_px},
    {"intersection_disparity_sigma_px", &UnmodelledNoise::intersection_disparity_sigma_px},
    {"row_offset_sigma_px", &UnmodelledNoise::row_offset_sigma_px},
    {"marking_slide_residual_sigma_px", &UnmodelledNoise::marking_slide_residual_sigma_px},
    {"marking_slide_residual_per_gain_px", &UnmodelledNoise::marking_slide_residual_per_gain_px},
    {"marking_feature_offset_sigma_px", &UnmodelledNoise::marking_feature_offset_sigma_px},
    {"intersection_slide_residual_sigma_px", &UnmodelledNoise::intersection_slide_residual_sigma_px},
    {"intersection_feature_offset_sigma_px", &UnmodelledNoise::intersection_feature_offset_sigma_px},
    {"goal_feature_column_sigma_px", &UnmodelledNoise::goal_feature_column_sigma_px},
    {"marking_feature_column_sigma_px", &UnmodelledNoise::marking_feature_column_sigma_px},
    {"intersection_feature_column_sigma_px", &UnmodelledNoise::intersection_feature_column_sigma_px},
    {"slip_rel_sigma", &UnmodelledNoise::slip_rel_sigma},
    {"exposure_offset_sigma_s", &UnmodelledNoise::exposure_offset_sigma_s},
    {"wheel_scale_drift", &UnmodelledNoise::wheel_scale_drift},
    {"wheel_base_drift", &UnmodelledNoise::wheel_base_drift},
};
}  // namespace

bool UnmodelledNoise::isZero() const {
  for (const auto& [key, field] : kNoiseKeys)
    if (this->*field != 0) return false;
  return true;
}

void UnmodelledNoise::validate() const {
  for (const auto& [key, field] : kNoiseKeys)
    if (!(std::isfinite(this->*field) && this->*field >= 0))
      throw Error(std::string("noise model: ") + key + " must be a finite number >= 0");
}

UnmodelledNoise UnmodelledNoise::load(const std::string& path) {
  const YamlReader in(path);
  UnmodelledNoise n;
  for (const auto& [key, field] : kNoiseKeys) {
    n.*field = in.getDouble(key, 0.0);
    if (!(n.*field >= 0)) in.fail(key, "must be >= 0");
  }
  return n;
}

void UnmodelledNoise::save(const std::string& path) const {
  validate();
  YamlWriter w;
  w.comment("stereoloc noise model (solvers/smoother_common.h UnmodelledNoise); rad, fractions");
  for (const auto& [key, field] : kNoiseKeys) w.put(key, this->*field);
  w.writeAtomically(path);
}

Eigen::Matrix4d unmodelledPixelCovariance(const StereoRig& rig, const StereoPixels& px, const UnmodelledNoise& noise) {
  const double f = rig.focal(), ou = rig.principalU(), ov = rig.principalV();
  Eigen::Matrix4d C = Eigen::Matrix4d::Zero();
  Eigen::Matrix<double, 4, 2> J_vib;  // d(u_l, v_l, u_r, v_r) / d(pitch, roll)
  const double u[2] = {px.u_left, px.u_right}, v[2] = {px.v_left, px.v_right};
  for (int c = 0; c < 2; ++c) {
    // Normalised coordinates of the (rectified ~ undistorted) point; OpenCV's distortion model
    // x' = x (1 + k1 r^2 + k2 r^4) + 2 p1 x y + p2 (r^2 + 2 x^2), y' likewise with p1, p2 swapped.
    const double x = (u[c] - ou) / f, y = (v[c] - ov) / f, r2 = x * x + y * y;
    Eigen::Matrix<double, 2, 4> J_lens;  // d(u, v) / d(k1, k2, p1, p2)
    J_lens << f * x * r2, f * x * r2 * r2, f * 2 * x * y, f * (r2 + 2 * x * x),  //
        f * y * r2, f * y * r2 * r2, f * (r2 + 2 * y * y), f * 2 * x * y;
    const Eigen::Vector4d var(noise.k1_sigma * noise.k1_sigma, noise.k2_sigma * noise.k2_sigma,
                              noise.tangential_sigma * noise.tangential_sigma,
                              noise.tangential_sigma * noise.tangential_sigma);
    C.block<2, 2>(2 * c, 2 * c) += J_lens * var.asDiagonal() * J_lens.transpose();
    // A small rotation of the camera: pitch about its x axis moves (u, v) by f (x y, 1 + y^2),
    // roll about its optical axis by f (-y, x); the pair shares them (one head).
    J_vib.row(2 * c) << f * x * y, -f * y;
    J_vib.row(2 * c + 1) << f * (1 + y * y), f * x;
  }
  const Eigen::Vector2d vib(noise.pitch_sigma_rad * noise.pitch_sigma_rad, noise.roll_sigma_rad * noise.roll_sigma_rad);
  C += J_vib * vib.asDiagonal() * J_vib.transpose();
  if (noise.relative_rotation_sigma_rad > 0) {
    // The right camera alone turned by (pitch, yaw, roll) about its own axes moves its pixel by
    // f (x y, 1 + y^2), f (1 + x^2, x y), f (-y, x); of the yaw's column shift f (1 + x^2) the
    // constant f is the disparity offset (a calibration parameter), so f x^2 remains.
    const double x = (px.u_right - ou) / f, y = (px.v_right - ov) / f;
    Eigen::Matrix<double, 2, 3> J_rot;
    J_rot << f * x * y, f * x * x, -f * y,  //
        f * (1 + y * y), f * x * y, f * x;
    const double s2 = noise.relative_rotation_sigma_rad * noise.relative_rotation_sigma_rad;
    C.block<2, 2>(2, 2) += s2 * J_rot * J_rot.transpose();
  }
  return 0.5 * (C + C.transpose());
}

BodyRate stepBodyRate(std::optional<BodyRateTracker>& tracker, const Step& step, const OdometryParams& params,
                      double slip_rel_sigma) {
  if (!tracker) tracker.emplace(params.wheel_base_mm);
  const OdometryParams p = withSlip(params, step.d_left, step.d_right, slip_rel_sigma);
  return tracker->add(step.t, step.d_left, step.d_right, stepRotationVariance(step.d_left, step.d_right, p));
}

OdometryParams withSlip(const OdometryParams& params, double d_left, double d_right, double slip_rel_sigma) {
  OdometryParams p = params;
  const double d = std::max(std::fabs(d_left), std::fabs(d_right));
  p.wheel_variance_floor += slip_rel_sigma * slip_rel_sigma * d * d;
  return p;
}

Eigen::Matrix4d pixelCovarianceFor(const Observation& obs, const Landmark& landmark, const ObservationModelConfig& config,
                                   bool slide_modelled, bool feature_offset_modelled) {
  Eigen::Matrix4d C;
  if (config.pixel_sigma > 0) {
    C = isotropicPixelCovariance(config.pixel_sigma);
  } else {
    if (!(obs.pixel_covariance.diagonal().minCoeff() > 0))
      throw Error("observation of landmark " + std::to_string(landmark.id) +
                  ": has pixels but no pixel covariance (the pixel observation model needs it)");
    C = obs.pixel_covariance;
  }
  if (obs.pixels && !config.unmodelled.isZero()) {
    C += unmodelledPixelCovariance(config.rig, *obs.pixels, config.unmodelled);
    // The right feature of a marking is found on the left's row: where the rows are misaligned
    // it slides along the marking, an error of u_r alone (u_l is the left image's own). With the
    // misalignment estimated, the slide s dv is in the factor and only its residual stays.
    const UnmodelledNoise& n = config.unmodelled;
    const bool marking = landmark.type == LandmarkType::MarkingCorner || landmark.type == LandmarkType::Junction;
    double var = 0;
    if (!slide_modelled) {
      if (marking) var = n.marking_disparity_sigma_px * n.marking_disparity_sigma_px;
      if (landmark.type == LandmarkType::Intersection)
        var = n.intersection_disparity_sigma_px * n.intersection_disparity_sigma_px;
    } else if (marking) {
      // The floor is the least white disparity error: what C already states counts toward it.
      const double stated = C(0, 0) + C(2, 2) - 2 * C(0, 2);
      const double floor = n.marking_slide_residual_sigma_px * n.marking_slide_residual_sigma_px;
      const double gain = n.marking_slide_residual_per_gain_px * obs.slide_gain;
      var = std::max(0.0, floor - stated) + gain * gain;
    } else if (landmark.type == LandmarkType::Intersection) {
      var = n.intersection_slide_residual_sigma_px * n.intersection_slide_residual_sigma_px;
    }
    C(2, 2) += var;
    if (slide_modelled && !feature_offset_modelled) {
      // The feature's constants as white noise: the disparity's on u_r, the column's on both.
      const FeatureOffsetSigma b = featureOffsetSigma(landmark.type, n);
      C(2, 2) += b.disparity * b.disparity;
      for (int i : {0, 2})
        for (int j : {0, 2}) C(i, j) += b.column * b.column;
    }
  }
  return C;
}

FeatureOffsetSigma featureOffsetSigma(LandmarkType type, const UnmodelledNoise& noise) {
  switch (type) {
    case LandmarkType::GoalCorner: return {noise.goal_feature_column_sigma_px, 0.0};
    case LandmarkType::MarkingCorner:
    case LandmarkType::Junction: return {noise.marking_feature_column_sigma_px, noise.marking_feature_offset_sigma_px};
    case LandmarkType::Intersection:
      return {noise.intersection_feature_column_sigma_px, noise.intersection_feature_offset_sigma_px};
    default: return {};
  }
}

bool isRangeBearingFactor(const Observation& obs, const ObservationModelConfig& config) {
  return config.model == ObservationModel::RangeBearing || !obs.pixels;
}

ceres::CostFunction* makeObservationFactor(const Observation& obs, const Landmark& landmark,
                                           const ObservationModelConfig& config) {
  if (isRangeBearingFactor(obs, config)) return RangeBearingFactor::Create(landmark.xy(), obs.z(), obs.covariance);
  return StereoPixelFactor::Create(config.rig, landmark.position, *obs.pixels, obs.head_pan,
                                   pixelCovarianceFor(obs, landmark, config),
                                   config.model == ObservationModel::Pixels ? PixelResiduals::All
                                                                            : PixelResiduals::Columns);
}

std::unique_ptr<ceres::LossFunction> makeLossFunction(const RobustLossConfig& config) {
  if (config.type == RobustLoss::None) return nullptr;
  if (!(std::isfinite(config.scale) && config.scale > 0)) throw Error("robust loss: scale must be a positive number");
  // Ceres's loss acts on the squared norm s = |r|^2; its parameter a is the residual norm
  // where the loss changes shape, i.e. the scale in whitened units.
  if (config.type == RobustLoss::Huber) return std::make_unique<ceres::HuberLoss>(config.scale);
  return std::make_unique<ceres::CauchyLoss>(config.scale);
}

void validateStep(const Step& step, const std::string& who) {
  const std::string at = who + ": step " + std::to_string(step.step);
  validateStepOdometryAndCompass(step, at);
  for (size_t i = 0; i < step.observations.size(); ++i) {
    const Observation& o = step.observations[i];
    const std::string oat = at + ": observation " + std::to_string(i);
    if (!std::isfinite(o.range) || !std::isfinite(o.bearing)) throw Error(oat + ": not finite");
    const Eigen::Matrix2d& R = o.covariance;
    if (!R.allFinite() || !(R(0, 0) > 0) || !(R(0, 0) * R(1, 1) - R(0, 1) * R(1, 0) > 0) ||
        std::fabs(R(0, 1) - R(1, 0)) > 1e-9 * R.cwiseAbs().maxCoeff())
      throw Error(oat + ": covariance R is not symmetric positive definite");
  }
}

bool accumulateNormalEquations(const ceres::CostFunction& cost, const std::vector<const double*>& current,
                               const std::vector<const double*>& linearisation, const std::vector<int>& offsets,
                               Eigen::MatrixXd& H, Eigen::VectorXd& g) {
  using RowMajor = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
  const int m = cost.num_residuals();
  const size_t nb = cost.parameter_block_sizes().size();
  Eigen::VectorXd r(m);
  std::vector<RowMajor> J(nb, RowMajor(m, 3));
  std::vector<double*> jp(nb);
  for (size_t i = 0; i < nb; ++i) jp[i] = J[i].data();
  if (!cost.Evaluate(linearisation.data(), r.data(), jp.data())) return false;
  if (!r.allFinite()) return false;
  for (size_t i = 0; i < nb; ++i) {
    if (!J[i].allFinite()) return false;
    if (current[i] != linearisation[i]) {
      const double* c = current[i];
      const double* l = linearisation[i];
      const Eigen::Vector3d d(c[0] - l[0], c[1] - l[1], wrapAngle(c[2] - l[2]));
      r += J[i] * d;
    }
  }
  for (size_t i = 0; i < nb; ++i) {
    g.segment<3>(offsets[i]) += J[i].transpose() * r;
    for (size_t j = 0; j < nb; ++j) H.block<3, 3>(offsets[i], offsets[j]) += J[i].transpose() * J[j];
  }
  return true;
}

bool chainMarginalCovariances(const std::vector<Eigen::Matrix3d>& D, const std::vector<Eigen::Matrix3d>& B,
                              std::vector<Eigen::Matrix3d>* covariances) {
  const size_t n = D.size();
  if (B.size() != n) throw Error("chainMarginalCovariances: D and B must have the same length");
  std::vector<Eigen::Matrix3d> inv(n);  // Lambda_i^-1
  Eigen::Matrix3d lambda;
  for (size_t i = 0; i < n; ++i) {
    lambda = D[i];
    if (i > 0) lambda -= B[i].transpose() * inv[i - 1] * B[i];
    lambda = 0.5 * (lambda + lambda.transpose());
    // Positive definite with its smallest eigenvalue above 1e-14 of D_i's scale. The closed-form
    // inverse of a 3x3 (a million poses: an eigen-decomposition each would dominate the pass);
    // 1 / |Lambda^-1|_F is a lower bound of the smallest eigenvalue within sqrt(3).
    const double scale = std::max(D[i].cwiseAbs().maxCoeff(), std::numeric_limits<double>::min());
    const Eigen::LLT<Eigen::Matrix3d> llt(lambda);
    if (!lambda.allFinite() || llt.info() != Eigen::Success) return false;
    inv[i] = lambda.inverse();
    inv[i] = 0.5 * (inv[i] + inv[i].transpose());
    const double norm = inv[i].norm();
    if (!inv[i].allFinite() || !(1.0 / norm > 1e-14 * scale)) return false;
  }
  covariances->assign(n, Eigen::Matrix3d::Zero());
  if (n == 0) return true;
  (*covariances)[n - 1] = inv[n - 1];
  for (size_t i = n - 1; i-- > 0;) {
    const Eigen::Matrix3d G = inv[i] * B[i + 1];
    const Eigen::Matrix3d S = inv[i] + G * (*covariances)[i + 1] * G.transpose();
    (*covariances)[i] = 0.5 * (S + S.transpose());
  }
  return true;
}

void schurComplement(const Eigen::MatrixXd& H, const Eigen::VectorXd& g, int m, Eigen::MatrixXd* H_marginal,
                     Eigen::VectorXd* g_marginal) {
  const int n = static_cast<int>(H.rows());
  if (m <= 0 || m > n || H.cols() != n || g.size() != n) throw Error("schurComplement: bad dimensions");
  const int k = n - m;
  const Eigen::MatrixXd Hmm = 0.5 * (H.topLeftCorner(m, m) + H.topLeftCorner(m, m).transpose());
  Eigen::LLT<Eigen::MatrixXd> llt(Hmm);
  if (llt.info() != Eigen::Success || !Hmm.allFinite())
    throw Error("marginalisation: the information of the marginalised pose is not positive definite (rank deficient)");
  const Eigen::MatrixXd Hrm = H.bottomLeftCorner(k, m);
  const Eigen::MatrixXd X = llt.solve(Hrm.transpose());  // H_mm^-1 H_mr
  *H_marginal = H.bottomRightCorner(k, k) - Hrm * X;
  *H_marginal = 0.5 * (*H_marginal + H_marginal->transpose());
  *g_marginal = g.tail(k) - X.transpose() * g.head(m);
}

void addRandomWalk(Eigen::MatrixXd& H, Eigen::VectorXd& g, int offset, const Eigen::VectorXd& variance) {
  const Eigen::Index n = H.rows(), k = variance.size();
  if (H.cols() != n || g.size() != n || offset < 0 || offset + k > n)
    throw Error("addRandomWalk: bad dimensions");
  std::vector<Eigen::Index> walked;
  for (Eigen::Index i = 0; i < k; ++i) {
    if (!(std::isfinite(variance[i]) && variance[i] >= 0))
      throw Error("addRandomWalk: a variance is negative or not finite");
    if (variance[i] > 0) walked.push_back(i);
  }
  if (walked.empty()) return;
  const Eigen::Index m = static_cast<Eigen::Index>(walked.size());
  Eigen::MatrixXd HE(n, m);  // H E
  Eigen::MatrixXd M(m, m);   // Q^-1 + E^T H E
  for (Eigen::Index j = 0; j < m; ++j) HE.col(j) = H.col(offset + walked[static_cast<size_t>(j)]);
  for (Eigen::Index i = 0; i < m; ++i) {
    for (Eigen::Index j = 0; j < m; ++j) M(i, j) = HE(offset + walked[static_cast<size_t>(i)], j);
    M(i, i) += 1.0 / variance[walked[static_cast<size_t>(i)]];
  }
  const Eigen::LLT<Eigen::MatrixXd> llt(0.5 * (M + M.transpose()));
  if (llt.info() != Eigen::Success) throw Error("addRandomWalk: the information is not positive semi-definite");
  Eigen::VectorXd Eg(m);
  for (Eigen::Index j = 0; j < m; ++j) Eg[j] = g[offset + walked[static_cast<size_t>(j)]];
  g -= HE * llt.solve(Eg);
  H -= HE * llt.solve(HE.transpose());
  H = 0.5 * (H + H.transpose());
}

}  // namespace stereoloc

namespace stereoloc {

SyntheticProblem makeRandomWalkProblem(const SyntheticProblemOptions& o, uint64_t seed) {
  if (o.steps < 1 || o.landmarks < 1 || o.landmarks > 10 || o.max_observations < 0)
    throw Error("makeRandomWalkProblem: steps >= 1, landmarks in 1..10, max_observations >= 0");
  static const double kLandmarks[10][2] = {{0, 0},       {750, 0},   {1500, 0},   {1500, 650},  {1500, 1300},
                                           {750, 1300},  {0, 1300},  {0, 650},    {375, 650},   {1125, 650}};
  std::vector<Landmark> lms;
  for (int i = 0; i < o.landmarks; ++i) {
    Landmark l;
    l.id = i;
    l.type = LandmarkType::Point;
    l.name = "lm" + std::to_string(i);
    l.position = Eigen::Vector3d(kLandmarks[i][0], kLandmarks[i][1], 0.0);
    l.unique = true;
    lms.push_back(l);
  }
  Bounds bounds;
  bounds.xmax = 1500;
  bounds.ymax = 1300;
  SyntheticProblem p{FieldMap("random_walk", bounds, lms), OdometryParams(), {}, {}};
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> N(0.0, 1.0);
  std::uniform_real_distribution<double> U(0.0, 1.0);
  Pose2 truth(750.0, 650.0, 0.3);
  const double w = p.odometry.wheel_base_mm;
  for (int k = 0; k < o.steps; ++k) {
    Step s;
    s.step = k;
    s.t = 0.1 * k;
    if (k > 0) {
      const double arc = std::max(0.0, o.step_length * (1.0 + 0.25 * N(rng)));
      double dtheta = o.turn_sigma * N(rng);
      const Pose2 ahead = compose(truth, Pose2(150.0, 0.0, 0.0));
      if (!bounds.contains(ahead.translation(), -150.0)) {  // steer back towards the centre
        const double to_centre = std::atan2(650.0 - truth.y, 750.0 - truth.x);
        dtheta = std::clamp(angleDiff(to_centre, truth.theta), -0.4, 0.4);
      }
      const WheelIncrements d = wheelIncrementsForArc(arc, dtheta, w);
      const Eigen::Vector3d u = controlVector(d.d_left, d.d_right, w);
      truth = compose(truth, Pose2(u.x(), u.y(), u.z()));
      s.d_left = d.d_left;
      s.d_right = d.d_right;
      if (o.noisy_odometry) {
        const Eigen::Matrix2d V = wheelCovariance(d.d_left, d.d_right, p.odometry);
        s.d_left += std::sqrt(V(0, 0)) * N(rng);
        s.d_right += std::sqrt(V(1, 1)) * N(rng);
      }
    }
    if (o.compass_sigma > 0) {
      s.compass = wrapAngle(truth.theta + o.compass_sigma * N(rng));
      s.compass_sigma = o.compass_sigma;
    }
    std::vector<std::pair<double, int>> visible;
    for (const Landmark& l : lms) {
      const Eigen::Vector2d z = predictRangeBearingNoThrow(truth, l.xy());
      if (z(0) > 1.0 && z(0) <= o.max_range && std::fabs(z(1)) <= o.half_fov && U(rng) < o.observation_probability)
        visible.emplace_back(z(0), l.id);
    }
    std::sort(visible.begin(), visible.end());
    for (size_t i = 0; i < visible.size() && static_cast<int>(i) < o.max_observations; ++i) {
      const Eigen::Vector2d z = predictRangeBearingNoThrow(truth, lms[static_cast<size_t>(visible[i].second)].xy());
      double range = z(0) + o.sigma_range * N(rng);
      const double bearing = wrapAngle(z(1) + o.sigma_bearing * N(rng));
      if (o.outlier_fraction > 0 && U(rng) < o.outlier_fraction) range *= 1.5;
      s.observations.push_back(observationFromRangeBearing(visible[i].second, LandmarkType::Point,
                                                           std::max(range, 1.0), bearing, o.sigma_range,
                                                           o.sigma_bearing));
    }
    p.steps.push_back(std::move(s));
    p.truth.push_back(truth);
  }
  return p;
}

}  // namespace stereoloc
