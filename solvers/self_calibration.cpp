#include "solvers/self_calibration.h"

#include <ceres/ceres.h>

#include <memory>
#include <opencv2/core.hpp>
#include <sstream>

#include "factors/calibration_prior_factor.h"
#include "factors/compass_factor.h"
#include "factors/odometry_calibration_factor.h"
#include "factors/odometry_factor.h"
#include "factors/pose_manifold.h"
#include "factors/pose_prior_factor.h"
#include "factors/range_bearing_factor.h"
#include "factors/stereo_pixel_calibration_factor.h"
#include "solvers/ekf.h"
#include "src/core/error.h"
#include "src/core/yaml_util.h"

namespace stereoloc {

SelfCalibrationConfig SelfCalibrationConfig::parse(const std::string& list) {
  SelfCalibrationConfig c;
  std::stringstream in(list);
  std::string item;
  while (std::getline(in, item, ',')) {
    if (item == "odometry")
      c.odometry = true;
    else if (item == "stereo")
      c.stereo = true;
    else if (!(item == "none" || item.empty()))
      throw Error("calibrate: unknown part '" + item + "' (expected odometry, stereo or both, comma-separated)");
  }
  return c;
}

void SelfCalibrationConfig::validate() const {
  auto pos = [](double v, const char* name) {
    if (!(std::isfinite(v) && v > 0)) throw Error(std::string("self-calibration: ") + name + " must be positive");
  };
  pos(wheel_scale_sigma, "wheel_scale_sigma");
  pos(wheel_base_rel_sigma, "wheel_base_rel_sigma");
  pos(tilt_sigma_rad, "tilt_sigma_rad");
  pos(baseline_scale_sigma, "baseline_scale_sigma");
  if (max_iterations < 1) throw Error("self-calibration: max_iterations must be at least 1");
}

void CalibrationEstimate::saveAsRig(const std::string& path, const StereoRig& rig) const {
  StereoRigParams p = rig.params();
  p.tilt_rad += head[0];
  p.baseline_mm *= head[1];
  const StereoRig out = [&] {
    if (!rig.calibration()) return StereoRig(p);
    StereoCalibration c = *rig.calibration();
    c.T = c.T * head[1];
    c.P2 = c.P2.clone();
    c.P2.at<double>(0, 3) *= head[1];
    if (!c.Q.empty()) c.Q.at<double>(3, 2) /= head[1];
    return StereoRig(p, c);
  }();
  out.save(path);
  // The estimate's own keys, appended as cv::FileStorage YAML (the rig reader ignores them).
  YamlReader back(path);
  YamlWriter w;
  w.comment("stereoloc rig with self-calibrated tilt and baseline; odometry estimate and standard deviations below.");
  for (auto it = back.node().begin(); it != back.node().end(); ++it) {
    const cv::FileNode n = *it;
    if (n.isString())
      w.put(n.name(), static_cast<std::string>(n));
    else if (n.isInt())
      w.put(n.name(), static_cast<int>(n));
    else
      w.put(n.name(), static_cast<double>(n));
  }
  if (stereo) {
    w.put("tilt_correction_rad", head[0]);
    w.put("tilt_correction_sigma_rad", std::sqrt(head_covariance(0, 0)));
    w.put("baseline_scale", head[1]);
    w.put("baseline_scale_sigma", std::sqrt(head_covariance(1, 1)));
  }
  if (odometry) {
    w.put("wheel_scale_left", wheels[0]);
    w.put("wheel_scale_left_sigma", std::sqrt(wheels_covariance(0, 0)));
    w.put("wheel_scale_right", wheels[1]);
    w.put("wheel_scale_right_sigma", std::sqrt(wheels_covariance(1, 1)));
    w.put("wheel_base_mm", wheels[2]);
    w.put("wheel_base_sigma_mm", std::sqrt(wheels_covariance(2, 2)));
  }
  w.writeAtomically(path);
}

SelfCalibrationResult selfCalibratingBatch(const Dataset& d, const InitialBelief& start,
                                           const SelfCalibrationConfig& config) {
  config.validate();
  if (start.mode != InitMode::Known) throw Error("self-calibration: needs a known start");
  if (d.steps.empty()) throw Error("self-calibration: the dataset has no steps");
  SelfCalibrationResult result;
  const size_t n = d.steps.size();

  // Initial guess: the EKF with the nominal calibration (its error does not grow with the run).
  EkfConfig ekf_config;
  ekf_config.init = start;
  ekf_config.use_compass = config.use_compass;
  Ekf ekf(d.map, d.odometry, ekf_config);
  std::vector<Eigen::Vector3d> poses(n);
  for (size_t k = 0; k < n; ++k) {
    const Estimate e = ekf.process(d.steps[k]);
    poses[k] = Eigen::Vector3d(e.pose.x, e.pose.y, e.pose.theta);
  }

  ceres::Problem::Options po;
  po.manifold_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  ceres::Problem problem(po);
  PoseManifold manifold;
  for (auto& p : poses) problem.AddParameterBlock(p.data(), 3, &manifold);

  const double w0 = d.odometry.wheel_base_mm;
  Eigen::Vector3d wheels(1.0, 1.0, w0);
  Eigen::Vector2d head(0.0, 1.0);
  if (config.odometry) {
    problem.AddParameterBlock(wheels.data(), 3);
    const Eigen::Vector3d sig(config.wheel_scale_sigma, config.wheel_scale_sigma, config.wheel_base_rel_sigma * w0);
    problem.AddResidualBlock(CalibrationPriorFactor<3>::Create(wheels, sig.cwiseAbs2().asDiagonal().toDenseMatrix()),
                             nullptr, wheels.data());
  }
  if (config.stereo) {
    problem.AddParameterBlock(head.data(), 2);
    const Eigen::Vector2d sig(config.tilt_sigma_rad, config.baseline_scale_sigma);
    problem.AddResidualBlock(CalibrationPriorFactor<2>::Create(head, sig.cwiseAbs2().asDiagonal().toDenseMatrix()),
                             nullptr, head.data());
  }
  problem.AddResidualBlock(PosePriorFactor::Create(start.pose, start.covariance), nullptr, poses[0].data());
  for (size_t k = 0; k < n; ++k) {
    const Step& st = d.steps[k];
    if (k > 0) {
      if (config.odometry)
        problem.AddResidualBlock(OdometryCalibrationFactor::Create(st.d_left, st.d_right, d.odometry), nullptr,
                                 poses[k - 1].data(), poses[k].data(), wheels.data());
      else
        problem.AddResidualBlock(OdometryFactor::Create(st.d_left, st.d_right, d.odometry), nullptr,
                                 poses[k - 1].data(), poses[k].data());
    }
    if (config.use_compass && st.compass)
      problem.AddResidualBlock(CompassFactor::Create(*st.compass, st.compass_sigma), nullptr, poses[k].data());
    for (const Observation& o : st.observations) {
      if (o.landmark_id < 0) {
        ++result.unidentified_observations;
        continue;
      }
      const Landmark& l = d.map.at(o.landmark_id);
      if (o.pixels) {
        if (config.stereo)
          problem.AddResidualBlock(StereoPixelCalibrationFactor::Create(d.rig, l.position, *o.pixels, o.head_pan,
                                                                        o.pixel_covariance, config.residuals),
                                   nullptr, poses[k].data(), head.data());
        else
          problem.AddResidualBlock(
              StereoPixelFactor::Create(d.rig, l.position, *o.pixels, o.head_pan, o.pixel_covariance, config.residuals),
              nullptr, poses[k].data());
      } else {
        problem.AddResidualBlock(RangeBearingFactor::Create(l.xy(), o.z(), o.covariance), nullptr, poses[k].data());
      }
    }
  }

  ceres::Solver::Options so;
  so.linear_solver_type = ceres::SPARSE_NORMAL_CHOLESKY;
  so.max_num_iterations = config.max_iterations;
  so.function_tolerance = 1e-12;
  so.gradient_tolerance = 1e-12;
  so.parameter_tolerance = 1e-12;
  so.num_threads = 1;
  ceres::Solver::Summary summary;
  ceres::Solve(so, &problem, &summary);
  result.converged = summary.termination_type == ceres::CONVERGENCE;
  result.iterations = static_cast<int>(summary.iterations.size());

  // Marginal covariances of every pose and of the calibration blocks.
  ceres::Covariance::Options co;
  co.algorithm_type = ceres::SPARSE_QR;
  co.num_threads = 1;
  ceres::Covariance cov(co);
  std::vector<std::pair<const double*, const double*>> blocks;
  for (auto& p : poses) blocks.emplace_back(p.data(), p.data());
  if (config.odometry) blocks.emplace_back(wheels.data(), wheels.data());
  if (config.stereo) blocks.emplace_back(head.data(), head.data());
  result.covariance_ok = cov.Compute(blocks, &problem);

  result.trajectory.resize(n);
  for (size_t k = 0; k < n; ++k) {
    Estimate& e = result.trajectory[k];
    e.step = d.steps[k].step;
    e.t = d.steps[k].t;
    e.pose = Pose2::fromVector(poses[k]);
    e.status = EstimateStatus::Tracking;
    if (result.covariance_ok) {
      Eigen::Matrix<double, 3, 3, Eigen::RowMajor> C;
      cov.GetCovarianceBlock(poses[k].data(), poses[k].data(), C.data());
      e.covariance = C;
    }
  }
  CalibrationEstimate& c = result.calibration;
  c.odometry = config.odometry;
  c.stereo = config.stereo;
  c.wheels = wheels;
  c.head = head;
  if (result.covariance_ok && config.odometry) {
    Eigen::Matrix<double, 3, 3, Eigen::RowMajor> C;
    cov.GetCovarianceBlock(wheels.data(), wheels.data(), C.data());
    c.wheels_covariance = C;
  }
  if (result.covariance_ok && config.stereo) {
    Eigen::Matrix<double, 2, 2, Eigen::RowMajor> C;
    cov.GetCovarianceBlock(head.data(), head.data(), C.data());
    c.head_covariance = C;
  }
  return result;
}

}  // namespace stereoloc
