// The batch smoother's solve (BatchSmoother::finish): the factors of the buffered steps, and the
// phases from the first solve to the marginal covariances (docs/estimators.md, "Smoothers").
#include "solvers/batch_smoother.h"

#include <ceres/covariance.h>
#include <ceres/solver.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <limits>
#include <map>
#include <memory>
#include <unordered_map>
#include <utility>

#include "factors/calibration_prior_factor.h"
#include "factors/compass_factor.h"
#include "factors/field_shifted_factor.h"
#include "factors/joined_global_blocks.h"
#include "factors/odometry_calibration_factor.h"
#include "factors/range_bearing_calibration_factor.h"
#include "factors/stereo_pixel_calibration_factor.h"
#include "factors/stereo_pixel_feature_calibration_factor.h"
#include "factors/stereo_pixel_image_calibration_factor.h"
#include "factors/stereo_pixel_row_calibration_factor.h"
#include "factors/odometry_factor.h"
#include "factors/pose_manifold.h"
#include "factors/pose_prior_factor.h"
#include "solvers/calibrated_models.h"
#include "solvers/chain_solver.h"
#include "src/core/angles.h"
#include "src/core/error.h"
#include "src/core/gaussian.h"
#include "src/core/measurement_model.h"

namespace stereoloc {

namespace {

using Clock = std::chrono::steady_clock;

double secondsSince(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

// The factors touching poses [lo, hi) as a ceres::Problem over those poses, the neighbours
// lo-1 and hi held constant, and over the global blocks (held constant unless free_globals)
// (BatchSolver::Ceres, and ceres::Covariance).
std::unique_ptr<ceres::Problem> makeCeresProblem(const ChainFactorSource& source, ceres::LossFunction* loss,
                                                 const ceres::Manifold* manifold, size_t lo, size_t hi,
                                                 std::vector<double>* x, std::vector<double>* globals,
                                                 bool free_globals) {
  ceres::Problem::Options popts;
  popts.manifold_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  popts.loss_function_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  auto problem = std::make_unique<ceres::Problem>(popts);
  double* X = x->data();
  for (size_t i = lo; i < hi; ++i) problem->AddParameterBlock(X + 3 * i, 3, const_cast<ceres::Manifold*>(manifold));
  std::vector<double*> global_blocks;
  {
    int offset = 0;
    for (int size : source.globalBlockSizes()) {
      global_blocks.push_back(globals->data() + offset);
      problem->AddParameterBlock(global_blocks.back(), size);
      if (!free_globals) problem->SetParameterBlockConstant(global_blocks.back());
      offset += size;
    }
  }
  auto add = [&](ChainFactor& f, std::vector<double*> blocks) {
    if (f.global >= 0) blocks.push_back(global_blocks[static_cast<size_t>(f.global)]);
    problem->AddResidualBlock(f.cost.release(), f.robust ? loss : nullptr, blocks);
  };
  std::vector<ChainFactor> unary;
  auto addBinary = [&](size_t i) {
    ChainFactor b = source.binaryFactor(i);
    if (!b.cost) return;
    add(b, {X + 3 * (i - 1), X + 3 * i});
    for (size_t j : {i - 1, i})
      if (j < lo || j >= hi) problem->SetParameterBlockConstant(X + 3 * j);
  };
  for (size_t i = lo; i < hi; ++i) {
    unary.clear();
    source.unaryFactors(i, &unary);
    for (ChainFactor& f : unary) add(f, {X + 3 * i});
    if (i > 0) addBinary(i);
  }
  if (hi < source.size() && hi > lo) addBinary(hi);
  unary.clear();
  source.globalFactors(&unary);
  for (ChainFactor& f : unary) add(f, {});
  return problem;
}

}  // namespace

// The factors of the buffered steps, made on demand (a million-step problem does not hold
// millions of cost functions). Pose i is steps_[first + i].
class BatchSmoother::StepFactorSource final : public ChainFactorSource {
 public:
  StepFactorSource(const BatchSmoother& smoother, size_t first, size_t n)
      : b_(smoother), first_(first), n_(n),
        prior_covariance_(0.5 * (b_.prior_covariance_ + b_.prior_covariance_.transpose())), cut_(n, 0),
        left_out_(b_.observations_.size(), 0) {
    if (b_.config_.calibration.odometry) {
      odometry_block_ = static_cast<int>(sizes_.size());
      sizes_.push_back(3);
    }
    if (b_.config_.calibration.stereo) {
      stereo_block_ = static_cast<int>(sizes_.size());
      image_sigmas_ = imageErrorSigmas(b_.config_.calibration, b_.config_.observation_model.unmodelled);
      row_sigma_ = rowOffsetSigma(b_.config_.calibration, b_.config_.observation_model.unmodelled);
      features_ = featureOffsetSigmas(b_.map_, b_.config_.calibration, b_.config_.observation_model.unmodelled);
      // After (q, [e,] dv): per feature its column offset, then its u_r offset, where stated.
      int next = kStereo + (image_sigmas_ ? kImage : 0) + (row_sigma_ ? 1 : 0);
      for (const FeatureOffsetPrior& f : features_) {
        std::array<int, 2>& at = feature_index_[f.landmark_id];
        at[0] = f.sigma.column > 0 ? next++ : -1;
        at[1] = f.sigma.disparity > 0 ? next++ : -1;
      }
      if (b_.config_.calibration.field) {
        if (!derivesFromGeometry(b_.map_))
          throw Error("batch smoother: --calibrate field needs a MiroSot map as its field geometry derives it; map '" +
                      b_.map_.name() + "' is not");
        field_index_ = next;
        next += kFieldDimensionCount;
        field_jacobian_ = b_.map_.fieldJacobians();
      }
      sizes_.push_back(next);
    }
    if (b_.config_.calibration.range) {
      range_block_ = static_cast<int>(sizes_.size());
      sizes_.push_back(RangeBearingCalibrationFactor::kCalibrationSize);
    }
  }

