// The frontend's rectification on real photographs: OpenCV's sample stereo pairs
// (data/real/checkerboard), rectified with the calibration `calibrate` makes of them. In the
// rectified images a board corner's two images lie on one row (what stereo matching along rows
// needs), and each lies where OpenCV's point mapping of its raw corner puts it.
#include <gtest/gtest.h>

#include <opencv2/calib3d.hpp>
#include <algorithm>
#include <cmath>
#include <cstdio>

#include "frontend/rectify.h"
#include "src/calib/stereo_target_calibration.h"
#include "src/calib/target_pairs.h"

namespace stereoloc::frontend {
namespace {

TEST(RectifyReal, ABoardsCornersShareTheirRowsInTheRectifiedPhotographs) {
  const std::vector<TargetPair> pairs = readTargetPairs(std::string(STEREOLOC_DATA_DIR) + "/real/checkerboard");
  CheckerBoard board;
  board.columns = 9;
  board.rows = 6;
  board.square_mm = 1.0;
  const StereoCalibration c = calibrateStereoFromTargets(pairs, board).calibration;
  Rectifier rectifier(c);
  double row_sq = 0.0, map_sq = 0.0;
  int corners = 0, found = 0;
  for (const TargetPair& pair : pairs) {
    rectifier.rectify(pair.left, pair.right);
    const std::vector<cv::Point2f> l = detectBoardCorners(rectifier.left(), board);
    std::vector<cv::Point2f> r = detectBoardCorners(rectifier.right(), board);
    if (l.empty() || r.empty()) continue;  // the rectified view is cropped: a board near the edge leaves it
    ++found;
    orderLike(l, r);
    // The raw corners mapped by OpenCV, in the same order.
    std::vector<cv::Point2f> raw_l = detectBoardCorners(pair.left, board), mapped;
    ASSERT_EQ(raw_l.size(), l.size()) << pair.name;
    orderLike(l, raw_l);
    cv::undistortPoints(raw_l, mapped, c.K1, c.D1, c.R1, c.P1);
    for (size_t k = 0; k < l.size(); ++k) {
      row_sq += std::pow(l[k].y - r[k].y, 2);
      map_sq += std::pow(cv::norm(l[k] - mapped[k]), 2);
      ++corners;
    }
  }
  ASSERT_GE(found, 10);
  const double row_rms = std::sqrt(row_sq / corners), map_rms = std::sqrt(map_sq / corners);
  std::printf("%d of %zu pairs whole in the rectified images: rows differ by %.3f px RMS, corners %.3f px RMS from "
              "OpenCV's mapping of the raw ones\n",
              found, pairs.size(), row_rms, map_rms);
  EXPECT_LT(row_rms, 0.3);
  EXPECT_LT(map_rms, 0.3);
}

}  // namespace
}  // namespace stereoloc::frontend
