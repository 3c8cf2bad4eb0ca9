#include "src/calib/rectified_view.h"

#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>
#include <string>

#include "src/core/error.h"

namespace stereoloc {

RectifiedView::RectifiedView(const StereoCalibration& calibration) : calibration_(calibration) {
  const StereoCalibration& c = calibration_;
  if (c.R1.empty() || c.P1.empty() || c.R2.empty() || c.P2.empty())
    throw Error((c.source.empty() ? std::string("calibration") : c.source) + ": R1, P1, R2, P2: not rectified");
  cv::initUndistortRectifyMap(c.K1, c.D1, c.R1, c.P1, c.image_size, CV_32FC1, map_x_[0], map_y_[0]);
  cv::initUndistortRectifyMap(c.K2, c.D2, c.R2, c.P2, c.image_size, CV_32FC1, map_x_[1], map_y_[1]);
}

cv::Mat RectifiedView::draw(const cv::Mat& left_raw, const cv::Mat& right_raw, const std::vector<cv::Point2f>& left_points,
                            const std::vector<cv::Point2f>& right_points, int line_spacing_px) const {
  const StereoCalibration& c = calibration_;
  const cv::Size size = c.image_size;
  for (const cv::Mat* raw : {&left_raw, &right_raw})
    if (raw->size() != size)
      throw Error("rectified view: image size " + std::to_string(raw->cols) + "x" + std::to_string(raw->rows) +
                  " differs from the calibration's image_size " + std::to_string(size.width) + "x" +
                  std::to_string(size.height));
  if (line_spacing_px <= 0) throw Error("rectified view: line spacing must be positive, got " + std::to_string(line_spacing_px));
  cv::Mat out(size.height, 2 * size.width, CV_8UC3);
  const std::vector<cv::Point2f>* points[2] = {&left_points, &right_points};
  const cv::Mat* raws[2] = {&left_raw, &right_raw};
  for (int cam = 0; cam < 2; ++cam) {
    cv::Mat bgr = *raws[cam];
    if (bgr.channels() == 1) cv::cvtColor(bgr, bgr, cv::COLOR_GRAY2BGR);
    cv::Mat half = out(cv::Rect(cam * size.width, 0, size.width, size.height));
    cv::remap(bgr, half, map_x_[cam], map_y_[cam], cv::INTER_LINEAR);
    if (points[cam]->empty()) continue;
    std::vector<cv::Point2f> rectified;
    cv::undistortPoints(*points[cam], rectified, cam ? c.K2 : c.K1, cam ? c.D2 : c.D1, cam ? c.R2 : c.R1,
                        cam ? c.P2 : c.P1);
    for (const cv::Point2f& q : rectified)
      cv::circle(half, cv::Point(cvRound(q.x * 16), cvRound(q.y * 16)), 3 * 16, cv::Scalar(0, 0, 255), 1, cv::LINE_AA, 4);
  }
  for (int y = line_spacing_px / 2; y < size.height; y += line_spacing_px)
    cv::line(out, cv::Point(0, y), cv::Point(out.cols - 1, y), cv::Scalar(0, 200, 0), 1);
  return out;
}

}  // namespace stereoloc
