#pragma once
// A stereo calibration checked by eye (`stereoloc calibrate --overlay DIR`): a raw pair
// rectified with the calibration, left and right side by side, with a horizontal line every
// few rows and given raw points (a board's corners) marked where rectification puts them. With
// a good calibration every corner's two marks lie on one row, and the lines cross the same
// scene features in both halves.
#include <opencv2/core.hpp>
#include <vector>

#include "src/core/stereo_calibration.h"

namespace stereoloc {

class RectifiedView {
 public:
  // Rectification maps computed once (cv::initUndistortRectifyMap with R1/P1 and R2/P2).
  explicit RectifiedView(const StereoCalibration& calibration);

  // The rectified pair side by side (BGR, twice the calibration's width), lines every
  // `line_spacing_px` rows (> 0), each raw point of left_points / right_points marked. Throws
  // Error for images of another size than the calibration's.
  cv::Mat draw(const cv::Mat& left_raw, const cv::Mat& right_raw, const std::vector<cv::Point2f>& left_points,
               const std::vector<cv::Point2f>& right_points, int line_spacing_px = 16) const;

 private:
  StereoCalibration calibration_;
  cv::Mat map_x_[2], map_y_[2];
};

}  // namespace stereoloc
