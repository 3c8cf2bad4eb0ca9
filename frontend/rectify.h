#pragma once
// Rectification of raw stereo pairs for a rig built from an OpenCV calibration
// (src/core/stereo_calibration.h): the maps are computed once (cv::initUndistortRectifyMap with
// R1/P1 and R2/P2) and stored in OpenCV's fixed-point form (CV_16SC2 + CV_16UC1, 1/32 px),
// resampled bilinearly by cv::remap.
//
// The frontend needs colour only at a few pixels (goal-corner colours, the field region), so it
// uses the luma path: beginPair() converts the raw left image to luma and rectifies that one
// channel whole; the right luma and both colour images are rectified only where they are read
// (rightLumaRows(), colour()). The one-channel remap is this file's own: 8 pixels at a time
// from two 16-byte loads and byte shuffles (SSSE3), since the top-left neighbours of 8
// consecutive rectified pixels lie within 16 bytes of one or two raw rows; blocks near the image
// border take a scalar loop. Every pixel so produced equals the one a whole-image cv::remap of
// the same input gives (tested). rectify() is the whole-image colour path (overlays, monocular
// use). Cost: docs/realistic_world.md.
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

  // The one-channel remap of the luma path: Auto takes the SSSE3 kernel when the CPU has it
  // (x86), Scalar the portable loop. Both give the same pixels (integer arithmetic of
  // cv::remap's INTER_LINEAR); Scalar is for tests and comparisons.
  enum class Kernel { Auto, Scalar };
  void setKernel(Kernel kernel);
  bool vectorKernel() const { return vector_kernel_; }

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
  // index, flagged for the pixels whose neighbourhood leaves the image (replicated borders).
  std::vector<int32_t> luma_offset_[2];
  std::vector<uint16_t> luma_frac_[2];
  // The vector kernel's tables, per 8 rectified pixels of a row (w / 8 blocks per row; the
  // remaining w % 8 pixels of a row go through the scalar loop): when the 8 top-left neighbours
  // share one raw row and span at most 15 columns, two 16-byte loads of that raw row and the
  // next, byte shuffles and the same integer weights give the 8 pixels; other blocks (border,
  // a row crossing) take the scalar loop.
  struct alignas(16) Block {
    uint8_t shuffle[16];   // byte pairs (top-left, top-right) per pixel, relative to `base`
    uint8_t next_row[16];  // 0xFF for the pairs of a pixel whose top-left neighbour is a row lower
    int8_t wx[16];         // (32 - fx, fx) per pixel
    int16_t fy[8];         // fy per pixel
    int32_t base = -1;     // raw offset of the 16-byte loads; -1: scalar block
    bool crossing = false; // the top-left neighbours lie on two raw rows
  };
  std::vector<Block> blocks_[2];
  std::vector<int32_t> scalar_blocks_[2];  // indices of the blocks the scalar loop does, ascending
  bool vector_kernel_ = false;
  void checkSize(const cv::Mat& left_raw, const cv::Mat& right_raw) const;
  void remapLumaRows(int camera, const cv::Mat& raw_luma, int row0, int row1, cv::Mat& out) const;
  // Pixels [u0, u1) of rectified row v by the scalar loop.
  void remapLumaPixels(int camera, const cv::Mat& raw, int v, int u0, int u1, uint8_t* dst) const;
  // Output images. A copy of a Rectifier shares the read-only maps but gets its own outputs
  // (cv::Mat copies share pixels, and two copies may rectify in two threads).
  struct Output {
    cv::Mat m;
    Output() = default;
    Output(const Output&) {}
    Output& operator=(const Output&) { return *this; }
  };
  Output left_, right_;
  // Raw luma: left whole, right in the rows rightLumaRows() needed; padded and zeroed, so that
  // the vector kernel's 16-byte loads stay inside initialised memory.
  std::vector<uint8_t> raw_luma_[2];
  cv::Mat rawLuma(int camera);  // a header on raw_luma_[camera]
  Output grid_map_, grid_frac_, grid_out_;  // sparse colour samples
  Output raw_[2];            // the current raw pair (headers sharing the caller's pixels)
};

}  // namespace stereoloc::frontend
