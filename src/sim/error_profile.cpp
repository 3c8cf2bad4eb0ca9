#include "src/sim/error_profile.h"

#include <cmath>
#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>

#include "src/core/error.h"
#include "src/core/yaml_util.h"

namespace stereoloc {
namespace {

// One table of every numeric field, so load, save and validate cannot drift apart.
struct Field {
  const char* key;
  double ErrorProfile::*ptr;
};

const Field kFields[] = {
    {"focal_rel_sigma", &ErrorProfile::focal_rel_sigma},
    {"principal_sigma_px", &ErrorProfile::principal_sigma_px},
    {"baseline_rel_sigma", &ErrorProfile::baseline_rel_sigma},
    {"relative_rotation_sigma_rad", &ErrorProfile::relative_rotation_sigma_rad},
    {"tilt_sigma_rad", &ErrorProfile::tilt_sigma_rad},
    {"height_sigma_mm", &ErrorProfile::height_sigma_mm},
    {"k1_mean", &ErrorProfile::k1_mean},
    {"k1_sigma", &ErrorProfile::k1_sigma},
    {"k2_mean", &ErrorProfile::k2_mean},
    {"k2_sigma", &ErrorProfile::k2_sigma},
    {"tangential_sigma", &ErrorProfile::tangential_sigma},
    {"k1_estimate_sigma", &ErrorProfile::k1_estimate_sigma},
    {"k2_estimate_sigma", &ErrorProfile::k2_estimate_sigma},
    {"tangential_estimate_sigma", &ErrorProfile::tangential_estimate_sigma},
    {"exposure_s", &ErrorProfile::exposure_s},
    {"exposure_offset_max_s", &ErrorProfile::exposure_offset_max_s},
    {"pitch_sigma_rad", &ErrorProfile::pitch_sigma_rad},
    {"roll_sigma_rad", &ErrorProfile::roll_sigma_rad},
    {"wheel_radius_rel_sigma", &ErrorProfile::wheel_radius_rel_sigma},
    {"wheel_base_rel_sigma", &ErrorProfile::wheel_base_rel_sigma},
    {"slip_probability", &ErrorProfile::slip_probability},
    {"slip_min", &ErrorProfile::slip_min},
    {"slip_max", &ErrorProfile::slip_max},
    {"time_offset_sigma_s", &ErrorProfile::time_offset_sigma_s},
    {"wheel_radius_drift", &ErrorProfile::wheel_radius_drift},
    {"wheel_base_drift", &ErrorProfile::wheel_base_drift},
    {"field_dimension_sigma_mm", &ErrorProfile::field_dimension_sigma_mm},
};

cv::Mat rotationVector(const double* r) {
  cv::Mat R;
  cv::Rodrigues(cv::Vec3d(r[0], r[1], r[2]), R);
  return R;
}

}  // namespace

ErrorProfile ErrorProfile::ideal() { return ErrorProfile(); }

ErrorProfile ErrorProfile::realistic() {
  ErrorProfile p;
  p.name = "realistic";
  p.focal_rel_sigma = 0.005;
  p.principal_sigma_px = 1.0;
  p.baseline_rel_sigma = 0.01;
  p.relative_rotation_sigma_rad = deg2rad(0.1);
  p.tilt_sigma_rad = deg2rad(0.5);
  p.height_sigma_mm = 1.0;
  p.k1_mean = -0.20;
  p.k1_sigma = 0.03;
  p.k2_mean = 0.05;
  p.k2_sigma = 0.02;
  p.tangential_sigma = 0.001;
  p.k1_estimate_sigma = 0.01;
  p.k2_estimate_sigma = 0.005;
  p.tangential_estimate_sigma = 0.0003;
  p.exposure_s = 0.010;
  p.exposure_samples = 3;
  p.exposure_offset_max_s = 0.005;
  p.pitch_sigma_rad = deg2rad(0.2);
  p.roll_sigma_rad = deg2rad(0.2);
  p.wheel_radius_rel_sigma = 0.005;
  p.wheel_base_rel_sigma = 0.02;
  p.slip_probability = 0.02;
  p.slip_min = 0.1;
  p.slip_max = 0.3;
  p.time_offset_sigma_s = 0.005;
  return p;
}

ErrorProfile ErrorProfile::named(const std::string& name) {
  if (name == "ideal") return ideal();
  if (name == "realistic") return realistic();
  return load(name);
}

ErrorProfile ErrorProfile::load(const std::string& path) {
  YamlReader in(path);
  ErrorProfile p;
  p.name = in.getString("name", path);
  for (auto it = in.node().begin(); it != in.node().end(); ++it) {
    const std::string key = (*it).name();
    bool known = key == "name" || key == "exposure_samples";
    for (const Field& f : kFields) known |= key == f.key;
    if (!known) in.fail(key, "unknown parameter");
  }
  for (const Field& f : kFields) p.*f.ptr = in.getDouble(f.key, 0.0);
  p.exposure_samples = in.getInt("exposure_samples", p.exposure_samples);
  try {
    p.validate();
  } catch (const Error& e) {
    throw Error(path + ": " + e.what());
  }
  return p;
}

void ErrorProfile::save(const std::string& path) const {
  YamlWriter out;
  out.comment("stereoloc simulator error profile (src/sim/error_profile.h). Units: rad, mm, px, s; fractions.");
  out.put("name", name);
  for (const Field& f : kFields) out.put(f.key, this->*f.ptr);
  out.put("exposure_samples", exposure_samples);
  out.writeAtomically(path);
}

void ErrorProfile::validate() const {
  for (const Field& f : kFields) {
    const double v = this->*f.ptr;
    const std::string key = f.key;
    const bool may_be_negative = key == "k1_mean" || key == "k2_mean";
    if (!std::isfinite(v) || (!may_be_negative && v < 0))
      throw Error(key + ": must be a finite number" + (may_be_negative ? "" : " >= 0"));
  }
  if (slip_probability > 1) throw Error("slip_probability: must be in [0, 1]");
  if (slip_max < slip_min) throw Error("slip_max: must be at least slip_min");
  if (exposure_samples < 1 || exposure_samples > 16) throw Error("exposure_samples: must be in 1..16");
  if (focal_rel_sigma > 0.2 || baseline_rel_sigma > 0.2 || wheel_radius_rel_sigma > 0.2 || wheel_base_rel_sigma > 0.2)
    throw Error("relative sigmas must be at most 0.2");
  if (wheel_radius_drift > 0.1) throw Error("wheel_radius_drift: must be at most 0.1 per sqrt(m)");
  if (wheel_base_drift > 0.1) throw Error("wheel_base_drift: must be at most 0.1 per sqrt(m)");
  // Beyond a few centimetres the field is another field, not an error of this one.
  if (field_dimension_sigma_mm > 20) throw Error("field_dimension_sigma_mm: must be at most 20 mm");
}

bool ErrorProfile::isIdeal() const {
  for (const Field& f : kFields)
    if (this->*f.ptr != 0.0) return false;
  return true;
}

DrawnErrors drawErrors(const ErrorProfile& p, size_t steps, std::mt19937_64& rng, const std::vector<WheelIncrements>& travel) {
  std::normal_distribution<double> N(0.0, 1.0);
  std::uniform_real_distribution<double> U(0.0, 1.0);
  DrawnErrors e;
  for (int c = 0; c < 2; ++c) {
    e.focal_rel[c] = p.focal_rel_sigma * N(rng);
    e.principal_px[c][0] = p.principal_sigma_px * N(rng);
    e.principal_px[c][1] = p.principal_sigma_px * N(rng);
  }
  e.baseline_rel = p.baseline_rel_sigma * N(rng);
  for (double& r : e.relative_rotation_rad) r = p.relative_rotation_sigma_rad * N(rng);
  e.tilt_rad = p.tilt_sigma_rad * N(rng);
  e.height_mm = p.height_sigma_mm * N(rng);
  for (int c = 0; c < 2; ++c) {
    double* d = e.distortion[c];
    d[0] = p.k1_mean + p.k1_sigma * N(rng);
    d[1] = p.k2_mean + p.k2_sigma * N(rng);
    d[2] = p.tangential_sigma * N(rng);
    d[3] = p.tangential_sigma * N(rng);
    double* g = e.distortion_given[c];
    g[0] = d[0] + p.k1_estimate_sigma * N(rng);
    g[1] = d[1] + p.k2_estimate_sigma * N(rng);
    g[2] = d[2] + p.tangential_estimate_sigma * N(rng);
    g[3] = d[3] + p.tangential_estimate_sigma * N(rng);
  }
  e.exposure_offset_s = p.exposure_offset_max_s * (2.0 * U(rng) - 1.0);
  e.wheel_radius_rel[0] = p.wheel_radius_rel_sigma * N(rng);
  e.wheel_radius_rel[1] = p.wheel_radius_rel_sigma * N(rng);
  e.wheel_base_rel = p.wheel_base_rel_sigma * N(rng);
  e.time_offset_s = p.time_offset_sigma_s * N(rng);
  e.pitch_rad.resize(steps);
  e.roll_rad.resize(steps);
  e.slip_left.assign(steps, 0.0);
  e.slip_right.assign(steps, 0.0);
  for (size_t s = 0; s < steps; ++s) {
    e.pitch_rad[s] = p.pitch_sigma_rad * N(rng);
    e.roll_rad[s] = p.roll_sigma_rad * N(rng);
    // Three draws per step whether or not it slips, so one parameter does not shift the others.
    const double happens = U(rng), which = U(rng), amount = U(rng);
    if (happens < p.slip_probability) {
      const double slip = p.slip_min + (p.slip_max - p.slip_min) * amount;
      (which < 0.5 ? e.slip_left : e.slip_right)[s] = slip;
    }
  }
  if (p.wheel_radius_drift > 0 || p.wheel_base_drift > 0) {
    if (travel.size() != steps) throw Error("drawErrors: a wheel drift needs each step's wheel travel");
    e.wheel_radius_drift_left.assign(steps, 0.0);
    e.wheel_radius_drift_right.assign(steps, 0.0);
    e.wheel_base_drift.assign(steps, 0.0);
    for (size_t s = 1; s < steps; ++s) {
      const double l_m = std::fabs(travel[s].d_left) / 1000.0, r_m = std::fabs(travel[s].d_right) / 1000.0;
      e.wheel_radius_drift_left[s] = e.wheel_radius_drift_left[s - 1] + p.wheel_radius_drift * std::sqrt(l_m) * N(rng);
      e.wheel_radius_drift_right[s] = e.wheel_radius_drift_right[s - 1] + p.wheel_radius_drift * std::sqrt(r_m) * N(rng);
      e.wheel_base_drift[s] = e.wheel_base_drift[s - 1] + p.wheel_base_drift * std::sqrt(0.5 * (l_m + r_m)) * N(rng);
    }
  }
  if (p.field_dimension_sigma_mm > 0)
    for (int k = 0; k < kFieldDimensionCount; ++k) e.field_dimension_mm.push_back(p.field_dimension_sigma_mm * N(rng));
  return e;
}

FieldMap trueFieldMap(const FieldMap& given, const DrawnErrors& e) {
  if (e.field_dimension_mm.empty()) return given;
  if (e.field_dimension_mm.size() != static_cast<size_t>(kFieldDimensionCount))
    throw Error("trueFieldMap: " + std::to_string(e.field_dimension_mm.size()) + " field dimension errors, expected " +
                std::to_string(kFieldDimensionCount));
  try {
    return given.withDimensionChange(
        Eigen::Map<const Eigen::Matrix<double, kFieldDimensionCount, 1>>(e.field_dimension_mm.data()));
  } catch (const Error& err) {
    throw Error(std::string("a field dimension error needs the map its MiroSot field geometry derives: ") + err.what());
  }
}

void DrawnErrors::save(const std::string& path, const ErrorProfile& profile) const {
  YamlWriter out;
  out.comment("drawn simulator errors of this dataset (src/sim/error_profile.h): true minus given. Units: rad, mm, px, s.");
  out.put("profile", profile.name);
  out.put("focal_rel", std::vector<double>{focal_rel[0], focal_rel[1]});
  out.put("principal_px", std::vector<double>{principal_px[0][0], principal_px[0][1], principal_px[1][0], principal_px[1][1]});
  out.put("baseline_rel", baseline_rel);
  out.put("relative_rotation_rad", std::vector<double>(relative_rotation_rad, relative_rotation_rad + 3));
  out.put("tilt_rad", tilt_rad);
  out.put("height_mm", height_mm);
  out.put("distortion_left", std::vector<double>(distortion[0], distortion[0] + 4));
  out.put("distortion_right", std::vector<double>(distortion[1], distortion[1] + 4));
  out.put("distortion_given_left", std::vector<double>(distortion_given[0], distortion_given[0] + 4));
  out.put("distortion_given_right", std::vector<double>(distortion_given[1], distortion_given[1] + 4));
  out.put("exposure_s", profile.exposure_s);
  out.put("exposure_offset_s", exposure_offset_s);
  out.put("wheel_radius_rel", std::vector<double>{wheel_radius_rel[0], wheel_radius_rel[1]});
  out.put("wheel_base_rel", wheel_base_rel);
  out.put("time_offset_s", time_offset_s);
  out.put("pitch_rad", pitch_rad);
  out.put("roll_rad", roll_rad);
  out.put("slip_left", slip_left);
  out.put("slip_right", slip_right);
  if (!wheel_radius_drift_left.empty()) {
    out.put("wheel_radius_drift_left", wheel_radius_drift_left);
    out.put("wheel_radius_drift_right", wheel_radius_drift_right);
    out.put("wheel_base_drift", wheel_base_drift);
  }
  for (size_t k = 0; k < field_dimension_mm.size() && k < static_cast<size_t>(kFieldDimensionCount); ++k)
    out.put(std::string("field_") + kFieldDimensions[k].name + "_mm", field_dimension_mm[k]);
  out.writeAtomically(path);
}

cv::Mat nominalCameraMatrix(const StereoRig& nominal) {
  return (cv::Mat_<double>(3, 3) << nominal.focal(), 0, nominal.principalU(), 0, nominal.focal(), nominal.principalV(), 0,
          0, 1);
}

RawCamera trueCamera(const StereoRig& nominal, const DrawnErrors& e, int camera, size_t step) {
  RawCamera c;
  const double f = nominal.focal() * (1.0 + e.focal_rel[camera]);
  c.K = (cv::Mat_<double>(3, 3) << f, 0, nominal.principalU() + e.principal_px[camera][0], 0, f,
         nominal.principalV() + e.principal_px[camera][1], 0, 0, 1);
  c.D = cv::Mat(1, 4, CV_64F, const_cast<double*>(e.distortion[camera])).clone();
  const double roll[3] = {0.0, 0.0, step < e.roll_rad.size() ? e.roll_rad[step] : 0.0};
  c.R = rotationVector(roll);
  if (camera == 1) c.R = c.R * rotationVector(e.relative_rotation_rad);
  return c;
}

StereoCalibration givenCalibration(const StereoRig& nominal, const DrawnErrors& e) {
  StereoCalibration c;
  c.K1 = nominalCameraMatrix(nominal);
  c.K2 = c.K1.clone();
  c.D1 = cv::Mat(1, 4, CV_64F, const_cast<double*>(e.distortion_given[0])).clone();
  c.D2 = cv::Mat(1, 4, CV_64F, const_cast<double*>(e.distortion_given[1])).clone();
  c.R = cv::Mat::eye(3, 3, CV_64F);
  c.T = (cv::Mat_<double>(3, 1) << -nominal.params().baseline_mm, 0, 0);
  c.image_size = cv::Size(nominal.params().image_width, nominal.params().image_height);
  c.source = "simulated calibration";
  c.rectify();
  return c;
}

StereoCalibration trueCameraCalibration(const StereoRig& nominal, const DrawnErrors& e) {
  DrawnErrors still = e;  // the head at rest: no roll
  still.roll_rad.clear();
  const RawCamera left = trueCamera(nominal, still, 0, 0);
  const RawCamera right = trueCamera(nominal, still, 1, 0);
  StereoCalibration c;
  c.K1 = left.K;
  c.D1 = left.D;
  c.K2 = right.K;
  c.D2 = right.D;
  // X_raw = R_i X_ideal and the ideal right camera sits at (b, 0, 0) of the ideal left one, so
  // X_right = R_r (X_left - (b, 0, 0)) with the left raw frame the ideal one (no roll).
  c.R = right.R * left.R.t();
  const double b = nominal.params().baseline_mm * (1.0 + e.baseline_rel);
  c.T = -right.R * (cv::Mat_<double>(3, 1) << b, 0, 0);
  c.image_size = cv::Size(nominal.params().image_width, nominal.params().image_height);
  c.source = "true cameras";
  c.rectify();
  return c;
}

StereoRigParams trueRigParams(const StereoRigParams& nominal, const DrawnErrors& e, size_t step) {
  StereoRigParams p = nominal;
  p.baseline_mm *= 1.0 + e.baseline_rel;
  p.camera_height_mm += e.height_mm;
  p.tilt_rad += e.tilt_rad + (step < e.pitch_rad.size() ? e.pitch_rad[step] : 0.0);
  return p;
}

}  // namespace stereoloc
