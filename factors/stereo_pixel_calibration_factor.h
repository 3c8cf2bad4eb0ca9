#pragma once
// Stereo pixel factor with the stereo calibration as parameters (self-calibration): the head
// tilt, the baseline and the pixel offsets of the pair as the robot really has them, against
// the rig the user measured.
//
//   r = S (pi(p, l; q) - z)                                4 residuals (u_l, v_l, u_r, v_r) or
//                                                          2 (u_l, u_r) with PixelResiduals::Columns
//
// p: robot pose (x, y, theta), world frame (mm, mm, rad). l: landmark (x, y, z), world, mm.
// q = (dbeta, k, delta_d, delta_u, phi, psi): calibration block; dbeta the tilt correction
// (rad, added to the rig's tilt beta; > 0 looks further down), k the baseline scale
// (dimensionless, nominally 1), delta_d the disparity offset and delta_u the column offset (px,
// nominally 0), phi the right camera's focal length error relative to the left's and psi the
// left camera's focal length error (dimensionless, nominally 0). pi: the projection of
// factors/stereo_pixel_factor.h with C0 -> C1 (pan) -> C2 (offset, height, tilt beta + dbeta),
// then, with F = f (1 + psi),
//   u_l = o_u + delta_u + delta_d / 2 - F (y - k b/2) / x,
//   u_r = o_u + delta_u - delta_d / 2 - F (1 + phi) (y + k b/2) / x,   v = o_v - F z / x,
// so the disparity u_l - u_r is F k b / x + delta_d (+ phi F (y + k b/2) / x) and the mean
// column moves by delta_u.
// Why these: range is f b / disparity (3.4), so a baseline error is a range scale error and a
// disparity offset a range error growing with range^2 (a difference of the principal points,
// or a relative yaw eps of the cameras, f eps: 0.1 deg is ~0.5 px at f = 277 px, a large
// fraction of the disparity of a far landmark); a focal length difference of the two cameras
// is a disparity error proportional to the bearing's tangent (0.7 % of 277 px: 1.1 px at 30 deg);
// delta_u is a bearing offset (mean principal point, head pan); a focal length error common to
// both cameras (psi; 0.5 % of 277 px is 0.8 px at 30 deg) scales the tangent of every bearing,
// which a baseline scale cannot absorb: F k b is the range scale, F alone the bearing scale, so
// a known map separates the two; the tilt sets where the floor
// and the landmarks appear in the rows and, through the (3.4) -> (3.5) rotation, the range of
// every point below or above the camera. The columns enter through an equivalent point in C2:
// any (u_l, u_r) is the projection of y' = (2 o_u - u_l - u_r) x / (2 f) with half baseline
// (u_l - u_r) x / (2 f), so v is unchanged and the shared residual code applies.
// z: measured pixels; S: the upper square-root information of their covariance, as in
// factors/stereo_pixel_factor.h.
//
// Raw cameras. The camera errors q stands for are errors of the RAW cameras (a principal point,
// a focal length), which the rectification of the given calibration carries into the rectified
// image through its local map: raw column shift delta moves the rectified pixel by
// A (delta, 0), A = (d raw px / d rectified px)^-1 from the calibration's camera matrix K,
// distortion D and rectifying rotation R_c (raw = K dist(norm(R_c^T x_r))). With k1 = -0.2 the
// map's scale at the image's edge differs from the centre's by ~20 %, so a 1.5 px disparity
// offset is 1.5 px at the centre and ~1.8 px at the edge, a fixed error of the size of the goal
// corners' sigma_d (0.105 px) that the rectified-space terms above cannot take. When the rig's
// calibration needs a remap (StereoCalibration::needsRemap), the columns therefore get, per
// camera, (A_00 f_raw / f - 1) times its offset (delta_u +- delta_d / 2) and, for the focal
// errors, the raw scaling's rectified column (A_0 K diag(x_d, y_d) per unit fx, fy scale) minus
// the rectified terms' (u - o_u); these gains are evaluated at the measured pixels (they vary
// slowly over the image), so the terms are linear in q. The same raw errors are what
// selfCalibratedRig (solvers/self_calibrated_rig.h) folds back into the raw cameras. The rows
// keep the rectified-space terms (the frontend reports the right row equal to the left).
//
// Image errors (factors/stereo_pixel_image_calibration_factor.h): a third block e of fixed errors of the
// images that are not camera parameters of q but the same in every image of a run: each
// camera's error of the calibrated lens distortion (dk1, dk2, dp1, dp2: OpenCV's model moves a
// normalised point by (x r^2, y r^2), (x r^4, y r^4), (2xy, r^2 + 2y^2), (r^2 + 2x^2, 2xy); the
// rectified column by A_0 K of that) and the right camera's rotation against the left
// (pitch, yaw, roll: f (x y, x^2, -y) on its column; the yaw's constant f is the disparity
// offset delta_d, which reaches the right column with the raw gain, so the yaw keeps
// f (x^2 - (A_00 f_raw / f - 1))). e is whitened: parameter i is e_i sigma_i with the sigmas
// given at creation, so its prior is the identity and a zero sigma switches a term off. Its last
// entry is the error dt of the right camera's exposure offset (s; src/core/exposure_offset.h):
// the right column is projected from the pose the robot reaches in dt at the image's body rate
// (v, w) (given at creation; ahead by v dt along the heading, turned by w dt), which is exact
// for the rectified camera because it moves rigidly with the robot, and zero at rest. Only
// columns move.
// Row offset (factors/stereo_pixel_row_calibration_factor.h): a fourth block dv (px), the rows'
// misalignment of the rectified pair (the right camera's row minus the left's for one scene
// point: the raw principal points' row difference and f times the relative pitch, as the given
// rectification carries them). The frontend finds the right feature on the left's row, so a
// feature whose edges are not vertical slides along them: u_r moves by s dv with s the
// observation's slide gain (Observation::slide_gain, frontend/stereo_match.h slideGain). The
// rows are not moved (the frontend reports the right row equal to the left's).
// Feature offsets (factors/stereo_pixel_feature_calibration_factor.h): a further block (b_c, b_d)
// (px), the constant parts of one feature's errors: both columns move by b_c, u_r by b_d too.
// Evaluation fails when the landmark is not in front of the cameras.
#include <ceres/cost_function.h>

