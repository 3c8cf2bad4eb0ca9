#pragma once
// Rectification of raw stereo pairs for a rig built from an OpenCV calibration
// (src/core/stereo_calibration.h): the maps are computed once (cv::initUndistortRectifyMap with
// R1/P1 and R2/P2) and stored in OpenCV's fixed-point form (CV_16SC2 + CV_16UC1, 1/32 px), so a
// pair costs two cv::remap calls with bilinear interpolation.
//
// Resampling changes the pixel noise of a feature found in the rectified image: an error e in
// the raw image becomes J e in the rectified one (J = d rect / d raw, the inverse of the map's
// local Jacobian), and the 1/32 px map grid adds a uniform rounding of variance (1/32)^2 / 12.
// effectiveSigma() returns sqrt((s sigma)^2 + (1/32)^2 / 12) with s the RMS singular value of J
// at that pixel (an isotropic summary: the maps of a real lens stretch by a few per cent at most).
#include <opencv2/core/mat.hpp>

#include "src/core/stereo_calibration.h"

namespace stereoloc::frontend {

class Rectifier {
 public:
  explicit Rectifier(const StereoCalibration& calibration);

  // Raw BGR (or grey) images of the calibration's image size in; rectified images of the same
  // size and type out (references into this object, valid until the next call). Raw images of
  // another size throw stereoloc::Error naming the calibration file and image_size.
  void rectify(const cv::Mat& left_raw, const cv::Mat& right_raw);
  const cv::Mat& left() const { return left_; }
  const cv::Mat& right() const { return right_; }

  // The pixel sigma of a feature at rectified (u, v) of camera 0 (left) or 1 (right) whose raw
  // sigma is `sigma_px`.
  double effectiveSigma(int camera, double u, double v, double sigma_px) const;

  // Where rectified pixel (u, v) of a camera comes from in its raw image (bilinear in the float
  // maps; for tests and the simulator's ground truth).
  cv::Point2d rawFromRectified(int camera, double u, double v) const;

  const cv::Size& size() const { return size_; }

 private:
  cv::Size size_;
  std::string source_;
  cv::Mat map_fixed_[2], map_frac_[2];  // CV_16SC2 integer part, CV_16UC1 fractional table index
  cv::Mat map_x_[2], map_y_[2];         // CV_32FC1, for rawFromRectified
  cv::Mat scale_[2];                    // CV_32FC1, s of the header comment per rectified pixel
  cv::Mat left_, right_;
};

}  // namespace stereoloc::frontend