  size_t size() const override { return n_; }
  void unaryFactors(size_t i, std::vector<ChainFactor>* out) const override {
    if (i == 0)
      out->push_back({std::unique_ptr<ceres::CostFunction>(PosePriorFactor::Create(b_.prior_pose_, prior_covariance_)), false});
    const size_t k = first_ + i;
    const BufferedStep& st = b_.steps_[k];
    if (st.compass_sigma > 0 && b_.config_.use_compass)
      out->push_back({std::unique_ptr<ceres::CostFunction>(CompassFactor::Create(st.compass, st.compass_sigma)), false});
    for (size_t o = b_.observationsBegin(k); o < st.observations_end; ++o)
      if (b_.observations_[o].landmark_id >= 0 && !left_out_[o]) out->push_back(observationFactor(o));
  }
  // The factor of observation o (index into observations_, identified), on its pose and, with
  // stereo self-calibration and pixels, the stereo block.
  ChainFactor observationFactor(size_t o) const {
    const ObservationModelConfig& model = b_.config_.observation_model;
    const Observation& obs = b_.observations_[o];
    const Landmark& landmark = b_.map_.at(obs.landmark_id);
    if (stereo_block_ >= 0 && obs.pixels) {
      const PixelResiduals residuals =
          model.model == ObservationModel::Pixels ? PixelResiduals::All : PixelResiduals::Columns;
      const auto feature = feature_index_.find(obs.landmark_id);
      const bool offset = row_sigma_ && feature != feature_index_.end();
      const Eigen::Matrix4d C =
          calibratedPixelCovariance(obs, landmark, model, image_sigmas_.has_value(), row_sigma_.has_value(), offset);
      const auto* image = image_sigmas_ ? &*image_sigmas_ : nullptr;
      const BodyRate& rate = b_.stepOf(o).rate;
      // The field's entries close the joined block; the inner factor sees the block before them.
      const int joined = field_index_ >= 0 ? field_index_ : sizes_[static_cast<size_t>(stereo_block_)];
      const auto withField = [&](ChainFactor f) {
        if (field_index_ < 0) return f;
        // (pose, g) -> (pose, g, f) -> (pose, [g f]): f at its place in the joined block.
        const int g = f.cost->parameter_block_sizes()[1];
        std::vector<std::vector<int>> indices(2);
        for (int i = 0; i < g; ++i) indices[0].push_back(i);
        for (int i = 0; i < kFieldDimensionCount; ++i) indices[1].push_back(field_index_ + i);
        f.cost = std::make_unique<JoinedGlobalBlocks>(
            new FieldShiftedFactor(f.cost.release(), field_jacobian_.at(obs.landmark_id)), std::move(indices),
            sizes_[static_cast<size_t>(stereo_block_)]);
        return f;
      };
      if (offset) {
        // (q, [e,] dv, (b_c, b_d)) at their places in the joined block (globalFactors).
        const int m = image_sigmas_ ? kImage : 0;
        std::vector<std::vector<int>> indices;
        auto range = [](int from, int n) {
          std::vector<int> r(static_cast<size_t>(n));
          for (int i = 0; i < n; ++i) r[static_cast<size_t>(i)] = from + i;
          return r;
        };
        indices.push_back(range(0, kStereo));
        if (image_sigmas_) indices.push_back(range(kStereo, kImage));
        indices.push_back({kStereo + m});
        indices.push_back({feature->second[0], feature->second[1]});
        return withField({std::make_unique<JoinedGlobalBlocks>(
                    StereoPixelFeatureCalibrationFactor::Create(model.rig, landmark.position, *obs.pixels,
                                                                obs.slide_gain, obs.head_pan, C, residuals, image,
                                                                rate),
                    std::move(indices), joined),
                true, stereo_block_});
      }
      if (row_sigma_)
        return withField({std::make_unique<JoinedGlobalBlocks>(
                    StereoPixelRowCalibrationFactor::Create(model.rig, landmark.position, *obs.pixels, obs.slide_gain,
                                                            obs.head_pan, C, residuals, image, rate),
                    std::vector<std::vector<int>>{}, joined),
                true, stereo_block_});
      if (image_sigmas_)
        return withField({std::make_unique<JoinedGlobalBlocks>(StereoPixelImageCalibrationFactor::Create(
                    model.rig, landmark.position, *obs.pixels, obs.head_pan, C, residuals, *image_sigmas_, rate)),
                true, stereo_block_});
      return withField({std::unique_ptr<ceres::CostFunction>(StereoPixelCalibrationFactor::Create(
                  model.rig, landmark.position, *obs.pixels, obs.head_pan, C, residuals)),
              true, stereo_block_});
    }
    if (range_block_ >= 0 && isRangeBearingFactor(obs, model))
      return {std::unique_ptr<ceres::CostFunction>(
                  RangeBearingCalibrationFactor::Create(landmark.xy(), obs.z(), obs.covariance)),
              true, range_block_};
    return {std::unique_ptr<ceres::CostFunction>(makeObservationFactor(obs, landmark, model)), true};
  }
  // Whether observation o's factor can be evaluated with pose i at `pose` and the global blocks
  // at `globals` (a pixel factor cannot when the landmark is behind the cameras).
  bool evaluable(size_t o, const double* pose, const std::vector<double>& globals) const {
    double cost;
    return observationCost(o, pose, globals, &cost);
  }
  // Observation o's 1/2 |r|^2 (whitened, no robust loss) there; false where not evaluable.
  bool observationCost(size_t o, const double* pose, const std::vector<double>& globals, double* cost) const {
    const ChainFactor f = observationFactor(o);
    const double* params[2] = {pose, nullptr};
    if (f.global >= 0) {
      size_t offset = 0;
      for (int k = 0; k < f.global; ++k) offset += static_cast<size_t>(sizes_[static_cast<size_t>(k)]);
      params[1] = globals.data() + offset;
    }
    const int m = f.cost->num_residuals();
    Eigen::VectorXd r(m);
    if (!f.cost->Evaluate(params, r.data(), nullptr) || !r.allFinite()) return false;
    *cost = 0.5 * r.squaredNorm();
    return true;
  }
  // Observation o (index into observations_) is left out of the problem (true) or in it.
  void setLeftOut(size_t o, bool left_out) { left_out_[o] = left_out ? 1 : 0; }
  bool leftOut(size_t o) const { return left_out_[o] != 0; }
  ChainFactor binaryFactor(size_t i) const override {
    if (i == 0 || cut_[i]) return {};
    const BufferedStep& st = b_.steps_[first_ + i];
    if (odometry_block_ >= 0) {
      const OdometryParams at_noise = withSlip(b_.odometry_, st.noise.d_left, st.noise.d_right, b_.config_.slip_rel_sigma);
      return {std::unique_ptr<ceres::CostFunction>(
                  OdometryCalibrationFactor::Create(st.d_left, st.d_right, st.noise, at_noise)),
              false, odometry_block_};
    }
    const OdometryParams odometry = withSlip(b_.odometry_, st.d_left, st.d_right, b_.config_.slip_rel_sigma);
    return {std::unique_ptr<ceres::CostFunction>(OdometryFactor::Create(st.d_left, st.d_right, odometry)), false};
  }
  std::vector<int> globalBlockSizes() const override { return sizes_; }
  void globalFactors(std::vector<ChainFactor>* out) const override {
    const SelfCalibrationConfig& c = b_.config_.calibration;
    if (odometry_block_ >= 0) {
      const Eigen::Vector3d sigma(c.wheel_scale_sigma, c.wheel_scale_sigma, c.wheel_base_rel_sigma * b_.odometry_.wheel_base_mm);
      out->push_back({std::unique_ptr<ceres::CostFunction>(CalibrationPriorFactor<3>::Create(
                          nominalWheels(), sigma.cwiseAbs2().asDiagonal().toDenseMatrix())),
                      false, odometry_block_});
    }
    if (stereo_block_ >= 0) {
      CalibrationEstimate::StereoVector sigma;
      sigma << c.tilt_sigma_rad, c.baseline_scale_sigma, c.disparity_offset_sigma_px, c.column_offset_sigma_px,
          c.focal_ratio_sigma, c.focal_scale_sigma;
      if (row_sigma_ || field_index_ >= 0) {
        // The joined block (q, [e,] [dv, b_1..b_K,] [f]): e whitened (prior the identity), dv,
        // the feature offsets and the field's dimensions with their stated sigmas.
        const int m = image_sigmas_ ? kImage : 0;
        const int size = sizes_[static_cast<size_t>(stereo_block_)];
        Eigen::VectorXd joined = Eigen::VectorXd::Zero(size), sd(size);
        joined.head<kStereo>() = nominalHead();
        sd.head<kStereo>() = sigma;
        sd.segment(kStereo, m).setOnes();
        if (row_sigma_) sd[kStereo + m] = *row_sigma_;
        for (const FeatureOffsetPrior& f : features_) {
          const std::array<int, 2>& at = feature_index_.at(f.landmark_id);
          if (at[0] >= 0) sd[at[0]] = f.sigma.column;
          if (at[1] >= 0) sd[at[1]] = f.sigma.disparity;
        }
        if (field_index_ < 0) {
          out->push_back({std::make_unique<DiagonalPriorFactor>(joined, sd), false, stereo_block_});
        } else {
          // A measured field's dimensions are correlated: the block's prior is dense there.
          Eigen::MatrixXd covariance = Eigen::MatrixXd::Zero(size, size);
          covariance.diagonal() = sd.cwiseAbs2();
          covariance.block<kFieldDimensionCount, kFieldDimensionCount>(field_index_, field_index_) =
              fieldPriorCovariance(c, b_.map_);
          out->push_back({std::make_unique<DensePriorFactor>(joined, covariance), false, stereo_block_});
        }
      } else if (image_sigmas_) {
        // The image block is whitened (StereoPixelImageCalibrationFactor): its prior is the identity.
        Eigen::Matrix<double, kStereo + kImage, 1> joined;
        joined << nominalHead(), Eigen::Matrix<double, kImage, 1>::Zero();
        Eigen::Matrix<double, kStereo + kImage, 1> variance;
        variance << sigma.cwiseAbs2(), Eigen::Matrix<double, kImage, 1>::Ones();
        out->push_back({std::unique_ptr<ceres::CostFunction>(CalibrationPriorFactor<kStereo + kImage>::Create(
                            joined, variance.asDiagonal().toDenseMatrix())),
                        false, stereo_block_});
      } else {
        out->push_back({std::unique_ptr<ceres::CostFunction>(CalibrationPriorFactor<kStereo>::Create(
                            nominalHead(), sigma.cwiseAbs2().asDiagonal().toDenseMatrix())),
                        false, stereo_block_});
      }
    }
    if (range_block_ >= 0) {
      constexpr int k = RangeBearingCalibrationFactor::kCalibrationSize;
      out->push_back({std::unique_ptr<ceres::CostFunction>(CalibrationPriorFactor<k>::Create(
                          Eigen::Matrix<double, k, 1>::Zero(), rangePriorSigma(c).cwiseAbs2().asDiagonal().toDenseMatrix())),
                      false, range_block_});
    }
  }
  // The global blocks' nominal values, concatenated (the solver's start).
  std::vector<double> nominalGlobals() const {
    std::vector<double> g;
    const Eigen::Vector3d wheels = nominalWheels();
    const CalibrationEstimate::StereoVector head = nominalHead();
    if (odometry_block_ >= 0) g.insert(g.end(), wheels.data(), wheels.data() + 3);
    if (stereo_block_ >= 0) g.insert(g.end(), head.data(), head.data() + kStereo);
    if (image_sigmas_) g.insert(g.end(), static_cast<size_t>(kImage), 0.0);
    if (row_sigma_) g.push_back(0.0);
    if (stereo_block_ >= 0) g.resize(g.size() + static_cast<size_t>(sizes_[static_cast<size_t>(stereo_block_)]) -
                                     (kStereo + (image_sigmas_ ? kImage : 0) + (row_sigma_ ? 1 : 0)), 0.0);
    if (range_block_ >= 0) g.resize(g.size() + RangeBearingCalibrationFactor::kCalibrationSize, 0.0);
    return g;
  }
  // The image block's sigmas (whitened parameter i is sigma_i e_i), when estimated.
  const std::optional<CalibrationEstimate::ImageVector>& imageSigmas() const { return image_sigmas_; }
  // The feature offsets' landmarks and prior sigmas (px), and where each sits in the stereo block
  // (column, u_r; -1 where not estimated).
  const std::vector<FeatureOffsetPrior>& features() const { return features_; }
  std::array<int, 2> featureIndices(int landmark_id) const { return feature_index_.at(landmark_id); }
  // The row block's prior sigma (px), when estimated.
  const std::optional<double>& rowSigma() const { return row_sigma_; }
  // Where the field's dimensions sit in the stereo block; -1 when not estimated.
  int fieldIndex() const { return field_index_; }
  int odometryBlock() const { return odometry_block_; }
  int stereoBlock() const { return stereo_block_; }
  int rangeBlock() const { return range_block_; }
  int blockSize(int block) const { return sizes_[static_cast<size_t>(block)]; }
  // The odometry factor into pose i is removed (true) or restored.
  void setCut(size_t i, bool cut) { cut_[i] = cut ? 1 : 0; }