#include <Eigen/Core>
#include <cmath>

#include "factors/stereo_pixel_factor.h"
#include "src/core/error.h"
#include "src/core/exposure_offset.h"
#include "src/core/stereo_rig.h"

namespace stereoloc {

namespace stereo_pixel_calibration {

// e = (dk1, dk2, dp1, dp2 of the left camera, the same of the right, the right camera's pitch,
// yaw, roll, the error of the right camera's exposure offset): lens terms dimensionless,
// rotations rad, the exposure offset s.
inline constexpr int kImageErrorSize = 12;
inline constexpr int kExposureOffsetEntry = 11;
using ImageErrorVector = Eigen::Matrix<double, kImageErrorSize, 1>;

// OpenCV's distortion of a normalised point (k1 k2 p1 p2 [k3 [k4 k5 k6 [s1 s2 s3 s4]]]), with the
// first four coefficients as separate (differentiable) values.
template <typename T>
void distort(const T& x, const T& y, const T* k4, const double* rest, int n, T* xd, T* yd) {
  const T r2 = x * x + y * y, r4 = r2 * r2, r6 = r4 * r2;
  const double k3 = n > 4 ? rest[0] : 0.0, k4c = n > 5 ? rest[1] : 0.0, k5 = n > 6 ? rest[2] : 0.0,
               k6 = n > 7 ? rest[3] : 0.0;
  const T radial = (T(1.0) + k4[0] * r2 + k4[1] * r4 + T(k3) * r6) / (T(1.0) + T(k4c) * r2 + T(k5) * r4 + T(k6) * r6);
  *xd = x * radial + T(2.0) * k4[2] * x * y + k4[3] * (r2 + T(2.0) * x * x);
  *yd = y * radial + k4[2] * (r2 + T(2.0) * y * y) + T(2.0) * k4[3] * x * y;
  if (n > 8) {
    *xd += T(rest[4]) * r2 + T(rest[5]) * r4;
    *yd += T(rest[6]) * r2 + T(rest[7]) * r4;
  }
}

// Per observation: the rectified columns' response to errors of the raw cameras, at the
// measured pixels (see the file comment). Index 0 the left camera, 1 the right.
struct ColumnResponse {
  bool raw = false;                  // q's terms through the rectification map
  double offset[2] = {0, 0};         // A_00 f_raw / f - 1
  double focal_u[2] = {0, 0};        // per unit fx scale: A_00 fx x_d - (u - o_u)
  double focal_v[2] = {0, 0};        // per unit fy scale: A_01 fy y_d
  bool image = false;                // the image-error block e
  double lens[2][4] = {{0, 0, 0, 0}, {0, 0, 0, 0}};  // per unit e_i (sigma_i included)
  double rotation[3] = {0, 0, 0};    // right column per unit e_8..e_10 (sigma included)
  // The robot's motion during the exposure offset's error per unit e_11 (sigma included): ahead
  // (mm) and turned (rad) at the right exposure.
  double exposure_ahead_mm = 0;
  double exposure_turn_rad = 0;
};

// Throws Error naming `who` unless the body rate is finite.
void checkRate(const char* who, const BodyRate& rate);

// The pixel covariance of an image-block factor with the exposure offset's rate noise: the right
// column moves by about f (1 + x_r^2) w dt for the block's dt (prior sigma sigma_dt) at turn rate
// w, and w is known to rate.yaw_sigma_rad_s only; a model that took it as exact would read the
// rate's noise as information on dt. (f (1 + x_r^2) yaw_sigma sigma_dt)^2 joins u_r's variance.
Eigen::Matrix4d withExposureRateNoise(const Eigen::Matrix4d& C, const StereoRig& rig, const StereoPixels& px,
                                      const ImageErrorVector& sigmas, const BodyRate& rate);

// The checks and whitening of a factor with an optional image block (`sigmas` null: none): the
// body rate finite, the sigmas finite and >= 0 (Error naming `who`), and the upper square-root
// information of the pixel covariance, with the exposure offset's rate noise when the block is
// there (withExposureRateNoise).
Eigen::Matrix4d imageBlockSqrtInformation(const char* who, const StereoRig& rig, const StereoPixels& px,
                                          const Eigen::Matrix4d& pixel_covariance, PixelResiduals residuals,
                                          const ImageErrorVector* sigmas, const BodyRate& rate);

// `sigmas` null: no image-error block. `rate`: the robot's motion at the image (bodyRate).
ColumnResponse columnResponse(const StereoRig& rig, const StereoPixels& px, const ImageErrorVector* sigmas,
                              const BodyRate& rate);

}  // namespace stereo_pixel_calibration

// The projection with calibration q (and the image errors e, or null), shared by the factors.
class StereoPixelCalibrationModel {
 public:
  StereoPixelCalibrationModel(const StereoRig& rig, const Eigen::Vector3d& landmark, const StereoPixels& pixels,
                              double pan, const Eigen::Matrix4d& sqrt_information, PixelResiduals residuals,
                              const stereo_pixel_calibration::ImageErrorVector* image_sigmas, const BodyRate& rate,
                              double slide_gain = 0.0)
      : landmark_(landmark), sqrt_info_(sqrt_information), rows_(residuals == PixelResiduals::All),
        response_(stereo_pixel_calibration::columnResponse(rig, pixels, image_sigmas, rate)), slide_gain_(slide_gain) {
    pan_cos_ = std::cos(pan);
    pan_sin_ = std::sin(pan);
    t_ = Eigen::Vector3d(rig.params().offset_x_mm, 0.0, rig.params().camera_height_mm);
    tilt_ = rig.params().tilt_rad;
    f_ = rig.focal();
    ou_ = rig.principalU();
    ov_ = rig.principalV();
    half_baseline_ = 0.5 * rig.params().baseline_mm;
    z_ << pixels.u_left, pixels.v_left, pixels.u_right, pixels.v_right;
  }

