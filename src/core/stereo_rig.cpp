#include "src/core/stereo_rig.h"

#include <cmath>
#include <filesystem>
#include <optional>
#include <opencv2/core/persistence.hpp>

#include "src/core/error.h"
#include "src/core/yaml_util.h"

namespace stereoloc {
namespace {

Eigen::Matrix3d rotZ(double a) {
  const double c = std::cos(a), s = std::sin(a);
  Eigen::Matrix3d R;
  R << c, -s, 0, s, c, 0, 0, 0, 1;
  return R;
}

}  // namespace

StereoRig::StereoRig(const StereoRigParams& p) : params_(p) {
  auto positive = [](double v, const char* name) {
    if (!(std::isfinite(v) && v > 0)) throw Error(std::string("stereo rig: ") + name + " must be a positive number");
  };
  if (p.image_width < 8 || p.image_height < 8) throw Error("stereo rig: image size must be at least 8 x 8 px");
  positive(p.baseline_mm, "baseline_mm");
  positive(p.pixel_sigma, "pixel_sigma");
  positive(p.min_disparity_px, "min_disparity_px");
  positive(p.max_range_mm, "max_range_mm");
  if (!std::isfinite(p.camera_height_mm)) throw Error("stereo rig: camera_height_mm must be finite");
  if (!std::isfinite(p.offset_x_mm)) throw Error("stereo rig: offset_x_mm must be finite");
  if (!(std::isfinite(p.tilt_rad) && std::fabs(p.tilt_rad) < kPi / 2))
    throw Error("stereo rig: tilt_rad must be in (-pi/2, pi/2)");
  if (!(std::isfinite(p.exposure_offset_s) && std::fabs(p.exposure_offset_s) <= 0.1))
    throw Error("stereo rig: exposure_offset_s must be within +-0.1 s");
  if (p.focal_px > 0) {
    // A pixel to a million: below, a camera sees nothing; above, a telescope.
    if (!(p.focal_px >= 1.0 && p.focal_px <= 1e6)) throw Error("stereo rig: focal_px must be within [1, 1e6] px");
    f_ = p.focal_px;
  } else {
    if (!(std::isfinite(p.hfov_rad) && p.hfov_rad > 0 && p.hfov_rad < kPi))
      throw Error("stereo rig: hfov_rad must be in (0, pi)");
    f_ = 0.5 * p.image_width / std::tan(0.5 * p.hfov_rad);
  }
  ou_ = p.principal_u >= 0 ? p.principal_u : 0.5 * (p.image_width - 1);
  ov_ = p.principal_v >= 0 ? p.principal_v : 0.5 * (p.image_height - 1);
  if (!std::isfinite(ou_) || !std::isfinite(ov_)) throw Error("stereo rig: principal point must be finite");
  const double c = std::cos(p.tilt_rad), s = std::sin(p.tilt_rad);
  R_tilt_ << c, 0, s, 0, 1, 0, -s, 0, c;
}

namespace {

StereoRigParams withCalibration(StereoRigParams p, const StereoCalibration& c) {
  p.image_width = c.image_size.width;
  p.image_height = c.image_size.height;
  p.focal_px = c.rectifiedFocal();
  p.principal_u = c.rectifiedPrincipalU();
  p.principal_v = c.rectifiedPrincipalV();
  p.baseline_mm = c.rectifiedBaseline();
  return p;
}

}  // namespace

StereoRig::StereoRig(const StereoRigParams& params, const StereoCalibration& calibration)
    : StereoRig(withCalibration(params, calibration)) {
  calibration_ = std::make_shared<const StereoCalibration>(calibration);
}

namespace {

// The robot mounting (appendix A) and the noise fields: ours whichever file holds the cameras.
StereoRigParams readMounting(const YamlReader& in) {
  StereoRigParams p;
  p.camera_height_mm = in.getDouble("camera_height_mm", p.camera_height_mm);
  p.offset_x_mm = in.getDouble("offset_x_mm", p.offset_x_mm);
  p.tilt_rad = in.getDouble("tilt_rad", p.tilt_rad);
  p.pixel_sigma = in.getDouble("pixel_sigma", p.pixel_sigma);
  p.min_disparity_px = in.getDouble("min_disparity_px", p.min_disparity_px);
  p.max_range_mm = in.getDouble("max_range_mm", p.max_range_mm);
  p.exposure_offset_s = in.getDouble("exposure_offset_s", p.exposure_offset_s);
  return p;
}

// The mounting has no default a robot could rely on.
void requireMounting(const YamlReader& in) {
  for (const char* k : {"camera_height_mm", "tilt_rad"})
    if (!in.has(k)) in.fail(k, "missing (the head's mounting, appendix A)");
}

}  // namespace

StereoRigParams StereoRig::loadMounting(const std::string& path) {
  const YamlReader in(path);
  requireMounting(in);
  const StereoRigParams p = readMounting(in);
  try {
    StereoRig{p};  // the mounting's and noise fields' ranges
  } catch (const Error& e) {
    throw Error(path + ": " + e.what());
  }
  return p;
}

StereoRig StereoRig::load(const std::string& path) {
  YamlReader in(path);
  StereoRigParams p = readMounting(in);
  std::optional<StereoCalibration> calibration;
  if (in.has("calibration_file")) {
    const std::filesystem::path dir = std::filesystem::path(path).parent_path();
    auto resolve = [&](const std::string& f) {
      const std::filesystem::path q(f);
      return (q.is_absolute() ? q : dir / q).string();
    };
    for (const char* k : {"focal_px", "principal_u", "principal_v", "baseline_mm", "hfov_rad"})
      if (in.has(k)) in.fail(k, "given by calibration_file; remove it from the rig file");
    const std::string ex = in.has("extrinsics_file") ? resolve(in.getString("extrinsics_file")) : std::string();
    calibration = StereoCalibration::load(resolve(in.getString("calibration_file")), ex);
    for (const auto& [key, value] : {std::pair<const char*, int>{"image_width", calibration->image_size.width},
                                     std::pair<const char*, int>{"image_height", calibration->image_size.height}})
      if (in.has(key) && in.getInt(key) != value)
        in.fail(key, std::to_string(in.getInt(key)) + " differs from the calibration's image_size (" +
                         std::to_string(value) + ")");
  } else {
    // The cameras' geometry has no default a real head could rely on: a file that lost a key
    // (cut short, edited) must not load as the thesis's rig.
    for (const char* k : {"image_width", "image_height", "baseline_mm"})
      if (!in.has(k)) in.fail(k, "missing");
    if (!in.has("focal_px") && !in.has("hfov_rad")) in.fail("focal_px", "missing (neither focal_px nor hfov_rad)");
    p.image_width = in.getInt("image_width");
    p.image_height = in.getInt("image_height");
    p.hfov_rad = in.getDouble("hfov_rad", p.hfov_rad);
    p.focal_px = in.getDouble("focal_px", p.focal_px);
    p.principal_u = in.getDouble("principal_u", p.principal_u);
    p.principal_v = in.getDouble("principal_v", p.principal_v);
    p.baseline_mm = in.getDouble("baseline_mm");
    // In the struct a non-positive focal length or a negative principal point asks for the
    // default; written in a file it is an error.
    if (in.has("focal_px") && !(p.focal_px >= 1.0 && p.focal_px <= 1e6)) in.fail("focal_px", "must be within [1, 1e6] px");
    if (in.has("hfov_rad") && !(p.hfov_rad > 0 && p.hfov_rad < kPi)) in.fail("hfov_rad", "must be in (0, pi)");
    if (in.has("principal_u") && !(p.principal_u >= 0 && p.principal_u <= p.image_width - 1))
      in.fail("principal_u", "must lie in the image, [0, image_width - 1]");
    if (in.has("principal_v") && !(p.principal_v >= 0 && p.principal_v <= p.image_height - 1))
      in.fail("principal_v", "must lie in the image, [0, image_height - 1]");
  }
  requireMounting(in);
  try {
    return calibration ? StereoRig(p, *calibration) : StereoRig(p);
  } catch (const Error& e) {
    throw Error(path + ": " + e.what());
  }
}

void StereoRig::save(const std::string& path) const {
  YamlWriter out;
  out.comment("stereoloc stereo rig (thesis 3.2, appendix A). Units: mm, rad, px.");
  if (calibration_) {
    const std::filesystem::path p(path);
    const std::string name = p.stem().string() + "_calibration.yml";
    calibration_->save((p.parent_path() / name).string());
    out.put("calibration_file", name);
  } else {
    out.put("image_width", params_.image_width);
    out.put("image_height", params_.image_height);
    out.put("hfov_rad", params_.hfov_rad);
    out.put("focal_px", f_);
    out.put("principal_u", ou_);
    out.put("principal_v", ov_);
    out.put("baseline_mm", params_.baseline_mm);
  }
  // The robot mounting (appendix A) is ours whichever file holds the cameras.
  out.put("camera_height_mm", params_.camera_height_mm);
  out.put("offset_x_mm", params_.offset_x_mm);
  out.put("tilt_rad", params_.tilt_rad);
  out.put("pixel_sigma", params_.pixel_sigma);
  out.put("min_disparity_px", params_.min_disparity_px);
  out.put("max_range_mm", params_.max_range_mm);
  if (params_.exposure_offset_s != 0.0) out.put("exposure_offset_s", params_.exposure_offset_s);
  out.writeAtomically(path);
}

Eigen::Vector3d StereoRig::visionToRobot(const Eigen::Vector3d& p_vision, double pan) const {
  const Eigen::Vector3d t(params_.offset_x_mm, 0.0, params_.camera_height_mm);
  return rotZ(pan) * (t + R_tilt_ * p_vision);
}

Eigen::Vector3d StereoRig::robotToVision(const Eigen::Vector3d& p_robot, double pan) const {
  const Eigen::Vector3d t(params_.offset_x_mm, 0.0, params_.camera_height_mm);
  return R_tilt_.transpose() * (rotZ(pan).transpose() * p_robot - t);
}

std::optional<StereoPixels> StereoRig::project(const Eigen::Vector3d& p_robot, double pan) const {
  const Eigen::Vector3d p = robotToVision(p_robot, pan);
  if (!(p.x() > 1e-6)) return std::nullopt;
  const double hb = 0.5 * params_.baseline_mm;
  StereoPixels px;
  px.u_left = ou_ - f_ * (p.y() - hb) / p.x();
  px.u_right = ou_ - f_ * (p.y() + hb) / p.x();
  px.v_left = px.v_right = ov_ - f_ * p.z() / p.x();
  return px;
}

bool StereoRig::inImages(const StereoPixels& px) const {
  const double umax = params_.image_width - 0.5, vmax = params_.image_height - 0.5;
  auto in = [&](double u, double v) { return u >= -0.5 && u < umax && v >= -0.5 && v < vmax; };
  return in(px.u_left, px.v_left) && in(px.u_right, px.v_right);
}

Eigen::Vector3d StereoRig::triangulateVision(const StereoPixels& px, Matrix34d* J_p_px) const {
  const double d = px.disparity();
  if (!std::isfinite(d) || !std::isfinite(px.v_left) || !std::isfinite(px.v_right))
    throw GeometryError("triangulate: pixel coordinates are not finite");
  if (d < params_.min_disparity_px)
    throw GeometryError("triangulate: disparity " + std::to_string(d) + " px is below the minimum " +
                        std::to_string(params_.min_disparity_px) + " px");
  const double b = params_.baseline_mm;
  const double s = px.u_left + px.u_right - 2.0 * ou_;
  const double m = 0.5 * (px.v_left + px.v_right) - ov_;
  const Eigen::Vector3d p(f_ * b / d, -0.5 * b * s / d, -b * m / d);  // (3.4)
  if (J_p_px) {
    const double d2 = d * d;
    // Columns: u_left, v_left, u_right, v_right.
    *J_p_px << -f_ * b / d2, 0.0, f_ * b / d2, 0.0,                      //
        -0.5 * b * (d - s) / d2, 0.0, -0.5 * b * (d + s) / d2, 0.0,       //
        b * m / d2, -0.5 * b / d, -b * m / d2, -0.5 * b / d;
  }
  return p;
}

Eigen::Vector3d StereoRig::triangulate(const StereoPixels& px, double pan, Matrix34d* J_p_px) const {
  Matrix34d J_vision;
  const Eigen::Vector3d p_vision = triangulateVision(px, J_p_px ? &J_vision : nullptr);
  if (J_p_px) *J_p_px = rotZ(pan) * R_tilt_ * J_vision;  // (3.5) is affine in p_C2
  return visionToRobot(p_vision, pan);
}

RangeBearing StereoRig::rangeBearing(const StereoPixels& px, double pan, Matrix24d* J_rb_px) const {
  Matrix34d J_p;
  const Eigen::Vector3d p = triangulate(px, pan, J_rb_px ? &J_p : nullptr);
  const double r2 = p.x() * p.x() + p.y() * p.y();
  const double r = std::sqrt(r2);
  if (!(r > 1e-9)) throw GeometryError("rangeBearing: point is at the robot centre");
  if (J_rb_px) {
    Eigen::Matrix<double, 2, 3> J_rb_p;
    J_rb_p << p.x() / r, p.y() / r, 0.0,  //
        -p.y() / r2, p.x() / r2, 0.0;
    *J_rb_px = J_rb_p * J_p;
  }
  return RangeBearing{r, std::atan2(p.y(), p.x())};  // (3.6), (3.7)
}

Eigen::Matrix2d StereoRig::rangeBearingCovariance(const StereoPixels& px, double pan, double sigma_px) const {
  if (!(std::isfinite(sigma_px) && sigma_px > 0)) throw Error("rangeBearingCovariance: pixel sigma must be positive");
  Matrix24d J;
  rangeBearing(px, pan, &J);
  const Eigen::Matrix2d R = sigma_px * sigma_px * J * J.transpose();  // (5.32) with Sigma_i = sigma^2 I (5.28)
  return 0.5 * (R + R.transpose());
}

std::optional<StereoPixels> StereoRig::pixelsFromRangeBearing(const RangeBearing& rb, double height_mm,
                                                              double pan) const {
  const Eigen::Vector3d p(rb.range * std::cos(rb.bearing), rb.range * std::sin(rb.bearing), height_mm);
  return project(p, pan);
}

}  // namespace stereoloc
