#pragma once
// The stereo rig of thesis section 3.2 and appendix A: projection, triangulation, range and
// bearing, and the observation covariance from pixel noise.
//
// Frames (all right-handed, mm):
//   C0  robot: origin on the floor below the robot centre, x forward, y left, z up.
//   C1  head: C0 rotated about z by the pan angle gamma (a per-step input, rad).
//   C2  vision: origin at (x_c, 0, h) in C1, then tilted about its y axis by beta
//       (beta > 0 looks down). The cameras L and R sit at y = +b/2 and y = -b/2 in C2, their
//       optical axes along x of C2.
//   Image: u grows opposite to y of C2, v opposite to z of C2; pixel centres at integer
//       coordinates, so the image centre of a W x H image is ((W-1)/2, (H-1)/2).
// The projection that follows is u_l = o_u - f (y - b/2) / x, u_r = o_u - f (y + b/2) / x,
// v = o_v - f z / x. Its inverse is (3.4). (The printed (3.1), (3.2) have the sign of y
// flipped relative to (3.4); (3.4) is what we implement.) The thesis's (3.5) applies the
// offset after the pan; here the head pans about the robot centre and carries the offset
// camera, which is the physical construction of Fig. 3.1 and agrees with (3.5) when
// gamma = 0 or x_c = 0.
//
// A rig may carry an OpenCV stereo calibration (stereo_calibration.h): then its focal length,
// principal point, baseline and image size are those of the rectified pair, and the frontend
// resamples raw images into it (frontend/rectify.h).
#include <Eigen/Core>
#include <memory>
#include <optional>
#include <string>

#include "src/core/angles.h"
#include "src/core/pose2.h"
#include "src/core/stereo_calibration.h"

namespace stereoloc {

// One landmark seen in both images of a rectified pair.
struct StereoPixels {
  double u_left = 0.0;   // px
  double v_left = 0.0;   // px
  double u_right = 0.0;  // px
  double v_right = 0.0;  // px
  double disparity() const { return u_left - u_right; }
};

struct RangeBearing {
  double range = 0.0;    // mm, horizontal distance from the robot centre (3.6)
  double bearing = 0.0;  // rad, in C0, counter-clockwise from the robot's x axis (3.7)
};

struct StereoRigParams {
  int image_width = 320;                        // px
  int image_height = 240;                       // px
  double hfov_rad = deg2rad(60.0);              // horizontal field of view; gives f when focal_px <= 0
  double focal_px = 0.0;                        // f in px; <= 0 means "derive from hfov_rad"
  double principal_u = -1.0;                    // o_u in px; < 0 means image centre
  double principal_v = -1.0;                    // o_v in px; < 0 means image centre
  double baseline_mm = 30.0;                    // b
  double camera_height_mm = 70.0;               // height of the C2 origin above the floor
  double offset_x_mm = 0.0;                     // x_c, C2 origin ahead of the head axis
  double tilt_rad = 0.0;                        // beta, > 0 looks down
  double pixel_sigma = 0.5;                     // sigma_uu of (5.28), px
  double min_disparity_px = 0.5;                // smaller disparities are not triangulated
  double max_range_mm = 2500.0;                 // landmarks further away are not "visible"
  // s, the right camera's exposure after the left's (negative: before); 0 for cameras triggered
  // together. Within +-0.1 s. Its effect while the robot moves: src/core/exposure_offset.h.
  double exposure_offset_s = 0.0;
};

class StereoRig {
 public:
  using Matrix24d = Eigen::Matrix<double, 2, 4>;
  using Matrix34d = Eigen::Matrix<double, 3, 4>;

  explicit StereoRig(const StereoRigParams& params = StereoRigParams());
  // The rectified rig of a calibration: image size, focal length, principal point and baseline
  // come from `calibration` (its P1, P2), the mounting and noise fields from `params`.
  StereoRig(const StereoRigParams& params, const StereoCalibration& calibration);