 private:
  const BatchSmoother& b_;
  size_t first_, n_;
  Eigen::Matrix3d prior_covariance_;
  std::vector<uint8_t> cut_;
  std::vector<uint8_t> left_out_;  // per observation in observations_
  std::vector<int> sizes_;
  int odometry_block_ = -1, stereo_block_ = -1, range_block_ = -1;
  std::optional<CalibrationEstimate::ImageVector> image_sigmas_;
  std::optional<double> row_sigma_;
  std::vector<FeatureOffsetPrior> features_;
  std::unordered_map<int, std::array<int, 2>> feature_index_;  // landmark id -> (column, u_r) index or -1
  int field_index_ = -1;  // of the field's dimensions in the stereo block
  std::unordered_map<int, FieldShiftedFactor::LandmarkJacobian> field_jacobian_;  // landmark id -> d(x, y)/d f
  Eigen::Vector3d nominalWheels() const { return Eigen::Vector3d(1.0, 1.0, b_.odometry_.wheel_base_mm); }
  static CalibrationEstimate::StereoVector nominalHead() { return CalibrationEstimate().head; }
  static constexpr int kStereo = StereoPixelCalibrationFactor::kCalibrationSize;
  static constexpr int kImage = StereoPixelImageCalibrationFactor::kImageErrorSize;
};

namespace {

// Poses either side of a cut in the windows that place and test it (a test grows its window
// fourfold until its decision is the full one).
constexpr size_t kCutWindowMargin = 256;

// Residual variance factor of the first solve above which the batch starts again, robust, from
// the filter pass's guess (BatchSmootherConfig::robust_start): whitened residuals three times
// their stated size. Calibrating solves of the realistic kidnap that found their basin have 1.6 to
// 2.6; those a lost filter's guess misled, 34 to 190.
constexpr double kRobustStartVarianceFactor = 10.0;

// Passes of pairing at the solution and solving again (Solve::solveReassociating).
constexpr int kReassociationPasses = 3;

// Cauchy scale of the robust start: 95 % efficiency on unit-variance whitened residuals.
constexpr double kRobustStartCauchyScale = 2.3849;

// The largest whitened residual of the calibration blocks' priors at `globals`: how many prior
// sigmas the furthest calibration parameter lies from its nominal value.
double calibrationPriorZ(const ChainFactorSource& source, const std::vector<double>& globals) {
  std::vector<ChainFactor> priors;
  source.globalFactors(&priors);
  const std::vector<int> sizes = source.globalBlockSizes();
  std::vector<size_t> offset(sizes.size() + 1, 0);
  for (size_t b = 0; b < sizes.size(); ++b) offset[b + 1] = offset[b] + static_cast<size_t>(sizes[b]);
  double worst = 0;
  for (const ChainFactor& f : priors) {
    const double* block = globals.data() + offset[static_cast<size_t>(f.global)];
    Eigen::VectorXd r(f.cost->num_residuals());
    if (!f.cost->Evaluate(&block, r.data(), nullptr)) return std::numeric_limits<double>::infinity();
    worst = std::max(worst, r.cwiseAbs().maxCoeff());
  }
  return worst;
}

}  // namespace

// One solve of the buffered steps (BatchSmoother::finish): the working state of the phases, each
// a member with one job, run in order by run():
//   first solve (left-out observations readmitted)      solveAll
//   the cuts' places                                      placeCuts
//   a robust start after a misled first solve             startRobustIfMisfit
//   pairing again at the calibrated solution              reassociateFromIdentified, solveReassociating
//   the cuts' verification by model selection            testCuts (moveCutToFix)
//   the whole chain when a cut's calibration is absurd    joinImplausibleCuts
//   marginal covariances and the calibration estimate     computeCovariances, writeCalibration
// Pose i of x_ is steps_[first_ + i].
class BatchSmoother::Solve {
 public:
  Solve(BatchSmoother& smoother, BatchSummary* summary);
  void run();

 private:
  // What the robust start begins again from: the guess, its cuts and its left-out observations.
  struct Guess {
    std::vector<double> x, globals;
    std::vector<Cut> cuts;
    std::vector<uint8_t> left_out;
  };

  Pose2 poseAt(size_t i) const { return Pose2(x_[3 * i], x_[3 * i + 1], x_[3 * i + 2]); }
  void setPose(size_t i, const Pose2& p);
  Pose2 motionInto(size_t i) const;  // the odometry's motion u_i from pose i - 1 into pose i (B.16)
  void report(const char* phase, long done, long total, int iteration, double cost) const;
  template <class F>
  void forEachObservation(F&& f) const;  // f(pose i, observation o) of every associated one
  bool sighted(size_t i) const;           // pose i has an observation in the problem
  void leaveOutUnevaluable();
  int admitLeftOut();
  void countFactors();
  void setCuts(const std::vector<Cut>& cuts, bool cut);
  double solveRange(size_t lo, size_t hi, bool full, bool may_fail = false);
  double solveAll();
  bool ratesFromPoses() const;  // BodyRateSource::SmoothedPoses, with the exposure offset estimated
  void ratesFromSolution();
  double varianceFactor(double cut_cost) const;
  int placeCuts();
  Guess saveGuess() const;
  void startRobustIfMisfit(Guess guess);
  int reassociate();
  void unpairUnidentified();
  double solveReassociating(double c);
  void reassociateFromIdentified();
  bool withdrawCutsIfUndetermined();  // every cut withdrawn when the chain's marginals fail; true then
  double cutEvidenceThreshold() const;  // of 2 x cost, for keeping a cut
  // The cost over poses [lo, hi) with cut c's odometry restored (the poses from `keep` on the
  // second start), x_ left at the better start's optimum.
  double restoredCost(size_t lo, size_t hi, size_t c, double base, double threshold, double variance_factor,
                      const std::vector<double>& keep);
  // Whether the data keep cut c (re-initialised at r, in the segment [seg_lo, seg_hi)); x_ is
  // left at the cut solution when kept, at the restored one when not.
  bool cutHoldsUp(size_t c, size_t r, size_t seg_lo, size_t seg_hi, double threshold, double variance_factor);
  // With x_ at the joined solution of [lo, hi) (the cut restored): whether the cut's evidence
  // falls to `threshold` or below without the sighting that solution fits worst; that sighting
  // then stays out of the problem and x_ at the joined solution without it.
  bool outlierExplainsCut(size_t lo, size_t hi, double base, double threshold, double variance_factor);
  void testCuts();
  bool moveCutToFix(size_t c, size_t a, size_t seg_lo, size_t seg_hi, size_t r);
  void joinImplausibleCuts();
  void finishSummary(Clock::time_point t_solve);
  Eigen::MatrixXd computeCovariances();
  void chainCovariances(std::vector<Eigen::Matrix3d>* pose_covariances, Eigen::MatrixXd* global_covariance);
  void ceresCovariances(Eigen::MatrixXd* global_covariance);
  void writeCalibration(const Eigen::MatrixXd& global_covariance);

