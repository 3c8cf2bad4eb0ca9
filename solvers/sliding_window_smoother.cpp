#include "solvers/sliding_window_smoother.h"

#include <ceres/solver.h>

#include <Eigen/Cholesky>
#include <Eigen/LU>
#include <algorithm>
#include <cmath>
#include <limits>
#include <memory>
#include <utility>

#include "factors/block_marginal_prior_factor.h"
#include "factors/calibration_prior_factor.h"
#include "factors/compass_factor.h"
#include "factors/composed_odometry_calibration_factor.h"
#include "factors/field_shifted_factor.h"
#include "factors/held_entries.h"
#include "factors/marginal_prior_factor.h"
#include "factors/odometry_calibration_factor.h"
#include "factors/range_bearing_calibration_factor.h"
#include "factors/odometry_factor.h"
#include "factors/pose_prior_factor.h"
#include "factors/stereo_pixel_calibration_factor.h"
#include "factors/stereo_pixel_feature_calibration_factor.h"
#include "factors/stereo_pixel_image_calibration_factor.h"
#include "factors/stereo_pixel_row_calibration_factor.h"
#include "solvers/iterated_update.h"
#include "solvers/sliding_window_detail.h"
#include "src/core/error.h"
#include "src/core/gaussian.h"
#include "src/core/measurement_model.h"

