#include "solvers/self_calibration.h"

#include <algorithm>
#include <cmath>
#include <opencv2/core.hpp>
#include <sstream>

#include "solvers/batch_smoother.h"
#include "solvers/calibrated_models.h"
#include "solvers/self_calibrated_rig.h"
#include "src/core/error.h"
#include "src/core/yaml_util.h"

namespace stereoloc {

SelfCalibrationConfig SelfCalibrationConfig::parse(const std::string& list) {
  SelfCalibrationConfig c;
  if (list.empty()) return c;
  // Split on every comma, so that an empty part ("odometry,", ",") is refused like a misspelt one.
  for (size_t start = 0;;) {
    const size_t comma = list.find(',', start);
    const std::string item = list.substr(start, comma == std::string::npos ? std::string::npos : comma - start);
    if (item == "odometry")
      c.odometry = true;
    else if (item == "stereo")
      c.stereo = true;
    else if (item == "range")
      c.range = true;
    else if (item == "field")
      c.field = true;
    else if (item != "none")
      throw Error("calibrate: unknown part '" + item + "' (expected odometry, stereo, range and/or field, comma-separated)");
    if (comma == std::string::npos) break;
    start = comma + 1;
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
  pos(disparity_offset_sigma_px, "disparity_offset_sigma_px");
  pos(column_offset_sigma_px, "column_offset_sigma_px");
  pos(focal_ratio_sigma, "focal_ratio_sigma");
  pos(focal_scale_sigma, "focal_scale_sigma");
  if (!(drive_disparity_sigma_px >= 0.0) || !std::isfinite(drive_disparity_sigma_px))
    throw Error("self-calibration: drive_disparity_sigma_px must be >= 0");
  pos(range_scale_sigma, "range_scale_sigma");
  pos(range_scale_slope_sigma, "range_scale_slope_sigma");
  pos(range_scale_curvature_sigma, "range_scale_curvature_sigma");
  pos(bearing_offset_sigma_rad, "bearing_offset_sigma_rad");
  pos(field_dimension_sigma_mm, "field_dimension_sigma_mm");
  if (field && !stereo) throw Error("self-calibration: the field block rides on the stereo block (calibrate stereo,field)");
  if (max_iterations < 1) throw Error("self-calibration: max_iterations must be at least 1");
}

PriorDistance furthestFromPrior(const CalibrationEstimate& e, const SelfCalibrationConfig& c, double nominal_wheel_base_mm) {
  PriorDistance out;
  auto consider = [&](const char* name, double value, double nominal, double sigma) {
    const double z = std::fabs(value - nominal) / sigma;
    if (z > out.sigmas || out.parameter.empty()) out = {name, z};
  };
  if (e.odometry) {
    const Eigen::Vector3d prior = wheelPriorSigma(c, nominal_wheel_base_mm).cwiseAbs2() + e.wheels_walk_variance;
    consider("wheel_scale_left", e.wheels[0], 1.0, std::sqrt(prior[0]));
    consider("wheel_scale_right", e.wheels[1], 1.0, std::sqrt(prior[1]));
    consider("wheel_base_mm", e.wheels[2], nominal_wheel_base_mm, std::sqrt(prior[2]));
  }
  if (e.stereo) {
    const CalibrationEstimate::StereoVector nominal = CalibrationEstimate().head;
    const std::pair<const char*, double> head[] = {{"tilt_correction_rad", c.tilt_sigma_rad},
                                                   {"baseline_scale", c.baseline_scale_sigma},
                                                   {"disparity_offset_px", c.disparity_offset_sigma_px},
                                                   {"column_offset_px", c.column_offset_sigma_px},
                                                   {"focal_ratio", c.focal_ratio_sigma},
                                                   {"focal_scale", c.focal_scale_sigma}};
    for (int i = 0; i < 6; ++i) consider(head[i].first, e.head[i], nominal[i], head[i].second);
  }
  if (e.range) {
    const std::pair<const char*, double> range[] = {{"range_scale_c0", c.range_scale_sigma},
                                                    {"range_scale_c1", c.range_scale_slope_sigma},
                                                    {"range_scale_c2", c.range_scale_curvature_sigma},
                                                    {"bearing_offset_rad", c.bearing_offset_sigma_rad}};
    for (int i = 0; i < 4; ++i) consider(range[i].first, e.range_bearing[i], 0.0, range[i].second);
  }
  if (e.field)
    for (int k = 0; k < kFieldDimensionCount; ++k) {
      const std::string name = std::string("field_") + kFieldDimensions[k].name + "_mm";
      consider(name.c_str(), e.field_dimensions_mm[k], 0.0, e.field_prior_sigma_mm[k]);
    }
  return out;
}

void CalibrationEstimate::saveAsRig(const std::string& path, const StereoRig& rig, double drive_disparity_sigma_px) const {
  if (!(drive_disparity_sigma_px >= 0.0) || !std::isfinite(drive_disparity_sigma_px))
    throw Error(path + ": disparity_offset_sigma_px: the drive's part must be >= 0, got " +
                std::to_string(drive_disparity_sigma_px));
  const StereoRig out = stereo ? selfCalibratedRig(rig, *this) : rig;
  out.save(path);
  // The estimate's own keys, appended as cv::FileStorage YAML (the rig reader ignores them).
  YamlReader back(path);
  YamlWriter w;
  w.comment("stereoloc rig with the self-calibrated stereo head folded in; the estimate, odometry and standard "
            "deviations below.");
  w.putScalarsOf(back);
  if (stereo) {
    w.put("tilt_correction_rad", head[0]);
    w.put("tilt_correction_sigma_rad", std::sqrt(head_covariance(0, 0)));
    w.put("baseline_scale", head[1]);
    w.put("baseline_scale_sigma", std::sqrt(head_covariance(1, 1)));
    w.put("disparity_offset_px", head[2]);
    constexpr int kExposure = stereo_pixel_calibration::kExposureOffsetEntry;
    const bool exposure_estimated = image && image_covariance(kExposure, kExposure) > 0;
    // The drive's part of the offset, unless the exposure offset is modelled: estimated, or
    // stated by the rig, whose pixels were then moved to one instant (see the header).
    const bool exposure_modelled = exposure_estimated || rig.params().exposure_offset_s != 0.0;
    w.put("disparity_offset_sigma_px",
          std::hypot(std::sqrt(head_covariance(2, 2)), exposure_modelled ? 0.0 : drive_disparity_sigma_px));
    w.put("column_offset_px", head[3]);
    w.put("column_offset_sigma_px", std::sqrt(head_covariance(3, 3)));
    w.put("focal_ratio", head[4]);
    w.put("focal_ratio_sigma", std::sqrt(head_covariance(4, 4)));
    w.put("focal_scale", head[5]);
    w.put("focal_scale_sigma", std::sqrt(head_covariance(5, 5)));
    if (row) {
      w.put("row_offset_px", row_offset_px);
      w.put("row_offset_sigma_px", std::sqrt(row_offset_variance));
    }
    if (exposure_estimated) w.put("exposure_offset_sigma_s", std::sqrt(image_covariance(kExposure, kExposure)));
  }
  if (odometry) {
    w.put("wheel_scale_left", wheels[0]);
    w.put("wheel_scale_left_sigma", std::sqrt(wheels_covariance(0, 0)));
    w.put("wheel_scale_right", wheels[1]);
    w.put("wheel_scale_right_sigma", std::sqrt(wheels_covariance(1, 1)));
    w.put("wheel_base_mm", wheels[2]);
    w.put("wheel_base_sigma_mm", std::sqrt(wheels_covariance(2, 2)));
  }
  if (range) {
    const char* keys[4][2] = {{"range_scale_c0", "range_scale_c0_sigma"},
                              {"range_scale_c1", "range_scale_c1_sigma"},
                              {"range_scale_c2", "range_scale_c2_sigma"},
                              {"bearing_offset_rad", "bearing_offset_sigma_rad"}};
    for (int i = 0; i < 4; ++i) {
      w.put(keys[i][0], range_bearing[i]);
      w.put(keys[i][1], std::sqrt(range_bearing_covariance(i, i)));
    }
  }
  if (field)
    for (int k = 0; k < kFieldDimensionCount; ++k) {
      // The change of the field's dimension, not the dimension: a property of the field, which the
      // rig reader ignores and a map built with it would take (FieldMap::withDimensionChange).
      w.put(std::string("field_") + kFieldDimensions[k].name + "_mm", field_dimensions_mm[k]);
      w.put(std::string("field_") + kFieldDimensions[k].name + "_sigma_mm", std::sqrt(field_covariance(k, k)));
    }
  if (odometry_delay_s) {
    w.put("odometry_delay_s", *odometry_delay_s);
    if (odometry_delay_sigma_s > 0) w.put("odometry_delay_sigma_s", odometry_delay_sigma_s);
  }
  w.writeAtomically(path);
}

namespace {

// The head's keys in CalibrationEstimate::head's order (saveAsRig writes them).
constexpr const char* kHeadSigmaKeys[6] = {"tilt_correction_sigma_rad", "baseline_scale_sigma",
                                           "disparity_offset_sigma_px", "column_offset_sigma_px",
                                           "focal_ratio_sigma",         "focal_scale_sigma"};

double positive(const YamlNode& y, const std::string& key) {
  const double v = y.getDouble(key);
  if (!(v > 0)) y.fail(key, "must be positive");
  return v;
}

}  // namespace

CalibrationHandover CalibrationHandover::load(const std::string& rig_path) {
  const YamlReader y(rig_path);
  CalibrationHandover h;
  if (y.has("wheel_scale_left")) {
    h.wheels = Eigen::Vector3d(positive(y, "wheel_scale_left"), positive(y, "wheel_scale_right"),
                               positive(y, "wheel_base_mm"));
    h.wheel_sigmas = Eigen::Vector3d(positive(y, "wheel_scale_left_sigma"), positive(y, "wheel_scale_right_sigma"),
                                     positive(y, "wheel_base_sigma_mm"));
  }
  if (y.has(kHeadSigmaKeys[0])) {
    CalibrationEstimate::StereoVector s;
    for (int i = 0; i < 6; ++i) s[i] = positive(y, kHeadSigmaKeys[i]);
    h.head_sigmas = s;
  }
  if (y.has("row_offset_sigma_px")) h.row_offset_sigma_px = positive(y, "row_offset_sigma_px");
  if (y.has("exposure_offset_sigma_s")) h.exposure_offset_sigma_s = positive(y, "exposure_offset_sigma_s");
  if (y.has("odometry_delay_s")) {
    const double d = y.getDouble("odometry_delay_s");
    if (!(std::fabs(d) <= 2.0)) y.fail("odometry_delay_s", "must be within +-2 s");
    h.odometry_delay_s = d;
    if (y.has("odometry_delay_sigma_s")) h.odometry_delay_sigma_s = positive(y, "odometry_delay_sigma_s");
  }
  return h;
}

void CalibrationHandover::applyPriors(SelfCalibrationConfig& c, UnmodelledNoise& noise) const {
  if (wheels) {
    c.wheel_scale_sigma = std::max((*wheel_sigmas)[0], (*wheel_sigmas)[1]);
    c.wheel_base_rel_sigma = (*wheel_sigmas)[2] / (*wheels)[2];
  }
  if (head_sigmas) {
    const CalibrationEstimate::StereoVector& s = *head_sigmas;
    c.tilt_sigma_rad = s[0];
    c.baseline_scale_sigma = s[1];
    c.disparity_offset_sigma_px = s[2];
    c.column_offset_sigma_px = s[3];
    c.focal_ratio_sigma = s[4];
    c.focal_scale_sigma = s[5];
  }
  if (row_offset_sigma_px && noise.row_offset_sigma_px > 0) noise.row_offset_sigma_px = *row_offset_sigma_px;
  if (exposure_offset_sigma_s && noise.exposure_offset_sigma_s > 0)
    noise.exposure_offset_sigma_s = *exposure_offset_sigma_s;
}

CalibrationEstimate CalibrationHandover::carriedOn(const CalibrationEstimate& run) const {
  CalibrationEstimate out = run;
  if (!run.odometry_delay_s && odometry_delay_s) {
    out.odometry_delay_s = odometry_delay_s;
    out.odometry_delay_sigma_s = odometry_delay_sigma_s;
  }
  if (!wheels) return out;
  if (!run.odometry) {
    out.odometry = true;
    out.wheels = *wheels;
    out.wheels_covariance = wheel_sigmas->cwiseAbs2().asDiagonal();
    return out;
  }
  // The run's scales multiply increments already scaled by the handed-over ones.
  const Eigen::DiagonalMatrix<double, 3> J((*wheels)[0], (*wheels)[1], 1.0);
  out.wheels = J * run.wheels;
  out.wheels_covariance = J * run.wheels_covariance * J;
  return out;
}

void applyWheelCalibration(Dataset& d, const Eigen::Vector3d& wheels) {
  if (!(wheels.allFinite() && (wheels.array() > 0).all()))
    throw Error("wheel calibration: scales and wheel base must be positive and finite");
  for (Step& s : d.steps) {
    s.d_left *= wheels[0];
    s.d_right *= wheels[1];
  }
  d.odometry.wheel_base_mm = wheels[2];
}

std::optional<CalibrationEstimate::ImageVector> imageErrorSigmas(const SelfCalibrationConfig& config,
                                                                 const UnmodelledNoise& noise) {
  if (!config.stereo || !config.image_errors) return std::nullopt;
  if (!(noise.k1_sigma > 0 || noise.k2_sigma > 0 || noise.tangential_sigma > 0 ||
        noise.relative_rotation_sigma_rad > 0 || noise.exposure_offset_sigma_s > 0))
    return std::nullopt;
  CalibrationEstimate::ImageVector s;
  for (int c = 0; c < 2; ++c)
    s.segment<4>(4 * c) << noise.k1_sigma, noise.k2_sigma, noise.tangential_sigma, noise.tangential_sigma;
  s.segment<3>(8).setConstant(noise.relative_rotation_sigma_rad);
  s[stereo_pixel_calibration::kExposureOffsetEntry] = noise.exposure_offset_sigma_s;
  return s;
}

std::optional<double> rowOffsetSigma(const SelfCalibrationConfig& config, const UnmodelledNoise& noise) {
  if (!config.stereo || !config.row_offset || !(noise.row_offset_sigma_px > 0)) return std::nullopt;
  return noise.row_offset_sigma_px;
}

std::vector<FeatureOffsetPrior> featureOffsetSigmas(const FieldMap& map, const SelfCalibrationConfig& config,
                                                    const UnmodelledNoise& noise) {
  std::vector<FeatureOffsetPrior> out;
  if (!rowOffsetSigma(config, noise) || !config.feature_offsets) return out;
  for (const Landmark& l : map.landmarks()) {
    const FeatureOffsetSigma sigma = featureOffsetSigma(l.type, noise);
    if (sigma.column > 0 || sigma.disparity > 0) out.push_back({l.id, sigma});
  }
  return out;
}

Eigen::Matrix4d calibratedPixelCovariance(const Observation& obs, const Landmark& landmark,
                                          const ObservationModelConfig& config, bool image_block, bool row_block,
                                          bool feature_offsets) {
  if (!image_block) return pixelCovarianceFor(obs, landmark, config, row_block, feature_offsets);
  ObservationModelConfig rest = config;
  UnmodelledNoise& n = rest.unmodelled;
  UnmodelledNoise block;  // the terms the image block takes
  block.k1_sigma = n.k1_sigma;
  block.k2_sigma = n.k2_sigma;
  block.tangential_sigma = n.tangential_sigma;
  block.relative_rotation_sigma_rad = n.relative_rotation_sigma_rad;
  n.k1_sigma = n.k2_sigma = n.tangential_sigma = n.relative_rotation_sigma_rad = 0;
  Eigen::Matrix4d C = pixelCovarianceFor(obs, landmark, rest, row_block, feature_offsets);
  if (obs.pixels) {
    // J diag(sigma^2) J^T with the column rows of J zero: the (v_l, v_r) block alone.
    const Eigen::Matrix4d B = unmodelledPixelCovariance(config.rig, *obs.pixels, block);
    for (int i : {1, 3})
      for (int j : {1, 3}) C(i, j) += B(i, j);
  }
  return C;
}

SelfCalibrationResult selfCalibratingBatch(const Dataset& d, const InitialBelief& start,
                                           const SelfCalibrationConfig& config) {
  config.validate();
  if (config.consider) throw Error("self-calibration: consider is the EKF's; the batch estimates the calibration");
  if (start.mode != InitMode::Known) throw Error("self-calibration: needs a known start");
  if (d.steps.empty()) throw Error("self-calibration: the dataset has no steps");
  BatchSmootherConfig c;
  c.init = start;
  c.use_compass = config.use_compass;
  c.max_iterations = config.max_iterations;
  c.observation_model.model =
      config.residuals == PixelResiduals::All ? ObservationModel::Pixels : ObservationModel::PixelColumns;
  c.observation_model.rig = d.rig;
  c.cut_at_reinitialisation = false;
  c.calibration = config;
  BatchSmoother batch(d.map, d.odometry, c);
  for (const Step& st : d.steps) batch.process(st);
  SelfCalibrationResult result;
  result.trajectory = batch.finish();
  result.calibration = batch.calibration();
  const BatchSummary& s = batch.summary();
  result.converged = s.converged;
  result.iterations = s.iterations;
  result.unidentified_observations = s.unassociated_observations;
  result.covariance_ok = s.covariance_status == CovarianceStatus::Ok;
  return result;
}

}  // namespace stereoloc
