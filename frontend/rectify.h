#pragma once
// Rectification of raw stereo pairs for a rig built from an OpenCV calibration
// (src/core/stereo_calibration.h): the maps are computed once (cv::initUndistortRectifyMap with
// R1/P1 and R2/P2) and stored in OpenCV's fixed-point form (CV_16SC2 + CV_16UC1, 1/32 px),
// resampled bilinearly by cv::remap.
//
// The frontend needs colour only at a few pixels (goal-corner colours, the field region), so it
// uses the luma path: beginPair() converts the raw left image to luma and rectifies that one
// channel whole; the right luma and both colour images are rectified only where they are read
// (rightLumaRows(), colour()). Every pixel so produced equals the one a whole-image cv::remap of
// the same input gives. rectify() is the whole-image colour path (overlays, monocular use).
//
// Resampling changes the pixel noise of a feature found in the rectified image: an error e in
// the raw image becomes J e in the rectified one (J = d rect / d raw, the inverse of the map's
// local Jacobian), and the 1/32 px map grid adds a uniform rounding of variance (1/32)^2 / 12.
// effectiveSigma() returns sqrt((s sigma)^2 + (1/32)^2 / 12) with s the RMS singular value of J
// at that pixel (an isotropic summary: the maps of a real lens stretch by a few per cent at most).
#include <opencv2/core/mat.hpp>
#include <vector>

#include "src/core/stereo_calibration.h"

namespace stereoloc::frontend {

class Rectifier {
 public:
  explicit Rectifier(const StereoCalibration& calibration);

  // Raw BGR (or grey) images of the calibration's image size in; rectified images of the same
  // size and type out (references into this object, valid until the next call). Raw images of
  // another size throw stereoloc::Error naming the calibration file and image_size.
  void rectify(const cv::Mat& left_raw, const cv::Mat& right_raw);
  const cv::Mat& left() const { return left_.m; }
  const cv::Mat& right() const { return right_.m; }

  // The luma path. Starts a raw BGR pair (checked as rectify() does; the pair must stay alive
  // and unchanged until the next beginPair() or rectify()) and writes the rectified luma of the
  // left image (CV_8UC1) into left_luma. The raw luma is OpenCV's BGR2GRAY, so left_luma is
  // cv::remap(cvtColor(raw)).
  void beginPair(const cv::Mat& left_raw_bgr, const cv::Mat& right_raw_bgr, cv::Mat& left_luma);
  // Makes rows [row0, row1) (clamped to the image) of the rectified right luma valid in
  // right_luma (CV_8UC1 of the full size, allocated here; other rows are left as they were).
  void rightLumaRows(int row0, int row1, cv::Mat& right_luma);
  // Makes the rectified colour of camera 0 (left) or 1 (right) of the current pair valid at the
  // pixels (rect.x + i step, rect.y + j step) inside rect (clamped to the image) in
  // colourImage(camera), a full-size CV_8UC3 image whose other pixels are unspecified.
  void colour(int camera, const cv::Rect& rect, int step = 1);
  const cv::Mat& colourImage(int camera) const { return camera == 0 ? left_.m : right_.m; }

  // The whole rectified colour image of a raw image of one camera, as a new image (overlays).
  cv::Mat rectifiedCopy(int camera, const cv::Mat& raw) const;

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
  // Per rectified row of each camera, the first and last raw row the bilinear remap reads.
  std::vector<int> raw_row_min_[2], raw_row_max_[2];
  // The one-channel remap's tables per rectified pixel: raw offset of the top-left neighbour
  // (column and row clamped so that its 2x2 neighbourhood is inside) and the 1/32 px fraction
  // index; the pixels whose neighbourhood leaves the image, handled apart with replicated borders.
  std::vector<int32_t> luma_offset_[2];
  std::vector<uint16_t> luma_frac_[2];
  std::vector<int32_t> border_pixels_[2];
  void checkSize(const cv::Mat& left_raw, const cv::Mat& right_raw) const;
  void remapLumaRows(int camera, const cv::Mat& raw_luma, int row0, int row1, cv::Mat& out) const;
  // Output images. A copy of a Rectifier shares the read-only maps but gets its own outputs
  // (cv::Mat copies share pixels, and two copies may rectify in two threads).
  struct Output {
    cv::Mat m;
    Output() = default;
    Output(const Output&) {}
    Output& operator=(const Output&) { return *this; }
  };
  Output left_, right_;
  Output raw_luma_[2];       // raw luma: left whole, right in the rows rightLumaRows() needed
  Output grid_map_, grid_frac_, grid_out_;  // sparse colour samples
  Output raw_[2];            // the current raw pair (headers sharing the caller's pixels)
};

}  // namespace stereoloc::frontend