namespace stereoloc {

using window_detail::emptyProblem;
using window_detail::poseOf;
using window_detail::positiveDefinite;

std::string toString(WindowLinearisation l) {
  switch (l) {
    case WindowLinearisation::PriorPoint: return "prior_point";
    case WindowLinearisation::FirstEstimates: return "first_estimates";
    case WindowLinearisation::Current: return "current";
  }
  return "prior_point";
}

WindowLinearisation windowLinearisationFromString(const std::string& name) {
  for (WindowLinearisation l :
       {WindowLinearisation::PriorPoint, WindowLinearisation::FirstEstimates, WindowLinearisation::Current})
    if (toString(l) == name) return l;
  throw Error("unknown window linearisation '" + name + "' (expected prior_point, first_estimates or current)");
}

void SlidingWindowConfig::validate() const {
  if (window < 1) throw Error("sliding window: window must be >= 1");
  if (image_errors_after_steps < 0) throw Error("sliding window: image_errors_after_steps must be >= 0");
  if (max_iterations < 1) throw Error("sliding window: max_iterations must be >= 1");
  if (final_iterations < 0) throw Error("sliding window: final_iterations must be >= 0");
  if (!(max_solver_seconds >= 0)) throw Error("sliding window: max_solver_seconds must be >= 0");
  if (!(compass_gate_probability > 0 && compass_gate_probability < 1))
    throw Error("sliding window: compass_gate_probability must be in (0, 1)");
  if (!(gate.probability > 0 && gate.probability < 1)) throw Error("sliding window: gate.probability must be in (0, 1)");
  if (gate.lost_after < 1) throw Error("sliding window: gate.lost_after must be >= 1");
  if (keyframe_max_steps < 1) throw Error("sliding window: keyframe_max_steps must be >= 1");
  if (!(retest_probability > 0 && retest_probability < 1))
    throw Error("sliding window: retest_probability must be in (0, 1)");
  if (!(reanchor_probability >= 0 && reanchor_probability < 1))
    throw Error("sliding window: reanchor_probability must be in [0, 1)");
  if (restart_buffer_steps < 0) throw Error("sliding window: restart_buffer_steps must be >= 0");
  if (!(restart_min_evidence >= 0)) throw Error("sliding window: restart_min_evidence must be >= 0");
  makeLossFunction(robust_loss);  // validates the scale
  calibration.validate();
  if (calibration.consider)
    throw Error("sliding window: calibration.consider is the EKF's (a Schmidt gain); the smoothers estimate the calibration");
}

SlidingWindowSmoother::SlidingWindowSmoother(const FieldMap& map, const OdometryParams& odometry,
                                             SlidingWindowConfig config)
    : map_(map),
      odometry_(odometry),
      config_((config.validate(), std::move(config))),
      gate_(config_.gate, 2),
      gate_enabled_(config_.gate_enabled &&
                    (config_.robust_loss.type == RobustLoss::None || config_.gate_with_robust_loss)),
      compass_threshold_(chi2Quantile(config_.compass_gate_probability, 1)),
      retest_threshold_(chi2Quantile(config_.retest_probability, 2)),
      retest_threshold_compass_(chi2Quantile(config_.retest_probability, 1)),
      loss_(makeLossFunction(config_.robust_loss)) {
  odometry_.validate();
  if (!config_.global_fix) config_.global_fix = defaultGlobalFix();
  if (config_.init.mode != InitMode::Global && (!config_.init.pose.isFinite() || !positiveDefinite(config_.init.covariance)))
    throw Error("sliding window: initial belief is not finite / its covariance not positive definite");
  problem_ = emptyProblem();
  // The calibration blocks with their priors (solvers/self_calibration.h).
  const SelfCalibrationConfig& cal = config_.calibration;
  wheels_[2] = odometry_.wheel_base_mm;
  row_sigma_ = rowOffsetSigma(cal, config_.observation_model.unmodelled);
  if (cal.odometry) wheels_block_ = addCalibBlock(wheels_.data(), 3);
  if (cal.stereo) head_block_ = addCalibBlock(head_.data(), StereoBlock::RowsAtCompileTime);
  image_sigmas_ = imageErrorSigmas(cal, config_.observation_model.unmodelled);
  if (image_sigmas_) image_block_ = addCalibBlock(image_.data(), CalibrationEstimate::ImageVector::RowsAtCompileTime);
  if (row_sigma_) row_block_ = addCalibBlock(&row_, 1);
  if (cal.range) range_block_ = addCalibBlock(range_.data(), RangeBearingCalibrationFactor::kCalibrationSize);
  if (cal.field) {
    if (!derivesFromGeometry(map_))
      throw Error("sliding window: --calibrate field needs a MiroSot map as its field geometry derives it; map '" +
                  map_.name() + "' is not");
    field_block_ = addCalibBlock(field_.data(), kFieldDimensionCount);
    field_jacobian_ = map_.fieldJacobians();
  }
  for (const FeatureOffsetPrior& f : featureOffsetSigmas(map_, cal, config_.observation_model.unmodelled))
    feature_sigmas_[f.landmark_id] = f.sigma;
  // With calibration blocks every factor is linearised at the current estimate: each factor's
  // own first estimates differ from pose to pose, and through the weakly observable wheel base
  // those differences become information the data do not have (on a 400-step circle, W = 20:
  // the wheel base drifted from 75 to 92 mm with a standard deviation below the batch's, while
  // linearising at the estimate stays within 0.1 mm and 1 % of the batch's).
  linearisation_ = calibDim() == 0 ? config_.linearisation : WindowLinearisation::Current;
  // Until the first solve, the calibration's covariance is its prior's (the gate reads it).
  calib_covariance_ = Eigen::MatrixXd::Zero(calibDim(), calibDim());
  if (cal.odometry) {
    const Eigen::Vector3d sig = wheelPriorSigma(cal, wheels_[2]);
    addFactor(CalibrationPriorFactor<3>::Create(wheels_, sig.cwiseAbs2().asDiagonal().toDenseMatrix()),
              {}, false, {wheels_block_});
    calib_covariance_.diagonal().segment<3>(calibOffset(wheels_block_)) = sig.cwiseAbs2();
  }
  if (cal.stereo) {
    const StereoBlock sig = stereoPriorSigma(cal);
    addFactor(CalibrationPriorFactor<StereoBlock::RowsAtCompileTime>::Create(
                  head_, sig.cwiseAbs2().asDiagonal().toDenseMatrix()),
              {}, false, {head_block_});
    calib_covariance_.diagonal().segment(calibOffset(head_block_), calibSize(head_block_)) = sig.cwiseAbs2();
  }
  if (image_sigmas_) {
    // Whitened: its prior is the identity.
    constexpr int m = CalibrationEstimate::ImageVector::RowsAtCompileTime;
    addFactor(CalibrationPriorFactor<m>::Create(CalibrationEstimate::ImageVector::Zero(),
                                                Eigen::Matrix<double, m, m>::Identity()),
              {}, false, {image_block_});
    calib_covariance_.diagonal().segment(calibOffset(image_block_), m).setOnes();
  }
  if (row_sigma_) {
    addFactor(CalibrationPriorFactor<1>::Create(Eigen::Matrix<double, 1, 1>::Zero(),
                                                Eigen::Matrix<double, 1, 1>::Constant(*row_sigma_ * *row_sigma_)),
              {}, false, {row_block_});
    calib_covariance_(calibOffset(row_block_), calibOffset(row_block_)) = *row_sigma_ * *row_sigma_;
  }
  if (cal.range) {
    constexpr int k = RangeBearingCalibrationFactor::kCalibrationSize;
    const Eigen::Vector4d sig = rangePriorSigma(cal);
    addFactor(CalibrationPriorFactor<k>::Create(range_, sig.cwiseAbs2().asDiagonal().toDenseMatrix()), {}, false,
              {range_block_});
    calib_covariance_.diagonal().segment<k>(calibOffset(range_block_)) = sig.cwiseAbs2();
  }
  if (cal.field) {
    constexpr int k = kFieldDimensionCount;
    const FieldDimensionMatrix prior = fieldPriorCovariance(cal, map_);
    addFactor(CalibrationPriorFactor<k>::Create(FieldDimensionVector::Zero(), prior), {}, false, {field_block_});
    calib_covariance_.block<k, k>(calibOffset(field_block_), calibOffset(field_block_)) = prior;
  }
}

SlidingWindowSmoother::Calib SlidingWindowSmoother::addCalibBlock(double* data, int size) {
  problem_->AddParameterBlock(data, size);
  calib_.push_back({data, size, calib_dim_});
  calib_dim_ += size;
  return static_cast<Calib>(calib_.size() - 1);
}

const SlidingWindowSmoother::FeatureBlock* SlidingWindowSmoother::featureBlock(const Landmark& lm) {
  const auto known = feature_index_.find(lm.id);
  if (known != feature_index_.end()) return &features_[known->second];
  const auto stated = feature_sigmas_.find(lm.id);
  if (stated == feature_sigmas_.end()) return nullptr;
  // A global block like the head's: never marginalised, so every sighting of the feature, in the
  // window or marginalised into its prior, sees the same constant. Only the stated entries are
  // parameters (an unstated one, a goal corner's u_r offset, has no prior to make it observable
  // and is zero by the noise model), with the zero-mean prior of their stated sigmas.
  features_.emplace_back();
  FeatureBlock& f = features_.back();
  f.landmark_id = lm.id;
  f.sigma = stated->second;
  Eigen::VectorXd sd(2);
  int n = 0;
  for (double s : {f.sigma.column, f.sigma.disparity})
    if (s > 0) sd[n++] = s;
  f.block = addCalibBlock(f.value.data(), n);
  feature_index_[lm.id] = features_.size() - 1;
  addFactor(new DiagonalPriorFactor(Eigen::VectorXd::Zero(n), sd.head(n)), {}, false, {f.block});
  // Uncorrelated with everything until the next covariance computation.
  const int k = calibOffset(f.block);
  calib_covariance_.conservativeResizeLike(Eigen::MatrixXd::Zero(calibDim(), calibDim()));
  calib_covariance_.diagonal().segment(k, n) = sd.head(n).cwiseAbs2();
  return &f;
}

CalibrationEstimate::StereoMatrix SlidingWindowSmoother::headCovariance() const {
  const int k = calibOffset(head_block_);
  const int n = calibSize(head_block_);
  return calib_covariance_.block(k, k, n, n);
}

std::vector<SlidingWindowSmoother::Calib> SlidingWindowSmoother::calibBlocks() const {
  std::vector<Calib> out(calib_.size());
  for (size_t i = 0; i < out.size(); ++i) out[i] = static_cast<Calib>(i);
  return out;
}

const double* SlidingWindowSmoother::linearisationPoint(const Factor& f, size_t j) const {
  const Node& n = *f.nodes[j];
  switch (linearisation_) {
    case WindowLinearisation::FirstEstimates: return f.linearisation[j].data();
    case WindowLinearisation::PriorPoint: return n.prior_point ? n.prior_point->data() : n.x.data();
    case WindowLinearisation::Current: break;
  }
  return n.x.data();
}

void SlidingWindowSmoother::relinearise() {
  for (const auto& n : nodes_)
    if (n->prior_point) n->prior_point = n->x;
  for (const auto& f : factors_) {
    size_t j = 0;
    for (; j < f->nodes.size(); ++j) f->linearisation[j] = f->nodes[j]->x;
  }
}

PosePrediction SlidingWindowSmoother::predictStep(const Pose2& rel, const Eigen::Matrix3d& C, double d_left,
                                                  double d_right, Eigen::Matrix3d* J_c) const {
  // Slip as the batch states it (UnmodelledNoise::slip_rel_sigma, solvers/smoother_common.h).
  const OdometryParams p = withSlip(odometry_, d_left, d_right, config_.observation_model.unmodelled.slip_rel_sigma);
  if (!config_.calibration.odometry) return predictPose(rel, C, d_left, d_right, p);
  return predictCalibratedStep(rel, C, d_left, d_right, wheels_, p, J_c);
}

Eigen::Matrix3d SlidingWindowSmoother::composedCovariance(const Node& k, const Eigen::Matrix3d& A1,
                                                          const Eigen::Matrix3d& A2, const Eigen::Matrix3d& rel_covariance,
                                                          const Eigen::Matrix3d& rel_wheels) const {
  Eigen::Matrix3d P = A1 * k.covariance * A1.transpose() + A2 * rel_covariance * A2.transpose();  // (5.9)
  if (config_.calibration.odometry) {
    // The odometry since k went through the estimated wheel calibration c, which is uncertain and
    // correlated with k's pose: linearised in (p_k, c, noise), the prediction's covariance gains
    // B C_c B^T + A1 C_kc B^T + B C_ck A1^T with B = A2 dr/dc. Without these terms the gate would
    // treat the current estimate of c as exact and reject the sightings that disagree with it,
    // which are the ones that would correct it.
    const Eigen::Matrix3d B = A2 * rel_wheels;
    const Eigen::Matrix3d Cc = calib_covariance_.block<3, 3>(calibOffset(wheels_block_), calibOffset(wheels_block_));
    const Eigen::Matrix3d cross = A1 * k.wheels_cross * B.transpose();
    P += B * Cc * B.transpose() + cross + cross.transpose();
  }
  return 0.5 * (P + P.transpose());
}

std::optional<CalibrationEstimate> SlidingWindowSmoother::calibration() const {
  if (calibDim() == 0) return std::nullopt;
  CalibrationEstimate e;
  e.odometry = config_.calibration.odometry;
  e.stereo = config_.calibration.stereo;
  e.wheels = wheels_;
  e.head = head_;
  if (e.odometry) {
    e.wheels_covariance = calib_covariance_.block<3, 3>(calibOffset(wheels_block_), calibOffset(wheels_block_));
    e.wheels_walk_variance = wheels_walked_;
  }
  if (e.stereo) e.head_covariance = headCovariance();
  if (image_sigmas_) {
    const int k = calibOffset(image_block_), m = calibSize(image_block_);
    e.image = true;
    e.image_errors = image_sigmas_->cwiseProduct(image_);
    e.image_covariance = image_sigmas_->asDiagonal() * calib_covariance_.block(k, k, m, m) * image_sigmas_->asDiagonal();
  }
  if (field_block_ >= 0) {
    const int k = calibOffset(field_block_);
    e.field = true;
    e.field_dimensions_mm = field_;
    e.field_covariance = calib_covariance_.block<kFieldDimensionCount, kFieldDimensionCount>(k, k);
    e.field_prior_sigma_mm = fieldPriorCovariance(config_.calibration, map_).diagonal().cwiseSqrt();
  }
  if (config_.calibration.range) {
    constexpr int k = RangeBearingCalibrationFactor::kCalibrationSize;
    e.range = true;
    e.range_bearing = range_;
    e.range_bearing_covariance = calib_covariance_.block<k, k>(calibOffset(range_block_), calibOffset(range_block_));
  }
  if (rowBlock()) {
    e.row = true;
    e.row_offset_px = row_;
    e.row_offset_variance = calib_covariance_(calibOffset(row_block_), calibOffset(row_block_));
  }
  // The landmarks fused so far, in the map's order (as the batch lists them).
  for (const Landmark& l : map_.landmarks()) {
    const auto i = feature_index_.find(l.id);
    if (i == feature_index_.end()) continue;
    const FeatureBlock& f = features_[i->second];
    CalibrationEstimate::FeatureOffset o;
    o.landmark_id = f.landmark_id;
    const int k = calibOffset(f.block);
    int j = 0;  // the block holds the stated entries only
    if (f.sigma.column > 0) {
      o.column_px = f.value[0];
      o.column_variance = calib_covariance_(k, k);
      ++j;
    }
    if (f.sigma.disparity > 0) {
      o.offset_px = f.value[static_cast<size_t>(j)];
      o.variance = calib_covariance_(k + j, k + j);
    }
    e.feature_offsets.push_back(o);
  }
  return e;
}

SlidingWindowSmoother::~SlidingWindowSmoother() {
  problem_.reset();  // before the cost functions it refers to
}

Estimate SlidingWindowSmoother::estimateOf(const Node& n) const {
  Estimate e;
  e.step = n.step;
  e.t = n.t;
  e.pose = poseOf(n.x);
  e.covariance = n.covariance;
  e.status = n.status;
  return e;
}

void SlidingWindowSmoother::pushHistory(const Estimate& e) {
  if (config_.keep_history) history_.push_back(e);
}

void SlidingWindowSmoother::addFactor(ceres::CostFunction* cost, std::vector<Node*> nodes, bool robust,
                                      std::vector<Calib> calib) {
  auto f = std::make_unique<Factor>();
  f->cost.reset(cost);
  f->nodes = std::move(nodes);
  f->calib = std::move(calib);
  f->robust = robust && loss_ != nullptr;
  std::vector<double*> blocks;
  for (Node* n : f->nodes) {
    f->linearisation.push_back(n->x);  // first estimate: the values at creation
    blocks.push_back(n->x.data());
  }
  for (Calib c : f->calib) blocks.push_back(calibData(c));  // always linearised at the estimate
  f->id = problem_->AddResidualBlock(f->cost.get(), f->robust ? loss_.get() : nullptr, blocks);
  factors_.push_back(std::move(f));
}

void SlidingWindowSmoother::pushIntermediates(const Node& k, const Node* next) {
  if (!config_.keep_history) return;
  const Pose2 pk = poseOf(k.x);
  for (const Intermediate& m : k.after) {
    Estimate e;
    e.step = m.step;
    e.t = m.t;
    e.status = m.status;
    Matrix3d A1, A2;
    if (!next || !k.have_joint_next) {  // the newest keyframe: the real-time prediction
      e.pose = compose(pk, m.rel, &A1, &A2);
      e.covariance = composedCovariance(k, A1, A2, m.rel_covariance, m.rel_wheels);
      history_.push_back(e);
      continue;
    }
    // Conditioned on both keyframes (see the header).
    const Pose2 pn = poseOf(next->x);
    Matrix3d M, Bk, Bn;
    compose(m.rel, between(m.rel, k.rel_to_next), &M);
    const Pose2 r_hat = between(pk, pn, &Bk, &Bn);
    Eigen::Vector3d delta(r_hat.x - k.rel_to_next.x, r_hat.y - k.rel_to_next.y,
                          angleDiff(r_hat.theta, k.rel_to_next.theta));
    const Eigen::Matrix3d CjN = m.rel_covariance * M.transpose();
    const Eigen::LDLT<Eigen::Matrix3d> CN(k.rel_to_next_covariance);
    const Eigen::Matrix3d G = CN.solve(CjN.transpose()).transpose();  // C_jN C_N^-1
    const Pose2 rj = plus(m.rel, G * delta);
    e.pose = compose(pk, rj, &A1, &A2);
    Eigen::Matrix<double, 3, 6> T;
    T.leftCols<3>() = A1 + A2 * G * Bk;
    T.rightCols<3>() = A2 * G * Bn;
    const Eigen::Matrix3d bridge = m.rel_covariance - G * CjN.transpose();
    const Eigen::Matrix3d P = T * k.joint_next * T.transpose() + A2 * bridge * A2.transpose();
    e.covariance = 0.5 * (P + P.transpose());
    history_.push_back(e);
  }
}

void SlidingWindowSmoother::removeFactor(size_t index) {
  problem_->RemoveResidualBlock(factors_[index]->id);
  factors_.erase(factors_.begin() + static_cast<long>(index));
}

void SlidingWindowSmoother::startWindow(const Step& step, const Pose2& pose, const Eigen::Matrix3d& covariance,
                                        EstimateStatus status) {
  auto node = std::make_unique<Node>();
  node->step = step.step;
  node->t = step.t;
  node->rate = step_rate_;
  node->x = {pose.x, pose.y, pose.theta};
  node->status = status;
  node->covariance = 0.5 * (covariance + covariance.transpose());
  Node* n = node.get();
  nodes_.push_back(std::move(node));
  problem_->AddParameterBlock(n->x.data(), 3, &manifold_);
  addFactor(PosePriorFactor::Create(pose, n->covariance), {n});
  gate_.reset();
  lost_ = false;
  rel_ = Pose2();
  rel_covariance_.setZero();
  rel_wheels_.setZero();
  steps_since_keyframe_ = 0;
  ++stats_.keyframes;
}

void SlidingWindowSmoother::dropNewest() {
  Node* n = nodes_.back().get();
  for (size_t i = factors_.size(); i-- > 0;)
    if (std::find(factors_[i]->nodes.begin(), factors_[i]->nodes.end(), n) != factors_[i]->nodes.end()) removeFactor(i);
  problem_->RemoveParameterBlock(n->x.data());
  nodes_.pop_back();
}

void SlidingWindowSmoother::finaliseWindow() {
  if (nodes_.empty()) return;
  computeCovariances(true);
  for (size_t i = 0; i < nodes_.size(); ++i) {
    history_.push_back(estimateOf(*nodes_[i]));  // the final window, with or without keep_history
    pushIntermediates(*nodes_[i], i + 1 < nodes_.size() ? nodes_[i + 1].get() : nullptr);
  }
  for (size_t i = factors_.size(); i-- > 0;) removeFactor(i);
  for (const auto& n : nodes_) problem_->RemoveParameterBlock(n->x.data());
  nodes_.clear();
  addCalibrationPrior();
}

void SlidingWindowSmoother::addCalibrationPrior() {
  // The calibration outlives the window: its marginal becomes the prior of the next one.
  if (calibDim() == 0) return;
  std::vector<BlockMarginalPriorFactor::Block> blocks;
  for (Calib c : calibBlocks())
    blocks.push_back({Eigen::Map<const Eigen::VectorXd>(calibData(c), calibSize(c)), false});
  const Eigen::MatrixXd C = 0.5 * (calib_covariance_ + calib_covariance_.transpose());
  const Eigen::LLT<Eigen::MatrixXd> llt(C);
  // Every marginal computed is positive definite (computeCovariances refuses the rest); the
  // diagonal is the fallback should one not be.
  const Eigen::MatrixXd info =
      llt.info() == Eigen::Success ? Eigen::MatrixXd(llt.solve(Eigen::MatrixXd::Identity(C.rows(), C.cols())))
                                   : Eigen::MatrixXd(C.diagonal().cwiseMax(1e-12).cwiseInverse().asDiagonal());
  addFactor(BlockMarginalPriorFactor::FromInformation(blocks, info, Eigen::VectorXd::Zero(C.rows())), {}, false,
            calibBlocks());
}

std::string toString(LateObservationStatus status) {
  switch (status) {
    case LateObservationStatus::Inserted: return "inserted";
    case LateObservationStatus::TooLate: return "too_late";
    case LateObservationStatus::NotTracking: return "not_tracking";
  }
  return "unknown";
}

std::vector<Observation> SlidingWindowSmoother::gateViews(const Observation& measured) const {
  std::vector<Observation> views;
  if (config_.calibration.stereo && measured.pixels) {
    Landmark kind;  // the pixel noise of the sighting's kind (a marking corner's disparity slides)
    kind.type = measured.type;
    const Eigen::Matrix4d C_px = pixelCovarianceFor(measured, kind, config_.observation_model, rowBlock());
    const StereoBlock sig = stereoPriorSigma(config_.calibration);
    const std::pair<StereoBlock, CalibrationEstimate::StereoMatrix> calibrations[2] = {
        {head_, headCovariance()}, {CalibrationEstimate().head, sig.cwiseAbs2().asDiagonal()}};
    // With the row block, each view also takes the slide s dv out of u_r, with the row offset's
    // variance as s^2 Var(dv) on u_r: the current estimate, then the prior (dv = 0, sigma_row).
    double row[2] = {0, 0}, row_variance[2] = {0, 0};
    if (rowBlock()) {
      row[0] = row_;
      row_variance[0] = calib_covariance_(calibOffset(row_block_), calibOffset(row_block_));
      row_variance[1] = *row_sigma_ * *row_sigma_;
    }
    for (int k = 0; k < 2; ++k) {
      const auto& [q, Cq] = calibrations[k];
      Observation slid = measured;
      Eigen::Matrix4d C = C_px;
      if (rowBlock()) {
        slid.pixels->u_right -= measured.slide_gain * row[k];
        C(2, 2) += measured.slide_gain * measured.slide_gain * row_variance[k];
      }
      try {
        views.push_back(calibratedObservation(slid, config_.observation_model.rig, q, Cq, C));
      } catch (const GeometryError&) {
      }
    }
  } else if (config_.calibration.range && isRangeBearingFactor(measured, config_.observation_model)) {
    // As the stereo head's: through the current estimate, then through the prior.
    const int k = calibOffset(range_block_);
    const Eigen::Matrix4d prior = rangePriorSigma(config_.calibration).cwiseAbs2().asDiagonal();
    const std::pair<Eigen::Vector4d, Eigen::Matrix4d> calibrations[2] = {
        {range_, calib_covariance_.block<4, 4>(k, k)}, {Eigen::Vector4d::Zero(), prior}};
    for (const auto& [value, covariance] : calibrations) {
      try {
        views.push_back(withRangeCalibration(measured, value, covariance));
      } catch (const Error&) {
      }
    }
  } else {
    views.push_back(measured);
  }
  return views;
}

const Landmark* SlidingWindowSmoother::landmarkOf(const Observation& measured, const Observation& view,
                                                  const Pose2& pose, const Eigen::Matrix3d& P, std::vector<int>& used) {
  if (measured.landmark_id >= 0) return map_.find(measured.landmark_id);
  const AssociationResult a =
      associate(view, pose, P, map_, config_.association, config_.association.exclusive ? used : std::vector<int>{});
  if (a.landmark_id < 0) return nullptr;
  used.push_back(a.landmark_id);
  return &map_.at(a.landmark_id);
}

SlidingWindowSmoother::CalibratedCost SlidingWindowSmoother::stereoCalibrationCost(const Observation& measured,
                                                                                   const Landmark& lm,
                                                                                   const BodyRate& rate,
                                                                                   bool image_free) {
  const PixelResiduals residuals =
      config_.observation_model.model == ObservationModel::Pixels ? PixelResiduals::All : PixelResiduals::Columns;
  const auto* image = image_sigmas_ ? &*image_sigmas_ : nullptr;
  CalibratedCost c;
  // The field's change moves the landmark (factors/field_shifted_factor.h): one more block.
  const auto withField = [&](CalibratedCost& out) {
    if (field_block_ >= 0) {
      out.cost = new FieldShiftedFactor(out.cost, field_jacobian_.at(lm.id));
      out.blocks.push_back(field_block_);
    }
    return out;
  };
  if (rowBlock()) {
    // With the feature's offsets estimated, their constant leaves the white pixel noise: it
    // repeats over the feature's sightings, and as white noise it would be averaged down as if
    // it did not (the calibration's covariance then too small).
    const FeatureBlock* feature = featureBlock(lm);
    // Until the image block is free its errors stay in the pixel noise too.
    const Eigen::Matrix4d C = calibratedPixelCovariance(measured, lm, config_.observation_model,
                                                        image_sigmas_ && image_free, true, feature != nullptr);
    c.blocks = {head_block_};
    if (image) c.blocks.push_back(image_block_);
    c.blocks.push_back(row_block_);
    if (feature) {
      c.cost = StereoPixelFeatureCalibrationFactor::Create(config_.observation_model.rig, lm.position,
                                                           *measured.pixels, measured.slide_gain, measured.head_pan,
                                                           C, residuals, image, rate);
      std::vector<int> entries;
      if (feature->sigma.column > 0) entries.push_back(0);
      if (feature->sigma.disparity > 0) entries.push_back(1);
      if (entries.size() < StereoPixelFeatureCalibrationFactor::kOffsetSize) c.cost = new HeldEntries(c.cost, entries);
      c.blocks.push_back(feature->block);
    } else {
      c.cost = StereoPixelRowCalibrationFactor::Create(config_.observation_model.rig, lm.position, *measured.pixels,
                                                       measured.slide_gain, measured.head_pan, C, residuals, image,
                                                       rate);
    }
    return withField(c);
  }
  const Eigen::Matrix4d C =
      calibratedPixelCovariance(measured, lm, config_.observation_model, image_sigmas_ && image_free);
  if (image) {
    c.cost = StereoPixelImageCalibrationFactor::Create(config_.observation_model.rig, lm.position, *measured.pixels,
                                                       measured.head_pan, C, residuals, *image, rate);
    c.blocks = {head_block_, image_block_};
  } else {
    c.cost = StereoPixelCalibrationFactor::Create(config_.observation_model.rig, lm.position, *measured.pixels,
                                                  measured.head_pan, C, residuals);
    c.blocks = {head_block_};
  }
  return withField(c);
}

void SlidingWindowSmoother::addObservationFactor(const Observation& measured, const Landmark& lm, Node* node) {
  if (config_.calibration.stereo && measured.pixels) {
    CalibratedCost c = stereoCalibrationCost(measured, lm, node->rate, image_free_);
    addFactor(c.cost, {node}, true, std::move(c.blocks));
    if (exposureRatesFromPoses()) {
      factors_.back()->rate_sighting = measured;
      factors_.back()->rate_landmark = &lm;
      factors_.back()->rate_image_free = image_free_;
    }
  } else if (config_.calibration.range && isRangeBearingFactor(measured, config_.observation_model)) {
    addFactor(RangeBearingCalibrationFactor::Create(lm.xy(), measured.z(), measured.covariance), {node}, true,
              {range_block_});
  } else {
    addFactor(makeObservationFactor(measured, lm, config_.observation_model), {node}, true);
  }
}

bool SlidingWindowSmoother::exposureRatesFromPoses() const {
  return config_.exposure_rate == BodyRateSource::SmoothedPoses && image_sigmas_ &&
         (*image_sigmas_)[stereo_pixel_calibration::kExposureOffsetEntry] > 0;
}

// As the batch's ratesFromSolution (solvers/batch_solve.cpp), over the window's poses: the
// central difference of the neighbours' estimates, the rate's sigma that of the odometry's
// rotation between them (an upper bound of the smoothed difference's). Neighbours further apart
// than the wheels' averaging window would give a rate no better than the wheels': the pose keeps
// its own.
void SlidingWindowSmoother::refreshExposureRates() {
  if (!exposureRatesFromPoses() || nodes_.size() < 3) return;
  std::vector<char> refreshed(nodes_.size(), 0);
  for (size_t i = 1; i + 1 < nodes_.size(); ++i) {
    const Node& a = *nodes_[i - 1];
    Node& k = *nodes_[i];
    const Node& b = *nodes_[i + 1];
    const double dt = b.t - a.t;
    if (!(dt > 0) || dt > BodyRateTracker::kDefaultWindowS) continue;
    k.rate = bodyRateBetween(poseOf(a.x), poseOf(b.x), dt,
                             a.rel_to_next_covariance(2, 2) + k.rel_to_next_covariance(2, 2));
    refreshed[i] = 1;
  }
  for (size_t i = 0; i < nodes_.size(); ++i) nodes_[i]->slot = static_cast<int>(i);
  for (const auto& f : factors_) {
    if (!f->rate_sighting || !refreshed[static_cast<size_t>(f->nodes[0]->slot)]) continue;
    CalibratedCost c = stereoCalibrationCost(*f->rate_sighting, *f->rate_landmark, f->nodes[0]->rate,
                                             f->rate_image_free);
    problem_->RemoveResidualBlock(f->id);
    f->cost.reset(c.cost);
    std::vector<double*> blocks{f->nodes[0]->x.data()};
    for (Calib b : f->calib) blocks.push_back(calibData(b));
    f->id = problem_->AddResidualBlock(f->cost.get(), f->robust ? loss_.get() : nullptr, blocks);
  }
}

bool SlidingWindowSmoother::fuseObservation(const Observation& measured, Node* node, Pose2& pose, Eigen::Matrix3d& P,
                                            std::vector<int>& used, ObservationTest test, double* e2) {
  // With the stereo head self-calibrated, gate, association and the belief update see the
  // observation through a calibration with its uncertainty in R (calibratedObservation): the
  // given calibration's range bias (a disparity offset of 1.5 px is 18 % of range at 1 m) would
  // otherwise gate out exactly the sightings that determine the calibration. First through the
  // current estimate; a sighting it gates is tested again through the prior (the nominal
  // calibration with the stated uncertainty, which holds the true one by construction): the
  // estimate from few landmarks can be confidently wrong along a combination of parameters they
  // do not separate (a disparity offset against the focal ratio, seen at one bearing), and then
  // gates out the landmark that would separate them.
  const std::vector<Observation> views = gateViews(measured);
  if (views.empty()) return false;
  const Landmark* lm = landmarkOf(measured, views.front(), pose, P, used);
  if (!lm) return false;
  Matrix23d Hz;
  Eigen::Vector2d zhat;
  try {
    zhat = predictRangeBearing(pose, lm->xy(), &Hz);  // (5.27)
  } catch (const GeometryError&) {
    return false;
  }
  const Observation* obs = nullptr;
  Eigen::Vector2d nu;
  Eigen::Matrix2d Sinv;
  const Eigen::Matrix<double, 3, 2> PHt = P * Hz.transpose();
  for (const Observation& v : views) {
    nu = rangeBearingInnovation(v.z(), zhat);
    const Eigen::Matrix2d S = Hz * PHt + v.covariance;  // (5.14)
    Sinv = S.inverse();
    const double d2 = nu.dot(Sinv * nu);  // (5.20)
    if (!std::isfinite(d2)) continue;
    if (!gate_enabled_ || test == ObservationTest::None ||
        (test == ObservationTest::Retest ? d2 <= retest_threshold_ : gate_.accepts(d2))) {
      obs = &v;
      if (e2) *e2 = d2;
      break;
    }
  }
  if (!obs) return false;
  addObservationFactor(measured, *lm, node);
  node->landmarks.push_back(lm->id);
  // The belief for the next gate test, as the EKF's sequential update (5.15), (5.17).
  const Eigen::Matrix<double, 3, 2> K = PHt * Sinv;
  pose = plus(pose, K * nu);
  const Eigen::Matrix3d IKH = Eigen::Matrix3d::Identity() - K * Hz;
  P = IKH * P * IKH.transpose() + K * obs->covariance * K.transpose();
  return true;
}

double SlidingWindowSmoother::jointThreshold(int dof) {
  if (static_cast<int>(joint_thresholds_.size()) <= dof) joint_thresholds_.resize(static_cast<size_t>(dof) + 1, 0.0);
  double& t = joint_thresholds_[static_cast<size_t>(dof)];
  if (!(t > 0)) t = chi2Quantile(config_.gate.probability, dof);
  return t;
}

std::vector<bool> SlidingWindowSmoother::fuseStep(const Step& step, Node* node, const Pose2& pred,
                                                  const Eigen::Matrix3d& P_pred, Pose2& pose, Eigen::Matrix3d& P,
                                                  bool* compass_fused) {
  // Joint compatibility as in Ekf::process (5.20; Neira and Tardos, IEEE T-RA 17(6), 2001): one
  // gate per observation at the sequential belief fails every sighting of a step at once when the
  // prediction sits in its prior's tail, and the window would then dead-reckon from a wrong start
  // until the lost policy restarts it and leaves those poses unsmoothed.
  const size_t n = step.observations.size();
  const bool with_compass = step.compass.has_value() && config_.use_compass;
  const size_t first_factor = factors_.size();
  const size_t first_landmark = node->landmarks.size();
  std::vector<bool> excluded(n + 1, false);  // n: the compass
  std::vector<bool> accepted(n, false);
  std::vector<int> landmark_of(n, -1);
  for (;;) {
    // The step's factors; a feature block's prior, created with its first sighting, stays with
    // the block (it is global).
    for (size_t i = factors_.size(); i-- > first_factor;)
      if (!factors_[i]->nodes.empty()) removeFactor(i);
    node->landmarks.resize(first_landmark);
    pose = pred;
    P = P_pred;
    std::fill(accepted.begin(), accepted.end(), false);
    *compass_fused = false;
    double e2 = 0.0;
    int dof = 0;
    if (with_compass && !excluded[n]) {
      const double sigma2 = step.compass_sigma * step.compass_sigma;
      const double nu = angleDiff(*step.compass, pose.theta);
      const double S = P(2, 2) + sigma2;
      addFactor(CompassFactor::Create(*step.compass, step.compass_sigma), {node});
      const Eigen::Vector3d K = P.col(2) / S;  // (5.19), H = [0 0 1]
      pose = plus(pose, K * nu);
      Eigen::Matrix3d IKH = Eigen::Matrix3d::Identity();
      IKH.col(2) -= K;
      P = IKH * P * IKH.transpose() + sigma2 * K * K.transpose();
      e2 += nu * nu / S;
      dof += 1;
      *compass_fused = true;
    }
    std::vector<int> used;
    for (const Observation& o : step.observations)
      if (o.landmark_id >= 0) used.push_back(o.landmark_id);
    for (size_t i = 0; i < n; ++i) {
      if (excluded[i]) continue;
      double d2 = 0.0;
      accepted[i] = fuseObservation(step.observations[i], node, pose, P, used, ObservationTest::None, &d2);
      if (!accepted[i]) continue;
      landmark_of[i] = node->landmarks.back();
      e2 += d2;
      dof += 2;
    }
    if (!gate_enabled_ || dof == 0 || e2 <= jointThreshold(dof)) break;
    // The fused one with the largest e^2 at the prediction is set aside.
    double worst = -1.0;
    size_t worst_index = n;
    if (*compass_fused) worst = std::pow(angleDiff(*step.compass, pred.theta), 2) /
                                (P_pred(2, 2) + step.compass_sigma * step.compass_sigma);
    for (size_t i = 0; i < n; ++i) {
      if (!accepted[i]) continue;
      const std::vector<Observation> views = gateViews(step.observations[i]);
      std::optional<RangeBearingInnovation> g;
      if (!views.empty())
        g = rangeBearingInnovationAt(pred, P_pred, views.front().z(), views.front().covariance,
                                     map_.at(landmark_of[i]).xy());
      const double e2p = g ? g->mahalanobis_squared : std::numeric_limits<double>::infinity();
      if (e2p > worst) {
        worst = e2p;
        worst_index = i;
      }
    }
    excluded[worst_index] = true;
  }
  return accepted;
}

int SlidingWindowSmoother::retestGated() {
  if (lost_ || !gate_enabled_ || !config_.retest_gated) return 0;
  if (std::none_of(nodes_.begin(), nodes_.end(),
                   [](const auto& n) { return !n->gated.empty() || n->gated_compass.has_value(); }))
    return 0;
  computeCovariances(true);
  int fused = 0;
  for (const auto& n : nodes_) {
    const int before = fused;
    if (n->gated_compass) {
      const auto [compass, sigma] = *n->gated_compass;
      const double nu = angleDiff(compass, n->x[2]);
      if (nu * nu / (n->covariance(2, 2) + sigma * sigma) <= retest_threshold_compass_) {
        addFactor(CompassFactor::Create(compass, sigma), {n.get()});
        n->gated_compass.reset();
        ++fused;
      }
    }
    if (!n->gated.empty()) fused += retestObservations(*n);
    if (fused > before && n->status == EstimateStatus::Predicted) n->status = EstimateStatus::Tracking;
  }
  if (fused > 0) solve(config_.max_iterations);
  return fused;
}

int SlidingWindowSmoother::retestObservations(Node& node) {
  // The marginal holds all the window's data but these observations: a valid prediction of them.
  Pose2 pose = poseOf(node.x);
  Eigen::Matrix3d P = node.covariance;
  std::vector<int> used = node.landmarks;
  for (const Observation& o : node.gated)
    if (o.landmark_id >= 0) used.push_back(o.landmark_id);
  std::vector<Observation> gated;
  gated.swap(node.gated);
  int fused = 0;
  for (const Observation& obs : gated) {
    if (fuseObservation(obs, &node, pose, P, used, ObservationTest::Retest)) {
      ++fused;
      ++stats_.accepted_observations;
      --stats_.rejected_observations;
      ++stats_.readmitted_observations;
    } else {
      node.gated.push_back(obs);
    }
  }
  return fused;
}

void SlidingWindowSmoother::addOdometry(Node* a, Node* b, const std::vector<Intermediate>& between, const Pose2& rel,
                                        const Eigen::Matrix3d& C) {
  if (!config_.calibration.odometry) {
    addFactor(OdometryFactor::Create(Eigen::Vector3d(rel.x, rel.y, rel.theta), C), {a, b});
  } else {
    const double slip = config_.observation_model.unmodelled.slip_rel_sigma;
    std::vector<std::pair<double, double>> readings;
    std::vector<WheelIncrements> noise;
    for (const Intermediate& q : between) {
      readings.emplace_back(q.d_left, q.d_right);
      noise.push_back(q.noise);
    }
    readings.emplace_back(b->d_left, b->d_right);
    noise.push_back(b->noise);
    std::vector<OdometryParams> params;
    for (const WheelIncrements& t : noise) params.push_back(withSlip(odometry_, t.d_left, t.d_right, slip));
    if (readings.size() == 1)  // wheel space, as the batch (see odometry_calibration_factor.h)
      addFactor(OdometryCalibrationFactor::Create(b->d_left, b->d_right, b->noise, params[0]), {a, b}, false,
                {wheels_block_});
    else
      addFactor(ComposedOdometryCalibrationFactor::Create(readings, noise, params), {a, b}, false, {wheels_block_});
  }
  factors_.back()->odometry = true;
}

Estimate SlidingWindowSmoother::current() const {
  Estimate e;
  if (nodes_.empty()) {
    e.step = last_step_;
    e.status = EstimateStatus::Uninitialised;
    return e;
  }
  const Node& k = *nodes_.back();
  if (k.after.empty() || k.after.back().step != last_step_) return estimateOf(k);
  const Intermediate& m = k.after.back();
  Matrix3d J1, J2;
  e.step = m.step;
  e.t = m.t;
  e.status = m.status;
  e.pose = compose(poseOf(k.x), m.rel, &J1, &J2);
  e.covariance = composedCovariance(k, J1, J2, m.rel_covariance, m.rel_wheels);
  return e;
}

Estimate SlidingWindowSmoother::process(const Step& step) {
  if (finished_) throw Error("sliding window: process() after finish()");
  if (have_step_ && step.step <= last_step_)
    throw Error("sliding window: step " + std::to_string(step.step) + " does not follow step " +
                std::to_string(last_step_));
  validateStep(step, "sliding window");
  for (size_t i = 0; i < step.observations.size(); ++i) {
    const int id = step.observations[i].landmark_id;
    if (id >= 0 && !map_.find(id))
      throw Error("sliding window: step " + std::to_string(step.step) + ": observation " + std::to_string(i) +
                  ": unknown landmark id " + std::to_string(id));
  }
  if (have_step_ && wheels_block_ >= 0 && config_.observation_model.unmodelled.wheelsDrift())
    wheels_walked_ += wheelDriftVariance(config_.observation_model.unmodelled, step.d_left, step.d_right,
                                         odometry_.wheel_base_mm);
  takeCheckpoint();
  try {
    return track(step, noise_travel_.next(step.d_left, step.d_right));
  } catch (...) {
    abandonWindow(step.step);
    throw;
  }
}

Estimate SlidingWindowSmoother::track(const Step& step, const WheelIncrements& noise) {
  const bool first = !have_step_;
  have_step_ = true;
  last_step_ = step.step;
  if (image_sigmas_)  // the image block's exposure offset is the rate's only reader
    step_rate_ = stepBodyRate(rate_tracker_, step, odometry_, config_.observation_model.unmodelled.slip_rel_sigma);
  ++stats_.steps;
  image_free_ = image_sigmas_ && stats_.steps > config_.image_errors_after_steps;
  keepForRestart(step, noise);

  StepBelief b;
  if (nodes_.empty()) {
    if (!first || config_.init.mode == InitMode::Global) return startFromGlobalFix(step);
    startWindow(step, config_.init.pose, config_.init.covariance, EstimateStatus::Tracking);
    b.pose = config_.init.pose;
    b.P = nodes_.back()->covariance;
    b.pred_pose = b.pose;
    b.pred_P = b.P;
  } else {
    b = predictFromNewestKeyframe(step);
    const bool keyframe = config_.keyframe_max_steps <= 1 || !step.observations.empty() ||
                          (step.compass && config_.use_compass) || steps_since_keyframe_ >= config_.keyframe_max_steps;
    if (!keyframe) return recordIntermediate(step, noise, b);
    appendKeyframe(step, noise, b.pose);
  }
  Node* node = nodes_.back().get();

  if (lost_ && config_.reinitialise_when_lost) {
    // Still lost: a global fix re-anchors the window when it agrees with the prediction (the
    // dead-reckoned poses since the loss are then smoothed with the sightings they had gated),
    // and restarts it otherwise.
    const std::optional<PoseFix> fix = config_.global_fix ? config_.global_fix(step, map_) : std::nullopt;
    if (fix && fix->pose.isFinite() && positiveDefinite(fix->covariance)) {
      node->gated.insert(node->gated.end(), step.observations.begin(), step.observations.end());
      stats_.rejected_observations += static_cast<long>(step.observations.size());
      return recoverFromLoss(step, *fix, b.pred_pose, b.pred_P);
    }
  }

  bool fused = false;
  if (!lost_) {
    if (std::optional<Estimate> recovered = fuseUnderGate(step, node, b, &fused)) return *recovered;
  }
  node->status = lost_ ? EstimateStatus::Lost : (fused ? EstimateStatus::Tracking : EstimateStatus::Predicted);
  refreshExposureRates();
  while (static_cast<int>(nodes_.size()) > config_.window) marginaliseOldest();
  solve(config_.max_iterations);
  retestGated();
  computeCovariances(false);
  return estimateOf(*nodes_.back());
}

void SlidingWindowSmoother::keepForRestart(const Step& step, const WheelIncrements& noise) {
  if (config_.restart_buffer_steps <= 0) return;
  recent_.push_back(RecentStep{step, noise});
  recent_.back().step.observations.clear();
  if (static_cast<int>(recent_.size()) > config_.restart_buffer_steps) recent_.pop_front();
}

SlidingWindowSmoother::StepBelief SlidingWindowSmoother::predictFromNewestKeyframe(const Step& step) {
  const Node* prev = nodes_.back().get();
  // The odometry since the newest keyframe (5.9 from the identity), and the prediction
  // p_K (+) u with P = J1 P_K J1^T + J2 U J2^T: for one step this is predictPose itself.
  const PosePrediction rel = predictStep(rel_, rel_covariance_, step.d_left, step.d_right, &rel_wheels_);
  rel_ = rel.pose;
  rel_covariance_ = rel.covariance;
  ++steps_since_keyframe_;
  Matrix3d J1, J2;
  StepBelief b;
  b.pose = compose(poseOf(prev->x), rel_, &J1, &J2);
  b.P = composedCovariance(*prev, J1, J2, rel_covariance_, rel_wheels_);
  b.pred_pose = b.pose;
  b.pred_P = b.P;
  return b;
}

Estimate SlidingWindowSmoother::recordIntermediate(const Step& step, const WheelIncrements& noise,
                                                   const StepBelief& b) {
  Intermediate m;
  m.step = step.step;
  m.t = step.t;
  m.rel = rel_;
  m.rel_covariance = rel_covariance_;
  m.rel_wheels = rel_wheels_;
  m.status = lost_ ? EstimateStatus::Lost : EstimateStatus::Predicted;
  m.d_left = step.d_left;
  m.d_right = step.d_right;
  m.noise = noise;
  m.rate = step_rate_;
  nodes_.back()->after.push_back(m);
  return stepEstimate(step, b.pose, b.P, m.status);
}

void SlidingWindowSmoother::appendKeyframe(const Step& step, const WheelIncrements& noise, const Pose2& pose) {
  Node* prev = nodes_.back().get();
  auto node = std::make_unique<Node>();
  node->step = step.step;
  node->t = step.t;
  node->x = {pose.x, pose.y, pose.theta};
  node->d_left = step.d_left;
  node->d_right = step.d_right;
  node->noise = noise;
  node->rate = step_rate_;
  Node* n = node.get();
  nodes_.push_back(std::move(node));
  problem_->AddParameterBlock(n->x.data(), 3, &manifold_);
  prev->rel_to_next = rel_;
  prev->rel_to_next_covariance = rel_covariance_;
  addOdometry(prev, n, prev->after, rel_, rel_covariance_);
  rel_ = Pose2();
  rel_covariance_.setZero();
  rel_wheels_.setZero();
  steps_since_keyframe_ = 0;
  ++stats_.keyframes;
}

std::optional<Estimate> SlidingWindowSmoother::fuseUnderGate(const Step& step, Node* node, StepBelief& b,
                                                            bool* fused) {
  bool compass_fused = false;
  const std::vector<bool> accepted = fuseStep(step, node, b.pred_pose, b.pred_P, b.pose, b.P, &compass_fused);
  *fused = compass_fused;
  if (step.compass && config_.use_compass && !compass_fused) node->gated_compass = {*step.compass, step.compass_sigma};
  for (size_t i = 0; i < step.observations.size(); ++i) {
    *fused = *fused || accepted[i];
    ++(accepted[i] ? stats_.accepted_observations : stats_.rejected_observations);
    if (!accepted[i]) node->gated.push_back(step.observations[i]);
    if (!gate_enabled_ || !gate_.record(accepted[i])) continue;
    lost_ = true;  // (5.1.3)
    if (config_.reinitialise_when_lost) {
      const std::optional<PoseFix> fix = globalFix(step);
      if (fix && fix->pose.isFinite() && positiveDefinite(fix->covariance)) {
        // The step's fused observations stay as factors of its pose (the reanchored window
        // keeps them; a restart drops the pose); the rest are set aside with it.
        for (size_t j = i + 1; j < step.observations.size(); ++j)
          if (!accepted[j]) node->gated.push_back(step.observations[j]);
        for (size_t j = i + 1; j < step.observations.size(); ++j)
          ++(accepted[j] ? stats_.accepted_observations : stats_.rejected_observations);
        return recoverFromLoss(step, *fix, b.pred_pose, b.pred_P);
      }
    }
    for (size_t j = i + 1; j < step.observations.size(); ++j) {
      ++(accepted[j] ? stats_.accepted_observations : stats_.rejected_observations);
      if (!accepted[j]) node->gated.push_back(step.observations[j]);
    }
    break;
  }
  return std::nullopt;
}

std::vector<Estimate> SlidingWindowSmoother::finish() {
  if (!finished_) {
    if (!nodes_.empty() && config_.final_iterations > 0) {
      refreshExposureRates();
      solve(config_.final_iterations);
    }
    finaliseWindow();
    finished_ = true;
  }
  return history_;
}

}  // namespace stereoloc