  // Reads / writes the rig from a cv::FileStorage YAML file; errors name the file and key.
  // The key calibration_file (and optionally extrinsics_file, for the intrinsics.yml /
  // extrinsics.yml pair of OpenCV's stereo_calib sample) names an OpenCV calibration, relative
  // to the rig file's folder; the rig file then must not give focal_px, principal_u/v,
  // baseline_mm or hfov_rad, and an image size it gives must match the calibration's. save()
  // writes a carried calibration beside the rig as <rig stem>_calibration.yml. The cameras'
  // geometry (unless calibration_file gives it) and the mounting's camera_height_mm and tilt_rad
  // are required keys (docs/dataset_format.md, "rig.yaml").
  static StereoRig load(const std::string& path);
  // The mounting and noise fields of a rig file alone (camera_height_mm and tilt_rad required;
  // offset_x_mm, pixel_sigma, min_disparity_px, max_range_mm, exposure_offset_s optional), for a
  // head whose cameras come from elsewhere (a checkerboard calibration); camera keys the file
  // may also give are not read. The camera fields of the result are the defaults.
  static StereoRigParams loadMounting(const std::string& path);
  void save(const std::string& path) const;

  // The OpenCV calibration the rig was built from; null for a plain pinhole rig.
  const std::shared_ptr<const StereoCalibration>& calibration() const { return calibration_; }

  const StereoRigParams& params() const { return params_; }
  double focal() const { return f_; }
  double principalU() const { return ou_; }
  double principalV() const { return ov_; }
  // The axes of C2 expressed in C1: the rotation about y by the tilt beta.
  const Eigen::Matrix3d& tiltRotation() const { return R_tilt_; }

  // p_C2 -> p_C0 (3.5) and back, for head pan gamma.
  Eigen::Vector3d visionToRobot(const Eigen::Vector3d& p_vision, double pan) const;
  Eigen::Vector3d robotToVision(const Eigen::Vector3d& p_robot, double pan) const;

  // Projects a point given in C0; nullopt when it is not in front of the cameras.
  std::optional<StereoPixels> project(const Eigen::Vector3d& p_robot, double pan) const;
  // True when both projections fall inside the images.
  bool inImages(const StereoPixels& px) const;

  // (3.4): pixels -> p_C2. Throws GeometryError when the disparity is below min_disparity_px.
  Eigen::Vector3d triangulateVision(const StereoPixels& px, Matrix34d* J_p_px = nullptr) const;
  // (3.4) then (3.5): pixels -> p_C0. Pixel order in Jacobians: (u_left, v_left, u_right, v_right).
  Eigen::Vector3d triangulate(const StereoPixels& px, double pan, Matrix34d* J_p_px = nullptr) const;

  // (3.6), (3.7), with the Jacobian of (r, psi) w.r.t. the four pixels (the general form of 5.30).
  RangeBearing rangeBearing(const StereoPixels& px, double pan, Matrix24d* J_rb_px = nullptr) const;
  // (5.32): R = J diag(sigma^2) J^T, the covariance of (range, bearing); v_left and v_right
  // are given the same sigma as u (they matter only when the rig is tilted).
  Eigen::Matrix2d rangeBearingCovariance(const StereoPixels& px, double pan, double sigma_px) const;

  // The inverse of rangeBearing: where a point at (range, bearing) and height z (mm, in C0)
  // appears in the images. nullopt when it is behind the cameras.
  std::optional<StereoPixels> pixelsFromRangeBearing(const RangeBearing& rb, double height_mm, double pan) const;

 private:
  StereoRigParams params_;
  std::shared_ptr<const StereoCalibration> calibration_;
  double f_ = 0.0, ou_ = 0.0, ov_ = 0.0;
  Eigen::Matrix3d R_tilt_;  // C2 axes expressed in C1 (rotation about y by beta)
};

}  // namespace stereoloc