  BatchSmoother& b_;
  BatchSummary& s_;
  const size_t first_, n_;
  std::vector<double> x_;
  const PoseManifold manifold_;
  const std::unique_ptr<ceres::LossFunction> loss_;
  StepFactorSource source_;
  std::vector<double> globals_;  // the calibration blocks, concatenated
  const ChainProblem chain_;
  // The problem (and loss) the solves minimise: chain_, or during the robust start
  // (BatchSmootherConfig::robust_start) the same factors under a Cauchy loss.
  std::unique_ptr<ceres::LossFunction> start_loss_;
  std::unique_ptr<ChainProblem> start_chain_;
  const ChainProblem* active_;
  ceres::LossFunction* active_loss_;
  ChainSolverOptions lm_;
  long residuals_ = 3;  // of the factors as last counted (countFactors)
  double cost_ = 0;     // of the last full solve
  int withdrawn_ = 0;
  std::vector<uint8_t> outlier_;  // per observation: left out as the one wrong sighting behind a cut
  // With the stereo calibration estimated, the unidentified observations are paired again at
  // the solution (reassociate).
  bool reassociate_passes_ = false;
  std::map<size_t, std::vector<int>> filter_pairings_;  // the filter pass's landmark ids per step index
};

void BatchSmoother::solve() {
  BatchSummary s;
  s.uninitialised_steps = summary_.uninitialised_steps;
  s.filter_seconds = summary_.filter_seconds;
  solved_ = true;
  if (first_index_ < 0) {
    result_ = guess_;
    s.message = "no initial pose (no global fix): nothing to estimate";
    summary_ = s;
    return;
  }
  observations_.shrink_to_fit();  // before the solver's workspace: the growth slack is not kept
  Solve(*this, &s).run();
  summary_ = s;
}

namespace {

std::vector<double> poseVector(const std::vector<Estimate>& guess, size_t first) {
  const size_t n = guess.size() - first;
  std::vector<double> x(3 * n);
  for (size_t i = 0; i < n; ++i) {
    const Pose2& p = guess[first + i].pose;
    x[3 * i] = p.x;
    x[3 * i + 1] = p.y;
    x[3 * i + 2] = p.theta;
  }
  return x;
}

}  // namespace

BatchSmoother::Solve::Solve(BatchSmoother& smoother, BatchSummary* summary)
    : b_(smoother), s_(*summary), first_(static_cast<size_t>(smoother.first_index_)),
      n_(smoother.steps_.size() - first_), x_(poseVector(smoother.guess_, first_)),
      loss_(makeLossFunction(smoother.config_.loss)), source_(smoother, first_, n_),
      globals_(source_.nominalGlobals()), chain_(source_, loss_.get(), &globals_), active_(&chain_),
      active_loss_(loss_.get()), outlier_(smoother.observations_.size(), 0) {
  if (b_.config_.initial_guess == InitialGuess::Filter && b_.given_.empty()) b_.smoothGuess(first_, &x_);
  lm_.max_iterations = b_.config_.max_iterations;
  lm_.function_tolerance = b_.config_.function_tolerance;
  lm_.gradient_tolerance = b_.config_.gradient_tolerance;
  lm_.parameter_tolerance = b_.config_.parameter_tolerance;
  reassociate_passes_ =
      b_.config_.reassociate_with_calibration && source_.stereoBlock() >= 0 && !b_.raw_observations_.empty();
}

void BatchSmoother::Solve::run() {
  const auto t_solve = Clock::now();
  leaveOutUnevaluable();
  s_.poses = static_cast<int>(n_);
  // Drops candidate cuts at the first pose (nothing to cut there).
  std::vector<Cut>& cuts = b_.cuts_;
  cuts.erase(std::remove_if(cuts.begin(), cuts.end(), [&](const Cut& c) { return c.index <= first_; }), cuts.end());
  setCuts(cuts, true);
  const bool may_start_robust = b_.config_.robust_start && b_.config_.loss.type == RobustLoss::None && !cuts.empty();
  Guess guess;
  if (may_start_robust) guess = saveGuess();
  cost_ = solveAll();
  if (!cuts.empty()) countFactors();
  if (placeCuts() > 0) cost_ = solveAll();
  if (may_start_robust) startRobustIfMisfit(std::move(guess));
  if (reassociate_passes_) reassociateFromIdentified();
  if (start_chain_) {
    // The robust start ends: least squares from its solution, paired again there.
    active_ = &chain_;
    active_loss_ = loss_.get();
    if (reassociate_passes_) reassociate();
    cost_ = solveAll();
  }
  if (ratesFromPoses()) {
    ratesFromSolution();
    cost_ = solveAll();
  }
  cost_ = solveReassociating(cost_);
  countFactors();
  testCuts();
  joinImplausibleCuts();
  finishSummary(t_solve);
  writeCalibration(computeCovariances());
}

void BatchSmoother::Solve::setPose(size_t i, const Pose2& p) {
  x_[3 * i] = p.x;
  x_[3 * i + 1] = p.y;
  x_[3 * i + 2] = p.theta;
}

Pose2 BatchSmoother::Solve::motionInto(size_t i) const {
  const BufferedStep& st = b_.steps_[first_ + i];
  const Eigen::Vector3d u = controlVector(st.d_left, st.d_right, b_.odometry_.wheel_base_mm);
  return Pose2(u.x(), u.y(), u.z());
}

void BatchSmoother::Solve::report(const char* phase, long done, long total, int iteration, double cost) const {
  if (!b_.config_.progress) return;
  BatchProgress p;
  p.phase = phase;
  p.done = done;
  p.total = total;
  p.iteration = iteration;
  p.cost = cost;
  b_.config_.progress(p);
}

template <class F>
void BatchSmoother::Solve::forEachObservation(F&& f) const {
  for (size_t i = 0; i < n_; ++i)
    for (size_t o = b_.observationsBegin(first_ + i); o < b_.steps_[first_ + i].observations_end; ++o)
      if (b_.observations_[o].landmark_id >= 0) f(i, o);
}

bool BatchSmoother::Solve::sighted(size_t i) const {
  for (size_t o = b_.observationsBegin(first_ + i); o < b_.steps_[first_ + i].observations_end; ++o)
    if (b_.observations_[o].landmark_id >= 0 && !source_.leftOut(o)) return true;
  return false;
}

// An observation whose factor cannot be evaluated at the initial guess (a pixel factor whose
// landmark is behind the cameras: the guess is off by more than the view allows, e.g. after a
// filter pass misled by a miscalibrated rig) would stop the solver before its first step. It
// is left out of the first solve and tested again at each solution (admitLeftOut): the
// problem is the same as from a better guess, provided the other factors bring the poses
// to where the landmark is in view; one still behind the cameras at the solution contradicts
// the estimate and stays out (summary().observations_left_out).
void BatchSmoother::Solve::leaveOutUnevaluable() {
  forEachObservation([&](size_t i, size_t o) {
    if (!source_.evaluable(o, &x_[3 * i], globals_)) {
      source_.setLeftOut(o, true);
      ++s_.observations_left_out_at_guess;
    }
  });
}

// Readmits the left-out observations evaluable at x_; returns how many.
int BatchSmoother::Solve::admitLeftOut() {
  int admitted = 0;
  if (s_.observations_left_out_at_guess == 0) return admitted;
  forEachObservation([&](size_t i, size_t o) {
    if (source_.leftOut(o) && !outlier_[o] && source_.evaluable(o, &x_[3 * i], globals_)) {
      source_.setLeftOut(o, false);
      ++admitted;
    }
  });
  return admitted;
}

// Counts of the problem (for the summary and the model selection's BIC).
void BatchSmoother::Solve::countFactors() {
  residuals_ = 3;  // the prior
  s_.observation_factors = s_.compass_factors = s_.unassociated_observations = 0;
  std::vector<ChainFactor> unary;
  for (size_t i = 0; i < n_; ++i) {
    unary.clear();
    source_.unaryFactors(i, &unary);
    for (const ChainFactor& f : unary) {
      residuals_ += f.cost->num_residuals();
      if (f.robust) ++s_.observation_factors;
    }
    if (b_.steps_[first_ + i].compass_sigma > 0 && b_.config_.use_compass) ++s_.compass_factors;
    for (size_t o = b_.observationsBegin(first_ + i); o < b_.steps_[first_ + i].observations_end; ++o)
      s_.unassociated_observations += b_.observations_[o].landmark_id < 0 ? 1 : 0;
  }
  residuals_ -= 3;  // counted with the unary factors of pose 0
  s_.observations_left_out = 0;
  forEachObservation([&](size_t, size_t o) { s_.observations_left_out += source_.leftOut(o) && !outlier_[o] ? 1 : 0; });
}

void BatchSmoother::Solve::setCuts(const std::vector<Cut>& cuts, bool cut) {
  for (const Cut& c : cuts)
    if (c.index > first_) source_.setCut(c.index - first_, cut);
}

// Minimises over poses [lo, hi) with the cuts set in source_; returns the cost of the factors
// touching the range. An unusable solve (a factor not evaluable at the start) throws, or with
// `may_fail` returns +infinity and leaves x_ unchanged.
double BatchSmoother::Solve::solveRange(size_t lo, size_t hi, bool full, bool may_fail) {
  const BatchSmootherConfig& config = b_.config_;
  ChainSolverSummary r;
  if (config.solver == BatchSolver::Chain) {
    ChainSolverOptions o = lm_;
    o.solve_globals = full;  // the cut tests' windows hold the calibration
    if (full) o.progress = [&](int it, double cost) { report("solve", it, config.max_iterations, it, cost); };
    r = active_->solve(lo, hi, &x_, o);
  } else {
    const std::unique_ptr<ceres::Problem> problem =
        makeCeresProblem(source_, active_loss_, &manifold_, lo, hi, &x_, &globals_, full);
    ceres::Solver::Options opts;
    opts.linear_solver_type = ceres::SPARSE_NORMAL_CHOLESKY;
    opts.sparse_linear_algebra_library_type = ceres::SUITE_SPARSE;
    opts.minimizer_type = ceres::TRUST_REGION;
    opts.trust_region_strategy_type = ceres::LEVENBERG_MARQUARDT;
    opts.max_num_iterations = config.max_iterations;
    opts.function_tolerance = config.function_tolerance;
    opts.gradient_tolerance = config.gradient_tolerance;
    opts.parameter_tolerance = config.parameter_tolerance;
    opts.num_threads = config.num_threads;
    opts.logging_type = ceres::SILENT;
    ceres::Solver::Summary cs;
    ceres::Solve(opts, problem.get(), &cs);
    r.usable = cs.IsSolutionUsable();
    r.converged = cs.termination_type == ceres::CONVERGENCE;
    r.iterations = static_cast<int>(cs.iterations.size()) - 1;
    r.initial_cost = cs.initial_cost;
    r.final_cost = cs.final_cost;
    r.message = cs.message;
  }
  if (!r.usable && may_fail) return std::numeric_limits<double>::infinity();
  if (!r.usable) throw Error("batch smoother: the solver failed: " + r.message);
  if (full) {
    s_.iterations += r.iterations;
    s_.initial_cost = s_.iterations == r.iterations ? r.initial_cost : s_.initial_cost;
    s_.final_cost = r.final_cost;
    s_.solved = true;
    s_.converged = r.converged;
    s_.message = r.message;
  } else {
    s_.cut_test_iterations += r.iterations;
  }
  return r.final_cost;
}

// Solves the whole chain, readmitting the left-out observations its solution brings into view.
double BatchSmoother::Solve::solveAll() {
  double c = solveRange(0, n_, true);
  while (admitLeftOut() > 0) c = solveRange(0, n_, true);
  return c;
}

bool BatchSmoother::Solve::ratesFromPoses() const {
  const auto& sigmas = source_.imageSigmas();
  return b_.config_.exposure_rate == BodyRateSource::SmoothedPoses && sigmas &&
         (*sigmas)[stereo_pixel_calibration::kExposureOffsetEntry] > 0;
}

// The image factors that estimate the exposure offset project the right column from the pose
// the robot reaches in the offset at the image's body rate. The odometry's rate (0.5 s average of
// the wheels, BodyRateTracker) lags the turns and keeps part of the wheels' noise, and the offset
// fitted against it as if exact comes out shrunk towards zero and over-confident (errors in
// variables; docs/realistic_world.md). Once a solution exists, each step's rate is the smoothed
// poses' central difference around it (one-sided at an end or a cut): the poses are fitted to the
// sightings as well as to the odometry, and the difference does not lag. A second round from the
// solution this gives moves the offset by less than a tenth of its sigma, so there is one. The
// rate's sigma is that of the odometry's rotation over the span alone, an upper bound of the
// smoothed difference's.
void BatchSmoother::Solve::ratesFromSolution() {
  std::vector<char> cut_into(n_, 0);  // the odometry factor into pose i is cut
  for (const Cut& c : b_.cuts_)
    if (c.index > first_ && c.index - first_ < n_) cut_into[c.index - first_] = 1;
  const double slip = b_.config_.observation_model.unmodelled.slip_rel_sigma;
  for (size_t i = 0; i < n_; ++i) {
    const size_t a = i > 0 && !cut_into[i] ? i - 1 : i;
    const size_t b = i + 1 < n_ && !cut_into[i + 1] ? i + 1 : i;
    if (a == b) continue;  // a pose alone in its segment keeps the odometry's rate
    const double dt = b_.steps_[first_ + b].t - b_.steps_[first_ + a].t;
    if (!(dt > 0)) continue;
    double rotation_variance = 0;
    for (size_t k = a + 1; k <= b; ++k) {
      const BufferedStep& st = b_.steps_[first_ + k];
      rotation_variance +=
          stepRotationVariance(st.d_left, st.d_right, withSlip(b_.odometry_, st.d_left, st.d_right, slip));
    }
    b_.steps_[first_ + i].rate = bodyRateBetween(poseAt(a), poseAt(b), dt, rotation_variance);
  }
}

// Residual variance factor of the cut model at `cut_cost` (2 cost / (m - parameters), m the
// residuals of every factor, odometry included; at least 1), with the factors as last counted:
// on mismodelled (e.g. real) data whose whitened residuals are larger than unit, the filter
// loses track without a kidnap, and unscaled tests would place and keep every such cut.
double BatchSmoother::Solve::varianceFactor(double cut_cost) const {
  const size_t odometry_factors = n_ - 1 - std::min(n_ - 1, b_.cuts_.size());
  const double m = static_cast<double>(residuals_) + 3.0 * static_cast<double>(odometry_factors);
  const double dof = m - 3.0 * static_cast<double>(n_);
  return dof > 0 ? std::max(1.0, 2.0 * cut_cost / dof) : 1.0;
}

// A cut sits right after the last pose the filter confirmed, but the lost filter may have gated
// out sightings that still came from before the kidnap: the poses up to the re-initialisation
// that they place would otherwise be tied to the new segment (two goal corners 9e6 in 2 x cost
// on the realistic kidnap, seed 7, trial 10, and a runaway calibration). Each later place up to
// the re-initialisation is tried, the poses before it chained forward by the odometry from the
// old segment, the window around solved with the calibration held; the cut moves to the best
// place if that lowers 2 x cost by more than the gate's chi-square(3) quantile (times the
// residual variance factor, as the cut tests). A pose without sightings fits either side, so
// the cut stays as early as the sightings allow (a teleport changes the view at once).
// Returns how many cuts moved.
int BatchSmoother::Solve::placeCuts() {
  std::vector<Cut>& cuts = b_.cuts_;
  int moved = 0;
  const double threshold = chi2Quantile(b_.config_.gate.probability, 3) * varianceFactor(cost_);
  for (size_t k = 0; k < cuts.size(); ++k) {
    const size_t c = cuts[k].index - first_;
    const size_t r = cuts[k].reinit - first_;
    const size_t seg_lo = k > 0 ? cuts[k - 1].index - first_ : 0;
    const size_t seg_hi = k + 1 < cuts.size() ? cuts[k + 1].index - first_ : n_;
    const size_t lo = c > seg_lo + kCutWindowMargin ? c - kCutWindowMargin : seg_lo;
    const size_t hi = std::min(seg_hi, r + kCutWindowMargin);
    double best = 0;
    if (r <= c || !active_->cost(lo, hi, x_, &best)) continue;
    const std::vector<double> at_cut(x_.begin() + static_cast<long>(3 * lo), x_.begin() + static_cast<long>(3 * hi));
    std::vector<double> best_x = at_cut;
    size_t best_place = c;
    for (size_t p = c + 1; p <= r && p < hi; ++p) {
      if (!sighted(p - 1)) continue;  // the same cost as at p - 1
      std::copy(at_cut.begin(), at_cut.end(), x_.begin() + static_cast<long>(3 * lo));
      for (size_t j = c; j < p; ++j) setPose(j, compose(poseAt(j - 1), motionInto(j)));
      source_.setCut(c, false);
      source_.setCut(p, true);
      const double placed = solveRange(lo, hi, false, true);
      if (2.0 * (best - placed) > threshold) {
        best = placed;
        best_x.assign(x_.begin() + static_cast<long>(3 * lo), x_.begin() + static_cast<long>(3 * hi));
        best_place = p;
      }
      source_.setCut(p, false);
      source_.setCut(c, true);
    }
    std::copy(best_x.begin(), best_x.end(), x_.begin() + static_cast<long>(3 * lo));
    if (best_place != c) {
      source_.setCut(c, false);
      source_.setCut(best_place, true);
      cuts[k].index = first_ + best_place;
      ++moved;
    }
  }
  return moved;
}

BatchSmoother::Solve::Guess BatchSmoother::Solve::saveGuess() const {
  Guess g;
  g.x = x_;
  g.globals = globals_;
  g.cuts = b_.cuts_;
  g.left_out.resize(b_.observations_.size());
  for (size_t o = 0; o < b_.observations_.size(); ++o) g.left_out[o] = source_.leftOut(o) ? 1 : 0;
  return g;
}

// A first solve that fits badly after a lost filter pass: the guess's gross errors misled it
// (BatchSmootherConfig::robust_start). It begins again from the guess, robust; the robust
// problem stays active up to the placing of the cuts and the re-pairing (run()).
void BatchSmoother::Solve::startRobustIfMisfit(Guess guess) {
  if (varianceFactor(cost_) > kRobustStartVarianceFactor) {
    x_ = std::move(guess.x);
    globals_ = std::move(guess.globals);
    setCuts(b_.cuts_, false);
    b_.cuts_ = std::move(guess.cuts);
    setCuts(b_.cuts_, true);
    for (size_t o = 0; o < b_.observations_.size(); ++o) source_.setLeftOut(o, guess.left_out[o] != 0);
    start_loss_ = makeLossFunction({RobustLoss::Cauchy, kRobustStartCauchyScale});
    start_chain_ = std::make_unique<ChainProblem>(source_, start_loss_.get(), &globals_);
    active_ = start_chain_.get();
    active_loss_ = start_loss_.get();
    cost_ = solveAll();
    if (placeCuts() > 0) cost_ = solveAll();
  }
}

namespace {

// The landmark of obs's kind nearest to where `pose` puts it (-1: none of that kind).
int nearestLandmark(const Observation& obs, const Pose2& pose, const FieldMap& map) {
  const Eigen::Vector2d at = landmarkFromRangeBearing(pose, obs.range, obs.bearing);
  int nearest = -1;
  double best = std::numeric_limits<double>::infinity();
  for (const Landmark& l : map.landmarks()) {
    if (l.type != obs.type) continue;
    const double d = (l.xy() - at).squaredNorm();
    if (d < best) {
      best = d;
      nearest = l.id;
    }
  }
  return nearest;
}

}  // namespace

// With the stereo calibration estimated, the unidentified observations are associated again at
// the solution: the filter pass associated them with the nominal calibration, whose errors
// (a focal-length difference of 1.7 % moves the disparity by ~3 px at the image's edge) pair
// floor markings with the wrong landmarks, and the solve, holding those pairings, settles on a
// wrong calibration. Each pass takes the solved poses and calibration; it stops when no
// pairing changes. Returns how many pairings changed.
int BatchSmoother::Solve::reassociate() {
  const ObservationModelConfig& model = b_.config_.observation_model;
  const double* q = globals_.data() + (source_.odometryBlock() >= 0 ? 3 : 0);  // (dbeta, k, dd, du, phi, psi)
  StereoRigParams params = model.rig.params();
  params.tilt_rad += q[0];
  const StereoRig rig = model.rig.calibration() ? StereoRig(params, *model.rig.calibration()) : StereoRig(params);
  const double ou = rig.principalU(), ov = rig.principalV(), scale = 1.0 + q[5];
  // The row offset dv, last in the stereo block when estimated (its slide s dv leaves u_r).
  const double dv = source_.rowSigma() ? q[StereoPixelCalibrationFactor::kCalibrationSize +
                                           (source_.imageSigmas() ? StereoPixelImageCalibrationFactor::kImageErrorSize : 0)]
                                       : 0.0;
  int changed = 0;
  for (const auto& [index, raw] : b_.raw_observations_) {
    if (index < first_) continue;
    const size_t i = index - first_;
    // The pixels as the nominal rig would have seen them (the inverse of
    // factors/stereo_pixel_calibration_factor.h's columns and rows), as range and bearing.
    std::vector<Observation> corrected = raw;
    for (Observation& o : corrected) {
      if (o.landmark_id >= 0 || !o.pixels) continue;
      const double cl = (o.pixels->u_left - ou - q[3] - 0.5 * q[2]) / scale;
      const double cr = (o.pixels->u_right - o.slide_gain * dv - ou - q[3] + 0.5 * q[2]) / (scale * (1.0 + q[4]));
      const double mean = 0.5 * (cl + cr), disparity = (cl - cr) / q[1];
      const StereoPixels px{ou + mean + 0.5 * disparity, ov + (o.pixels->v_left - ov) / scale,
                            ou + mean - 0.5 * disparity, ov + (o.pixels->v_right - ov) / scale};
      Landmark kind;
      kind.type = o.type;
      try {
        const double gain = o.slide_gain;
        o = observationFromPixels(rig, -1, o.type, px, o.head_pan, pixelCovarianceFor(o, kind, model));
        o.slide_gain = gain;
      } catch (const Error&) {
        // Not triangulable with the calibration (disparity too small): keeps its nominal form.
      }
    }
    const Pose2 pose = poseAt(i);
    const std::vector<Observation> a =
        associateObservations(corrected, pose, b_.guess_[index].covariance, b_.map_, b_.config_.association);
    const size_t begin = b_.observationsBegin(index);
    const auto filtered = filter_pairings_.find(index);
    for (size_t k = 0; k < a.size(); ++k) {
      Observation& target = b_.observations_[begin + k];
      // An observation the solution cannot pair (outside every gate, or ambiguous) keeps the
      // filter pass's pairing where the solution puts the sighting nearer to that landmark than
      // to any other of its kind. A filter pass that drifted, even one still fusing, pairs
      // sightings with landmarks far from where the solution sees them.
      int id = a[k].landmark_id;
      if (id < 0 && filtered != filter_pairings_.end() && filtered->second[k] >= 0 &&
          nearestLandmark(corrected[k], pose, b_.map_) == filtered->second[k])
        id = filtered->second[k];
      if (target.landmark_id == id) continue;
      target.landmark_id = id;
      ++changed;
      source_.setLeftOut(begin + k, false);
      if (target.landmark_id >= 0 && !source_.evaluable(begin + k, &x_[3 * i], globals_)) {
        source_.setLeftOut(begin + k, true);
        ++s_.observations_left_out_at_guess;
      }
    }
  }
  return changed;
}

// Drops the pairings of the unidentified observations, so that a solve places the chain with
// the identified landmarks alone.
void BatchSmoother::Solve::unpairUnidentified() {
  for (const auto& [index, raw] : b_.raw_observations_) {
    if (index < first_) continue;
    const size_t begin = b_.observationsBegin(index);
    for (size_t k = 0; k < raw.size(); ++k)
      if (raw[k].landmark_id < 0) {
        b_.observations_[begin + k].landmark_id = -1;
        source_.setLeftOut(begin + k, false);
      }
  }
}

// Pairs the unidentified observations at the solution and solves again, until no pairing
// changes (at most kReassociationPasses times); returns the cost, `c` if nothing changed.
double BatchSmoother::Solve::solveReassociating(double c) {
  for (int pass = 0; pass < kReassociationPasses && reassociate_passes_; ++pass) {
    if (reassociate() == 0) break;
    c = solveAll();
  }
  return c;
}

// The first solve's calibration comes from the identified landmarks alone (the pairings of the
// others are the nominal calibration's guesses); they are paired at its solution.
void BatchSmoother::Solve::reassociateFromIdentified() {
  for (const auto& [index, raw] : b_.raw_observations_) {
    if (index < first_) continue;
    const size_t begin = b_.observationsBegin(index);
    std::vector<int>& ids = filter_pairings_[index];
    for (size_t k = 0; k < raw.size(); ++k) ids.push_back(b_.observations_[begin + k].landmark_id);
  }
  unpairUnidentified();
  cost_ = solveAll();
}

bool BatchSmoother::Solve::withdrawCutsIfUndetermined() {
  std::vector<Eigen::Matrix3d> D, B, cov;
  std::vector<Eigen::Vector3d> g;
  double c0 = 0;
  if (chain_.linearise(0, n_, x_, &D, &B, &g, &c0) && chainMarginalCovariances(D, B, &cov)) return false;
  std::vector<Cut>& cuts = b_.cuts_;
  withdrawn_ += static_cast<int>(cuts.size());
  setCuts(cuts, false);
  cuts.clear();
  cost_ = solveAll();
  return true;
}

// Model selection for each cut, in step order: a cut frees the 3 degrees of freedom of the
// segment after it; by the Bayesian information criterion it is kept only if restoring its
// odometry factor raises 2 x cost by more than 3 ln(m), m the number of residuals (and at
// least the gate's chi-square(3) quantile). A rare kidnap thus needs strong evidence: one
// outlier that a free pose can fit does not cut the chain.
double BatchSmoother::Solve::cutEvidenceThreshold() const {
  return std::max({chi2Quantile(b_.config_.gate.probability, 3),
                   3.0 * std::log(std::max(2.0, static_cast<double>(residuals_))), b_.config_.cut_min_evidence});
}

// Two starts: the cut solution, and the segment after the cut moved rigidly to continue the
// odometry from the pose before it (a robust loss would otherwise keep a misplaced segment);
// the better optimum counts, so a cut is kept only on the evidence. When the first already
// withdraws the cut, the second cannot keep it.
double BatchSmoother::Solve::restoredCost(size_t lo, size_t hi, size_t c, double base, double threshold,
                                          double variance_factor, const std::vector<double>& keep) {
  double restored = solveRange(lo, hi, false);
  if (2.0 * (restored - base) / variance_factor > threshold) {
    std::vector<double> best(x_.begin() + static_cast<long>(3 * lo), x_.begin() + static_cast<long>(3 * hi));
    std::copy(keep.begin(), keep.end(), x_.begin() + static_cast<long>(3 * lo));
    const Pose2 target = compose(poseAt(c - 1), motionInto(c));
    const Pose2 start = poseAt(c);
    for (size_t j = c; j < hi; ++j) setPose(j, compose(target, between(start, poseAt(j))));
    const double restored_moved = solveRange(lo, hi, false, true);
    if (restored_moved < restored)
      restored = restored_moved;
    else
      std::copy(best.begin(), best.end(), x_.begin() + static_cast<long>(3 * lo));
  }
  return restored;
}

// Restoring a cut changes only the segments it joins (the others stay cut off), and within
// them its effect decays along the chain: the test solves a window around the cut and its
// unobserved stretch with the poses outside held at the cut solution. Holding them can only
// raise the restored cost, so a rise below the threshold withdraws the cut exactly; a rise
// above it is confirmed on a window that reaches the neighbouring cuts or whose edge poses
// did not move, growing the window fourfold until then. Holding an edge that wanted to move
// by d changes the restored cost by about (information) d^2: with d below 1e-3 mm and 1e-6 rad
// that is far below the threshold (>= 1000 by default), so the decision is the full one.
bool BatchSmoother::Solve::cutHoldsUp(size_t c, size_t r, size_t seg_lo, size_t seg_hi, double threshold,
                                      double variance_factor) {
  constexpr double kEdgeToleranceMm = 1e-3, kEdgeToleranceRad = 1e-6;
  for (size_t margin = kCutWindowMargin;; margin *= 4) {
    const size_t lo = c > seg_lo + margin ? c - margin : seg_lo;
    const size_t hi = std::min(seg_hi, r + margin);
    const std::vector<double> keep(x_.begin() + static_cast<long>(3 * lo), x_.begin() + static_cast<long>(3 * hi));
    double base = 0;
    if (!chain_.cost(lo, hi, x_, &base)) throw Error("batch smoother: a factor cannot be evaluated at the solution");
    source_.setCut(c, false);
    const double restored = restoredCost(lo, hi, c, base, threshold, variance_factor, keep);
    const double evidence = 2.0 * (restored - base) / variance_factor;
    auto edgeMoved = [&](size_t j) {
      const size_t o = 3 * (j - lo);
      return std::fabs(x_[3 * j] - keep[o]) > kEdgeToleranceMm || std::fabs(x_[3 * j + 1] - keep[o + 1]) > kEdgeToleranceMm ||
             std::fabs(wrapAngle(x_[3 * j + 2] - keep[o + 2])) > kEdgeToleranceRad;
    };
    const bool exact = (lo == seg_lo || !edgeMoved(lo)) && (hi == seg_hi || !edgeMoved(hi - 1));
    if (evidence <= threshold) return false;
    if (exact && outlierExplainsCut(lo, hi, base, threshold, variance_factor)) return false;
    std::copy(keep.begin(), keep.end(), x_.begin() + static_cast<long>(3 * lo));
    source_.setCut(c, true);
    if (exact) return true;
  }
}

// A cut lets the poses after it start again anywhere: evidence for it that a single wrong
// sighting gives is no evidence of a kidnap. One sighting left out (2 residuals) is a smaller
// change of model than a cut (3 parameters), so where the joined chain without the sighting
// it fits worst is within the threshold of the cut model with it, the sighting goes and the
// cut with it. A frontend's false stereo match at the first pose, sharp and 10 px off in
// disparity, otherwise kept a cut after that pose and left the pose at the false range.
bool BatchSmoother::Solve::outlierExplainsCut(size_t lo, size_t hi, double base, double threshold,
                                              double variance_factor) {
  size_t worst = 0;
  double worst_cost = -1.0;
  for (size_t i = lo; i < hi; ++i)
    for (size_t o = b_.observationsBegin(first_ + i); o < b_.steps_[first_ + i].observations_end; ++o) {
      double cost = 0;
      if (b_.observations_[o].landmark_id < 0 || source_.leftOut(o) ||
          !source_.observationCost(o, &x_[3 * i], globals_, &cost) || cost <= worst_cost)
        continue;
      worst_cost = cost;
      worst = o;
    }
  if (worst_cost < 0) return false;
  const std::vector<double> joined(x_.begin() + static_cast<long>(3 * lo), x_.begin() + static_cast<long>(3 * hi));
  source_.setLeftOut(worst, true);
  const double restored = solveRange(lo, hi, false, true);
  if (2.0 * (restored - base) / variance_factor <= threshold) {
    outlier_[worst] = 1;
    ++s_.cut_outliers;
    return true;
  }
  source_.setLeftOut(worst, false);
  std::copy(joined.begin(), joined.end(), x_.begin() + static_cast<long>(3 * lo));
  return false;
}

void BatchSmoother::Solve::testCuts() {
  std::vector<Cut>& cuts = b_.cuts_;
  const auto t_cuts = Clock::now();
  // A segment the data do not determine cannot be verified, nor estimated on its own.
  if (cuts.empty() || withdrawCutsIfUndetermined()) return;
  const double threshold = cutEvidenceThreshold();
  const double variance_factor = varianceFactor(cost_);
  const long total_cuts = static_cast<long>(cuts.size());
  long tested = 0;
  // The re-initialisation of the last candidate withdrawn since the previous kept cut: see
  // moveCutToFix.
  long withdrawn_fix = -1;  // local index, -1: none
  int moved_cuts = 0;
  for (size_t k = 0; k < cuts.size();) {
    report("cut test", tested++, total_cuts, 0, cost_);
    const size_t c = cuts[k].index - first_;
    const size_t r = std::max(c, cuts[k].reinit - first_);
    const size_t seg_lo = k > 0 ? cuts[k - 1].index - first_ : 0;
    const size_t seg_hi = k + 1 < cuts.size() ? cuts[k + 1].index - first_ : n_;
    if (cutHoldsUp(c, r, seg_lo, seg_hi, threshold, variance_factor)) {
      const size_t a = static_cast<size_t>(withdrawn_fix);
      if (withdrawn_fix >= 0 && a > seg_lo && a < c && moveCutToFix(c, a, seg_lo, seg_hi, r)) {
        cuts[k].index = first_ + a;
        ++moved_cuts;
      }
      withdrawn_fix = -1;
      ++k;
    } else {
      withdrawn_fix = static_cast<long>(cuts[k].reinit - first_);
      cuts.erase(cuts.begin() + static_cast<long>(k));
      ++withdrawn_;
    }
  }
  s_.cut_test_seconds = secondsSince(t_cuts);
  // The final solve with the kept cuts, from the windows' solutions; a moved cut moved poses
  // whose unidentified observations were paired where they were.
  cost_ = solveAll();
  if (moved_cuts > 0) cost_ = solveReassociating(cost_);
}

// A kept cut sits right after the last pose the filter confirmed before it lost track. When
// the filter lost track earlier, a withdrawn candidate stretches back over that loss and the
// kept cut can only follow the withdrawn candidate's re-initialisation a; but the global fix
// at a is a pose the data place, and the robot may have been moved right before it (the filter
// fixed itself at once, then lost track again). The cut at c therefore also tries a (the poses
// a .. c-1 re-chained backwards from pose c by the odometry, as at the candidate's creation)
// and moves there if that solves the window around both to a lower cost: the same number of
// parameters, so the lower cost is the likelier place.
bool BatchSmoother::Solve::moveCutToFix(size_t c, size_t a, size_t seg_lo, size_t seg_hi, size_t r) {
  const size_t lo = a > seg_lo + kCutWindowMargin ? a - kCutWindowMargin : seg_lo;
  const size_t hi = std::min(seg_hi, r + kCutWindowMargin);
  double base = 0;
  if (!chain_.cost(lo, hi, x_, &base)) return false;
  const std::vector<double> keep(x_.begin() + static_cast<long>(3 * lo), x_.begin() + static_cast<long>(3 * hi));
  for (size_t j = c; j-- > a;) setPose(j, compose(poseAt(j + 1), inverse(motionInto(j + 1))));
  source_.setCut(c, false);
  source_.setCut(a, true);
  const double moved = solveRange(lo, hi, false, true);
  if (moved < base) return true;
  std::copy(keep.begin(), keep.end(), x_.begin() + static_cast<long>(3 * lo));
  source_.setCut(a, false);
  source_.setCut(c, true);
  return false;
}

// A miscalibrated filter pass loses track without a kidnap, and a cut kept on its evidence
// lets a segment and the calibration settle together on a wrong solution: a calibration
// parameter far outside its prior (a baseline scale 28 sigma off, a wheel base at half) says
// so. The chain is then solved whole, its pairings redone at that solution, and kept if its
// calibration is plausible; a real kidnap's chain cannot be, and the cuts stay.
void BatchSmoother::Solve::joinImplausibleCuts() {
  std::vector<Cut>& cuts = b_.cuts_;
  std::vector<Observation>& observations = b_.observations_;
  if (cuts.empty() || globals_.empty() || calibrationPriorZ(source_, globals_) <= kImplausiblePriorSigmas) return;
  const std::vector<double> keep_x = x_, keep_globals = globals_;
  std::vector<int> keep_ids(observations.size());
  std::vector<uint8_t> keep_left_out(observations.size());
  for (size_t o = 0; o < observations.size(); ++o) {
    keep_ids[o] = observations[o].landmark_id;
    keep_left_out[o] = source_.leftOut(o) ? 1 : 0;
  }
  setCuts(cuts, false);
  // The pairings made on the cut segments are not trusted: as after the filter pass, the
  // identified landmarks alone place the whole chain first.
  if (reassociate_passes_) unpairUnidentified();
  const double whole = solveReassociating(solveAll());
  if (calibrationPriorZ(source_, globals_) <= kImplausiblePriorSigmas) {
    cost_ = whole;
    withdrawn_ += static_cast<int>(cuts.size());
    cuts.clear();
  } else {
    x_ = keep_x;
    globals_ = keep_globals;
    for (size_t o = 0; o < observations.size(); ++o) {
      observations[o].landmark_id = keep_ids[o];
      source_.setLeftOut(o, keep_left_out[o] != 0);
    }
    setCuts(cuts, true);
  }
}

void BatchSmoother::Solve::finishSummary(Clock::time_point t_solve) {
  countFactors();
  s_.solve_seconds = secondsSince(t_solve);
  s_.withdrawn_cuts = withdrawn_;
  s_.segments = 1 + static_cast<int>(b_.cuts_.size());
  s_.odometry_factors = static_cast<int>(n_) - 1 - static_cast<int>(b_.cuts_.size());
  for (const Cut& c : b_.cuts_) {
    s_.cut_steps.push_back(b_.steps_[c.index].step);
    s_.reinit_steps.push_back(b_.steps_[c.reinit].step);
  }
}

// Writes the result (poses and their marginal covariances) and returns the calibration's.
Eigen::MatrixXd BatchSmoother::Solve::computeCovariances() {
  const BatchSmootherConfig& config = b_.config_;
  std::vector<Estimate>& result = b_.result_;
  // The chain marginals first, then the result: each phase holds one more copy of the
  // trajectory's size, not two (the peak memory of a long run).
  std::vector<Eigen::Matrix3d> chain_cov;
  Eigen::MatrixXd global_covariance = Eigen::MatrixXd::Zero(static_cast<Eigen::Index>(globals_.size()),
                                                            static_cast<Eigen::Index>(globals_.size()));
  const bool chain_covariance = config.compute_covariance && config.covariance_method == CovarianceMethod::Chain;
  if (config.compute_covariance) report("covariance", 0, 1, 0, cost_);
  const auto t1 = Clock::now();
  if (chain_covariance) chainCovariances(&chain_cov, &global_covariance);
  result = b_.guess_;
  for (size_t i = 0; i < n_; ++i) {
    Estimate& e = result[first_ + i];
    e.pose = poseAt(i);
    e.covariance = chain_cov.empty() ? Eigen::Matrix3d::Zero() : chain_cov[i];
    e.status = EstimateStatus::Tracking;
  }
  chain_cov = std::vector<Eigen::Matrix3d>();
  if (config.compute_covariance && !chain_covariance) ceresCovariances(&global_covariance);
  if (config.compute_covariance) s_.covariance_seconds = secondsSince(t1);
  return global_covariance;
}

// The marginals by the chain's own elimination (BatchSmootherConfig::covariance_method Chain).
void BatchSmoother::Solve::chainCovariances(std::vector<Eigen::Matrix3d>* pose_covariances,
                                            Eigen::MatrixXd* global_covariance) {
  bool ok = false;
  double c0 = 0;
  if (globals_.empty()) {
    std::vector<Eigen::Matrix3d> D, B;
    std::vector<Eigen::Vector3d> g;
    ok = chain_.linearise(0, n_, x_, &D, &B, &g, &c0);
    g = std::vector<Eigen::Vector3d>();
    ok = ok && chainMarginalCovariances(D, B, pose_covariances);
  } else {
    BorderedSystem h;
    ok = chain_.linearise(0, n_, x_, &h, &c0) && borderedMarginalCovariances(h, pose_covariances, global_covariance);
  }
  if (ok) {
    s_.covariance_status = CovarianceStatus::Ok;
    return;
  }
  pose_covariances->clear();
  global_covariance->setZero();
  s_.covariance_status = CovarianceStatus::RankDeficient;
  s_.message += "; covariance: the information matrix is rank deficient, marginal covariances are not available";
}

// The marginals by ceres::Covariance (sparse QR of the whole Jacobian), into the result's poses.
void BatchSmoother::Solve::ceresCovariances(Eigen::MatrixXd* global_covariance) {
  std::vector<Estimate>& result = b_.result_;
  const std::unique_ptr<ceres::Problem> problem =
      makeCeresProblem(source_, loss_.get(), &manifold_, 0, n_, &x_, &globals_, true);
  ceres::Covariance::Options copts;
  copts.algorithm_type = ceres::SPARSE_QR;
  copts.sparse_linear_algebra_library_type = ceres::SUITE_SPARSE;
  copts.num_threads = b_.config_.num_threads;
  copts.apply_loss_function = true;
  ceres::Covariance covariance(copts);
  std::vector<std::pair<const double*, const double*>> blocks;
  blocks.reserve(n_);
  for (size_t i = 0; i < n_; ++i) blocks.emplace_back(&x_[3 * i], &x_[3 * i]);
  const std::vector<int> sizes = source_.globalBlockSizes();
  std::vector<double*> global_blocks;
  for (size_t k = 0, offset = 0; k < sizes.size(); offset += static_cast<size_t>(sizes[k]), ++k)
    global_blocks.push_back(globals_.data() + offset);
  for (double* a : global_blocks)
    for (double* b : global_blocks) blocks.emplace_back(a, b);
  s_.covariance_status = CovarianceStatus::RankDeficient;
  if (covariance.Compute(blocks, problem.get())) {
    s_.covariance_status = CovarianceStatus::Ok;
    for (size_t a = 0, oa = 0; a < sizes.size(); oa += static_cast<size_t>(sizes[a]), ++a)
      for (size_t b = 0, ob = 0; b < sizes.size(); ob += static_cast<size_t>(sizes[b]), ++b) {
        Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor> C(sizes[a], sizes[b]);
        covariance.GetCovarianceBlock(global_blocks[a], global_blocks[b], C.data());
        global_covariance->block(static_cast<Eigen::Index>(oa), static_cast<Eigen::Index>(ob), sizes[a], sizes[b]) = C;
      }
    for (size_t i = 0; i < n_; ++i) {
      Eigen::Matrix<double, 3, 3, Eigen::RowMajor> C;
      if (!covariance.GetCovarianceBlockInTangentSpace(&x_[3 * i], &x_[3 * i], C.data())) {
        s_.covariance_status = CovarianceStatus::RankDeficient;
        break;
      }
      result[first_ + i].covariance = 0.5 * (C + C.transpose());
    }
  }
  if (s_.covariance_status == CovarianceStatus::Ok) return;
  for (size_t i = 0; i < n_; ++i) result[first_ + i].covariance.setZero();
  global_covariance->setZero();
  s_.message += "; covariance: the Jacobian is rank deficient, marginal covariances are not available";
}

void BatchSmoother::Solve::writeCalibration(const Eigen::MatrixXd& global_covariance) {
  CalibrationEstimate& cal = b_.calibration_;
  cal = CalibrationEstimate();
  cal.wheels.z() = b_.odometry_.wheel_base_mm;
  cal.odometry = source_.odometryBlock() >= 0;
  cal.stereo = source_.stereoBlock() >= 0;
  {
    Eigen::Index offset = 0;
    const Eigen::Map<const Eigen::VectorXd> c(globals_.data(), static_cast<Eigen::Index>(globals_.size()));
    if (cal.odometry) {
      cal.wheels = c.segment<3>(offset);
      cal.wheels_covariance = global_covariance.block<3, 3>(offset, offset);
      offset += 3;
    }
    if (cal.stereo) {
      constexpr int k = StereoPixelCalibrationFactor::kCalibrationSize;
      cal.head = c.segment<k>(offset);
      cal.head_covariance = global_covariance.block<k, k>(offset, offset);
      if (const auto& sigmas = source_.imageSigmas()) {
        // Back from the whitened block to its units.
        constexpr int m = StereoPixelImageCalibrationFactor::kImageErrorSize;
        cal.image = true;
        cal.image_errors = sigmas->cwiseProduct(c.segment<m>(offset + k));
        cal.image_covariance =
            sigmas->asDiagonal() * global_covariance.block<m, m>(offset + k, offset + k) * sigmas->asDiagonal();
      }
      if (source_.rowSigma()) {
        const Eigen::Index r = offset + k + (source_.imageSigmas() ? StereoPixelImageCalibrationFactor::kImageErrorSize : 0);
        cal.row = true;
        cal.row_offset_px = c[r];
        cal.row_offset_variance = global_covariance(r, r);
        for (const FeatureOffsetPrior& f : source_.features()) {
          const std::array<int, 2> at = source_.featureIndices(f.landmark_id);
          CalibrationEstimate::FeatureOffset e;
          e.landmark_id = f.landmark_id;
          if (at[0] >= 0) {
            e.column_px = c[offset + at[0]];
            e.column_variance = global_covariance(offset + at[0], offset + at[0]);
          }
          if (at[1] >= 0) {
            e.offset_px = c[offset + at[1]];
            e.variance = global_covariance(offset + at[1], offset + at[1]);
          }
          cal.feature_offsets.push_back(e);
        }
      }
      if (source_.fieldIndex() >= 0) {
        const Eigen::Index f = offset + source_.fieldIndex();
        cal.field = true;
        cal.field_dimensions_mm = c.segment<kFieldDimensionCount>(f);
        cal.field_covariance = global_covariance.block<kFieldDimensionCount, kFieldDimensionCount>(f, f);
        cal.field_prior_sigma_mm = fieldPriorCovariance(b_.config_.calibration, b_.map_).diagonal().cwiseSqrt();
      }
      offset += source_.blockSize(source_.stereoBlock());
    }
    if (source_.rangeBlock() >= 0) {
      constexpr int k = RangeBearingCalibrationFactor::kCalibrationSize;
      cal.range = true;
      cal.range_bearing = c.segment<k>(offset);
      cal.range_bearing_covariance = global_covariance.block<k, k>(offset, offset);
    }
  }
}

}  // namespace stereoloc