  template <typename T>
  bool evaluate(const T* pose, const T* calib, const T* image, T* residual) const {
    return evaluate<T>(pose, calib, image, nullptr, residual);
  }
  // `row`: the row offset dv (1 value, px), or null.
  template <typename T>
  bool evaluate(const T* pose, const T* calib, const T* image, const T* row, T* residual) const {
    return evaluate<T>(pose, calib, image, row, nullptr, residual);
  }
  // `offset`: the feature's own offsets (b_c, b_d) (px): b_c moves both columns, b_d u_r; or null.
  template <typename T>
  bool evaluate(const T* pose, const T* calib, const T* image, const T* row, const T* offset, T* residual) const {
    using std::cos;
    using std::sin;
    const stereo_pixel_calibration::ColumnResponse& g = response_;
    const T beta = T(tilt_) + calib[0];
    const T cb = cos(beta), sb = sin(beta);
    const T z1 = T(landmark_[2]) - T(t_[2]);
    // The landmark in C2 seen from the robot at (x + ax, y + ay) with heading `heading`: C0 =
    // R(heading)^T (l_xy - t_xy), height unchanged; C1 = Rz(pan)^T C0 minus the offset t; C2 =
    // R_y(beta)^T C1 (stereo_rig.h: R_tilt = [c 0 s; 0 1 0; -s 0 c]). Returns (x2, y1 = y2, z2).
    auto inC2 = [&](const T& heading, const T& ax, const T& ay, T* x2, T* y1, T* z2) {
      const T c = cos(heading), s = sin(heading);
      const T dx = T(landmark_[0]) - pose[0] - ax, dy = T(landmark_[1]) - pose[1] - ay;
      const T x0 = c * dx + s * dy, y0 = -s * dx + c * dy;
      const T x1 = T(pan_cos_) * x0 + T(pan_sin_) * y0 - T(t_[0]);
      *y1 = -T(pan_sin_) * x0 + T(pan_cos_) * y0;
      *x2 = cb * x1 - sb * z1;
      *z2 = sb * x1 + cb * z1;
    };
    T x2, y1, z2;
    inC2(pose[2], T(0.0), T(0.0), &x2, &y1, &z2);
    if (!(x2 > T(stereo_pixel::kMinDepth))) return false;
    // The right camera exposes at the pose the robot reaches in the exposure offset's error
    // (src/core/exposure_offset.h): ahead by v dt along its heading, turned by w dt, dt = sigma e_11.
    T x2r = x2, y1r = y1;
    if (image && (g.exposure_ahead_mm != 0.0 || g.exposure_turn_rad != 0.0)) {
      const T e = image[stereo_pixel_calibration::kExposureOffsetEntry];
      const T ahead = T(g.exposure_ahead_mm) * e;
      T z2r;
      inC2(pose[2] + T(g.exposure_turn_rad) * e, ahead * cos(pose[2]), ahead * sin(pose[2]), &x2r, &y1r, &z2r);
      if (!(x2r > T(stereo_pixel::kMinDepth))) return false;
    }
    const T hb = calib[1] * T(half_baseline_);
    const T f = T(f_) * (T(1.0) + calib[5]);
    // Columns relative to o_u.
    T cl = calib[3] + 0.5 * calib[2] - f * (y1 - hb) / x2;
    T cr = calib[3] - 0.5 * calib[2] - f * (T(1.0) + calib[4]) * (y1r + hb) / x2r;
    if (g.raw) {
      // Raw principal points and focal lengths through the rectification (file comment).
      const T psi_right = (T(1.0) + calib[5]) * (T(1.0) + calib[4]) - T(1.0);
      cl += T(g.offset[0]) * (calib[3] + 0.5 * calib[2]) + calib[5] * T(g.focal_u[0] + g.focal_v[0]);
      cr += T(g.offset[1]) * (calib[3] - 0.5 * calib[2]) + psi_right * T(g.focal_u[1]) + calib[5] * T(g.focal_v[1]);
    }
    if (image) {
      for (int j = 0; j < 4; ++j) {
        cl += T(g.lens[0][j]) * image[j];
        cr += T(g.lens[1][j]) * image[4 + j];
      }
      for (int j = 0; j < 3; ++j) cr += T(g.rotation[j]) * image[8 + j];
    }
    if (row) cr += T(slide_gain_) * row[0];
    if (offset) {
      cl += offset[0];
      cr += offset[0] + offset[1];
    }
    const T per_px = x2 / T(f_);  // mm in C2 per pixel of column at this depth, for the shared code's f
    const T y2 = -0.5 * (cl + cr) * per_px;
    const T half_baseline = 0.5 * (cl - cr) * per_px;
    // The rows through the same F: the shared code projects with the nominal f, so z scales.
    return stereo_pixel::whitenedResiduals(x2, y2, (T(1.0) + calib[5]) * z2, half_baseline, f_, ou_, ov_, sqrt_info_,
                                           rows_, z_, residual);
  }

