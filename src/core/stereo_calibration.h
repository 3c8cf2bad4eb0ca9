#pragma once
// An OpenCV stereo calibration (the output of cv::stereoCalibrate / cv::stereoRectify, in the
// file layout of OpenCV's samples/cpp/stereo_calib.cpp), read and written through
// cv::FileStorage, and the rectified pinhole rig it implies.
//
// Keys: M1/M2 (or K1/K2) 3x3 camera matrices, D1/D2 distortion (4, 5, 8 or 12 coefficients,
// OpenCV order k1 k2 p1 p2 [k3 [k4 k5 k6 [s1 s2 s3 s4]]]), R 3x3 and T 3x1 with
// X_right = R X_left + T (OpenCV camera frames: x right, y down, z forward; T in mm), image_size
// [width, height] (or image_width / image_height). Optional R1, R2, P1, P2, Q from
// cv::stereoRectify; when absent they are computed with CALIB_ZERO_DISPARITY and alpha = 0.
//
// The rectified left camera frame, re-ordered to x forward, y left, z up and moved to the
// middle of the rectified baseline, is the vision frame C2 of StereoRig (stereo_rig.h): the
// robot mounting (height, tilt, offset) of the rig YAML refers to the rectified cameras.
#include <opencv2/core/mat.hpp>
#include <string>

namespace stereoloc {

struct StereoCalibration {
  cv::Mat K1, K2;      // 3x3 CV_64F camera matrices, px
  cv::Mat D1, D2;      // 1xN CV_64F distortion, N in {4, 5, 8, 12}
  cv::Mat R;           // 3x3 CV_64F, left -> right camera rotation
  cv::Mat T;           // 3x1 CV_64F, mm
  cv::Size image_size; // px
  cv::Mat R1, R2;      // 3x3 CV_64F rectifying rotations
  cv::Mat P1, P2;      // 3x4 CV_64F rectified projections (P2(0,3) = -f b)
  cv::Mat Q;           // 4x4 CV_64F disparity-to-depth
  std::string source;  // file it was read from ("" when built in code), for error messages

  // Reads a cv::FileStorage file; throws stereoloc::Error "FILE: KEY: reason" for a missing key,
  // a wrong matrix size, NaN/inf, a non-positive focal length, a non-orthonormal R (or R1, R2)
  // or rectified projections that are not in the zero-disparity form this library uses.
  // With `extrinsics_path`, R, T and R1 ... Q are read from that file (OpenCV's stereo_calib
  // sample writes intrinsics.yml and extrinsics.yml).
  static StereoCalibration load(const std::string& path, const std::string& extrinsics_path = "");
  // Writes every key (R1 ... Q included) atomically.
  void save(const std::string& path) const;

  // Fills R1, R2, P1, P2, Q with cv::stereoRectify (CALIB_ZERO_DISPARITY, alpha 0, same size).
  void rectify();
  // Checks the fields as load() does; `where` prefixes the messages.
  void validate(const std::string& where) const;

  // True when raw images must be resampled before the pinhole rig applies: non-zero distortion,
  // R1/R2 not the identity, or different camera matrices.
  bool needsRemap() const;

  // The rectified pinhole parameters (px, mm).
  double rectifiedFocal() const { return P1.at<double>(0, 0); }
  double rectifiedPrincipalU() const { return P1.at<double>(0, 2); }
  double rectifiedPrincipalV() const { return P1.at<double>(1, 2); }
  double rectifiedBaseline() const { return -P2.at<double>(0, 3) / P2.at<double>(0, 0); }
};

// An ideal (undistorted, rectified) calibration of a pinhole pair with focal f, principal point
// (ou, ov) and baseline b, for tests and the simulator.
StereoCalibration idealCalibration(int width, int height, double f, double ou, double ov, double baseline_mm);

}  // namespace stereoloc
