// Calibration on real photographs: OpenCV's sample stereo pairs of a 9x6 checkerboard
// (data/real/checkerboard; the square's size is not published, so lengths are in squares).
// No truth comes with them; what real pairs can show is whether the calibration holds on
// views it did not fit, whether its rectification lines rows up, and whether two calibrations
// from disjoint halves of the pairs agree within their stated standard deviations.
#include <gtest/gtest.h>

#include <opencv2/calib3d.hpp>
#include <algorithm>
#include <cmath>
#include <cstdio>

#include "src/calib/stereo_target_calibration.h"
#include "src/calib/target_pairs.h"

namespace stereoloc {
namespace {

const std::string kFolder = std::string(STEREOLOC_DATA_DIR) + "/real/checkerboard";

CheckerBoard sampleBoard() {
  CheckerBoard b;
  b.columns = 9;
  b.rows = 6;
  b.square_mm = 1.0;  // lengths in squares
  return b;
}

const std::vector<TargetPair>& samplePairs() {
  static const std::vector<TargetPair> pairs = readTargetPairs(kFolder);
  return pairs;
}

const TargetCalibrationResult& allPairs() {
  static const TargetCalibrationResult r = calibrateStereoFromTargets(samplePairs(), sampleBoard());
  return r;
}

TEST(RealCheckerboard, TheFolderAndOpenCvsImageListGiveTheSamePairs) {
  const std::vector<TargetPair> listed = readTargetPairs(kFolder + "/stereo_calib.xml");
  ASSERT_EQ(samplePairs().size(), 13u);
  ASSERT_EQ(listed.size(), samplePairs().size());
  for (size_t i = 0; i < listed.size(); ++i) {
    EXPECT_EQ(cv::norm(listed[i].left, samplePairs()[i].left, cv::NORM_INF), 0.0) << listed[i].name;
    EXPECT_EQ(cv::norm(listed[i].right, samplePairs()[i].right, cv::NORM_INF), 0.0) << listed[i].name;
  }
}

TEST(RealCheckerboard, EveryPairIsUsedAndReprojectsWell) {
  const TargetCalibrationResult& r = allPairs();
  EXPECT_EQ(r.used_pairs, 13);
  EXPECT_EQ(r.corners_per_image, 54);
  std::printf("reprojection RMS %.3f px\n", r.rms_px);
  EXPECT_LT(r.rms_px, 0.5);
  for (const auto& p : r.pairs) EXPECT_LT(p.rms_px, 1.0) << p.name;
}

// Rectified with the calibration, a corner's two images lie on one row (what the frontend's
// stereo matching assumes) and the board triangulates flat with squares of one side.
TEST(RealCheckerboard, RectifiedCornersShareTheirRowsAndTriangulateTheBoard) {
  const StereoCalibration& c = allPairs().calibration;
  double row_sq = 0.0, side_sq = 0.0;
  int rows = 0, sides = 0;
  for (const TargetPairResult& pair : allPairs().pairs) {
    const std::vector<cv::Point2f>&l = pair.left_corners, &r = pair.right_corners;
    ASSERT_FALSE(l.empty() || r.empty()) << pair.name;
    std::vector<cv::Point2f> lr, rr;
    cv::undistortPoints(l, lr, c.K1, c.D1, c.R1, c.P1);
    cv::undistortPoints(r, rr, c.K2, c.D2, c.R2, c.P2);
    std::vector<cv::Point3d> xyz;
    for (size_t k = 0; k < lr.size(); ++k) {
      row_sq += std::pow(lr[k].y - rr[k].y, 2);
      ++rows;
      const double d = lr[k].x - rr[k].x, z = c.rectifiedFocal() * c.rectifiedBaseline() / d;
      xyz.emplace_back((lr[k].x - c.rectifiedPrincipalU()) * z / c.rectifiedFocal(),
                       (lr[k].y - c.rectifiedPrincipalV()) * z / c.rectifiedFocal(), z);
    }
    const CheckerBoard b = sampleBoard();
    for (int j = 0; j < b.rows; ++j)
      for (int i = 0; i + 1 < b.columns; ++i) {
        const size_t k = static_cast<size_t>(j * b.columns + i);
        side_sq += std::pow(cv::norm(xyz[k + 1] - xyz[k]) - b.square_mm, 2);
        ++sides;
      }
  }
  const double row_rms = std::sqrt(row_sq / rows), side_rms = std::sqrt(side_sq / sides);
  EXPECT_NEAR(allPairs().rectified_row_rms_px, row_rms, 1e-6);
  std::printf("rectified row difference RMS %.3f px, triangulated square side RMS error %.4f squares\n", row_rms, side_rms);
  EXPECT_LT(row_rms, 0.5);
  EXPECT_LT(side_rms, 0.05);
}

// The squared differences, over the root-sum-square of the stated standard deviations, of the
// cameras' parameters of two calibrations: one standard normal draw each when the stated
// uncertainty is honest.
std::vector<double> squaredZ(const TargetCalibrationResult& a, const TargetCalibrationSigmas& sa,
                             const TargetCalibrationResult& b, const TargetCalibrationSigmas& sb) {
  std::vector<double> z2;
  auto add = [&](double va, double sda, double vb, double sdb) { z2.push_back(std::pow((va - vb) / std::hypot(sda, sdb), 2)); };
  for (int cam = 0; cam < 2; ++cam) {
    const cv::Mat& Ka = cam ? a.calibration.K2 : a.calibration.K1;
    const cv::Mat& Kb = cam ? b.calibration.K2 : b.calibration.K1;
    add(Ka.at<double>(0, 0), sa.focal_px[cam][0], Kb.at<double>(0, 0), sb.focal_px[cam][0]);
    add(Ka.at<double>(1, 1), sa.focal_px[cam][1], Kb.at<double>(1, 1), sb.focal_px[cam][1]);
    add(Ka.at<double>(0, 2), sa.principal_px[cam][0], Kb.at<double>(0, 2), sb.principal_px[cam][0]);
    add(Ka.at<double>(1, 2), sa.principal_px[cam][1], Kb.at<double>(1, 2), sb.principal_px[cam][1]);
  }
  cv::Mat wa, wb;
  cv::Rodrigues(a.calibration.R, wa);
  cv::Rodrigues(b.calibration.R, wb);
  for (int k = 0; k < 3; ++k) add(wa.at<double>(k), sa.rotation_rad[k], wb.at<double>(k), sb.rotation_rad[k]);
  add(cv::norm(a.calibration.T), sa.baseline_mm, cv::norm(b.calibration.T), sb.baseline_mm);
  return z2;
}

// Calibrations from disjoint halves of the pairs (six splits: pair i in the first half when
// i k mod 13 < 7, k = 1..6) estimate the same head. The fit's covariance alone counts every
// corner as independent, which a real view's corners are not: its mean z^2 here is 4.7 (12.7
// on cx1, 4.8 on the baseline). The stated standard deviations, the larger of it and the
// pairs' spread, are not over-confident (0.71).
TEST(RealCheckerboard, DisjointHalvesAgreeWithinTheirStatedSigmas) {
  const size_t n = samplePairs().size();
  std::vector<double> stated, fit;
  const char* names[12] = {"fx1", "fy1", "cx1", "cy1", "fx2", "fy2", "cx2", "cy2", "wx", "wy", "wz", "baseline"};
  std::vector<double> stated_per(12, 0.0), fit_per(12, 0.0);
  for (size_t k = 1; k <= 6; ++k) {
    std::vector<TargetPair> a, b;
    for (size_t i = 0; i < n; ++i) (i * k % n < 7 ? a : b).push_back(samplePairs()[i]);
    const TargetCalibrationResult ra = calibrateStereoFromTargets(a, sampleBoard());
    const TargetCalibrationResult rb = calibrateStereoFromTargets(b, sampleBoard());
    const std::vector<double> s = squaredZ(ra, ra.sigmas, rb, rb.sigmas), f = squaredZ(ra, ra.fit_sigmas, rb, rb.fit_sigmas);
    stated.insert(stated.end(), s.begin(), s.end());
    fit.insert(fit.end(), f.begin(), f.end());
    for (size_t q = 0; q < s.size(); ++q) {
      stated_per[q] += s[q] / 6.0;
      fit_per[q] += f[q] / 6.0;
    }
  }
  auto mean = [](const std::vector<double>& v) {
    double m = 0.0;
    for (double x : v) m += x / static_cast<double>(v.size());
    return m;
  };
  for (size_t q = 0; q < 12; ++q)
    std::printf("%-8s mean z^2 %.2f stated, %.2f the fit's alone\n", names[q], stated_per[q], fit_per[q]);
  std::printf("mean z^2 over 6 splits x 12 parameters: %.2f stated, %.2f the fit's alone\n", mean(stated), mean(fit));
  EXPECT_LT(mean(stated), 1.5);
  EXPECT_GT(mean(stated), 0.2);
  for (size_t q = 0; q < 12; ++q) EXPECT_LT(stated_per[q], 4.0) << names[q];
}

}  // namespace
}  // namespace stereoloc