 private:
  Eigen::Vector3d landmark_;
  Eigen::Matrix4d sqrt_info_;
  bool rows_;
  stereo_pixel_calibration::ColumnResponse response_;
  double slide_gain_ = 0;
  double pan_cos_ = 1, pan_sin_ = 0, tilt_ = 0;
  Eigen::Vector3d t_;
  double f_ = 0, ou_ = 0, ov_ = 0, half_baseline_ = 0;
  Eigen::Vector4d z_;
};

struct StereoPixelCalibrationFactor {
  StereoPixelCalibrationFactor(const StereoRig& rig, const Eigen::Vector3d& landmark, const StereoPixels& pixels,
                               double pan, const Eigen::Matrix4d& sqrt_information, PixelResiduals residuals)
      : model_(rig, landmark, pixels, pan, sqrt_information, residuals, nullptr, BodyRate()) {}

  template <typename T>
  bool operator()(const T* pose, const T* calib, T* residual) const {
    return model_.evaluate<T>(pose, calib, nullptr, residual);
  }

  static constexpr int kCalibrationSize = 6;  // (dbeta, k, delta_d, delta_u, phi, psi)

  // Blocks: pose (3), stereo calibration (dbeta, k, delta_d, delta_u, phi, psi) (6).
  static ceres::CostFunction* Create(const StereoRig& rig, const Eigen::Vector3d& landmark, const StereoPixels& pixels,
                                     double pan, const Eigen::Matrix4d& pixel_covariance, PixelResiduals residuals);
  // The same with independent pixels of noise sigma (px, > 0).
  static ceres::CostFunction* Create(const StereoRig& rig, const Eigen::Vector3d& landmark, const StereoPixels& pixels,
                                     double pan, double sigma, PixelResiduals residuals);

 private:
  StereoPixelCalibrationModel model_;
};

}  // namespace stereoloc
