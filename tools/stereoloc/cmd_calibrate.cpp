// `stereoloc calibrate`: a stereo head's OpenCV calibration from checkerboard pairs
// (src/calib/stereo_target_calibration.h), and optionally the rig that uses it with the
// calibration's standard deviations as a self-calibration's priors.
#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <opencv2/calib3d.hpp>

#include "solvers/self_calibration.h"
#include "src/calib/rectified_view.h"
#include "src/calib/stereo_target_calibration.h"
#include "src/calib/target_pairs.h"
#include "src/core/angles.h"
#include "src/core/stereo_rig.h"
#include "src/io/image_file.h"
#include "tools/stereoloc/cli_common.h"

namespace stereoloc::cli {
namespace {

struct CalibrateOptions {
  std::string source, board = "9x6", out, rig_out, mounting, overlay;
  double square_mm = 15.0;
  int distortion = 4, min_pairs = 6;
  double outlier_factor = TargetCalibrationOptions().outlier_factor;
  bool same_focal_axes = false;
  double tilt_sigma_deg = rad2deg(SelfCalibrationConfig().tilt_sigma_rad);
  double column_offset_sigma_px = SelfCalibrationConfig().column_offset_sigma_px;
  double drive_disparity_sigma_px = SelfCalibrationConfig().drive_disparity_sigma_px;
};

CheckerBoard parseBoard(const std::string& text, double square_mm) {
  CheckerBoard b;
  const size_t x = text.find('x');
  char* end = nullptr;
  const std::string bad = "--board: expected COLUMNSxROWS inner corners (e.g. 9x6), got '" + text + "'";
  if (x == std::string::npos) throw UsageError(bad);
  const std::string c = text.substr(0, x), r = text.substr(x + 1);
  b.columns = static_cast<int>(std::strtol(c.c_str(), &end, 10));
  if (c.empty() || *end != '\0') throw UsageError(bad);
  b.rows = static_cast<int>(std::strtol(r.c_str(), &end, 10));
  if (r.empty() || *end != '\0') throw UsageError(bad);
  b.square_mm = square_mm;
  try {
    b.validate("--board");
  } catch (const Error& e) {
    throw UsageError(e.what());
  }
  return b;
}

// Every pair rectified side by side with the corners found in it marked, as
// DIR/rectified_<left image's stem>.png, or left_out_<stem>.png for a pair the calibration did
// not use (to see why).
void writeOverlays(const std::string& dir, const StereoCalibration& c, const std::vector<TargetPair>& pairs,
                   const TargetCalibrationResult& r) {
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (ec) throw Error(dir + ": cannot create the overlay folder (" + ec.message() + ")");
  const RectifiedView view(c);
  int used = 0, left_out = 0;
  for (size_t i = 0; i < pairs.size(); ++i) {
    const TargetPairResult& p = r.pairs[i];
    const cv::Mat image = view.draw(pairs[i].left, pairs[i].right, p.left_corners, p.right_corners);
    const std::string name = (p.used ? "rectified_" : "left_out_") + std::filesystem::path(p.name).stem().string() + ".png";
    const std::string path = (std::filesystem::path(dir) / name).string();
    writePngFile(path, image);
    ++(p.used ? used : left_out);
  }
  std::printf("wrote %d rectified pairs (%d of them left out) to %s\n", used + left_out, left_out, dir.c_str());
}

void runCalibrate(const CalibrateOptions& o) {
  const CheckerBoard board = parseBoard(o.board, o.square_mm);
  TargetCalibrationOptions options;
  options.distortion_coefficients = o.distortion;
  options.same_focal_axes = o.same_focal_axes;
  options.min_views = o.min_pairs;
  options.outlier_factor = o.outlier_factor;
  const std::vector<TargetPair> pairs = readTargetPairs(o.source);
  const TargetCalibrationResult r = calibrateStereoFromTargets(pairs, board, options);
  const StereoCalibration& c = r.calibration;
  const TargetCalibrationSigmas& s = r.sigmas;
  std::printf("pairs: %d of %zu used, %d corners per image, reprojection RMS %.3f px\n", r.used_pairs, r.pairs.size(),
              r.corners_per_image, r.rms_px);
  for (const auto& p : r.pairs)
    if (p.used)
      std::printf("  %s  %.3f px\n", p.name.c_str(), p.rms_px);
    else
      std::printf("  %s  not used: %s\n", p.name.c_str(), p.reason.c_str());
  for (int i = 0; i < 2; ++i) {
    const cv::Mat& K = i == 0 ? c.K1 : c.K2;
    const cv::Mat& D = i == 0 ? c.D1 : c.D2;
    std::printf("%s camera: fx %.2f ± %.2f  fy %.2f ± %.2f  cx %.2f ± %.2f  cy %.2f ± %.2f px; distortion", i ? "right" : "left",
                K.at<double>(0, 0), s.focal_px[i][0], K.at<double>(1, 1), s.focal_px[i][1], K.at<double>(0, 2),
                s.principal_px[i][0], K.at<double>(1, 2), s.principal_px[i][1]);
    for (int k = 0; k < D.cols; ++k) std::printf(" %.4f ± %.4f", D.at<double>(0, k), s.distortion[i][static_cast<size_t>(k)]);
    std::printf("\n");
  }
  std::printf("the lens at the image's corners (relative to its centre): ± %.2f px (left), ± %.2f px (right)\n",
              s.image_corner_px[0], s.image_corner_px[1]);
  if (std::max(s.image_corner_px[0], s.image_corner_px[1]) > TargetCalibrationSigmas::kEdgeWarningPx)
    std::fprintf(stderr,
                 "stereoloc: warning: the lens model is uncertain by more than %.1f px at the image's corners: add views "
                 "with the board near the edges and corners\n",
                 TargetCalibrationSigmas::kEdgeWarningPx);
  cv::Mat rvec;
  cv::Rodrigues(c.R, rvec);
  std::printf("right camera against the left: rotation (%.3f, %.3f, %.3f) ± (%.3f, %.3f, %.3f) deg, baseline %.3f ± %.3f mm\n",
              rad2deg(rvec.at<double>(0)), rad2deg(rvec.at<double>(1)), rad2deg(rvec.at<double>(2)),
              rad2deg(s.rotation_rad[0]), rad2deg(s.rotation_rad[1]), rad2deg(s.rotation_rad[2]), cv::norm(c.T),
              s.baseline_mm);
  std::printf("rectified: f %.2f px, principal point (%.2f, %.2f) px, baseline %.2f mm; a corner's two images %.3f px "
              "apart in row (RMS)\n",
              c.rectifiedFocal(), c.rectifiedPrincipalU(), c.rectifiedPrincipalV(), c.rectifiedBaseline(),
              r.rectified_row_rms_px);
  std::printf("for a self-calibration: baseline scale ± %.4f, disparity offset ± %.3f px, focal ratio ± %.4f, focal scale ± %.4f, "
              "column offset ± %.2f px, tilt ± %.3f deg (the calibration's part)\n",
              s.baseline_scale, s.disparity_offset_px, s.focal_ratio, s.focal_scale, s.column_offset_px, rad2deg(s.tilt_rad));
  const TargetCalibrationSigmas &fit = r.fit_sigmas, &spread = r.pair_spread_sigmas;
  std::printf("standard deviations: each the larger of the fit's and the pairs' spread (leave one pair out); the spread is "
              "%.1fx the fit's on the baseline, %.1fx on the left focal length, %.1fx on the disparity offset\n",
              spread.baseline_mm / fit.baseline_mm, spread.focal_px[0][0] / fit.focal_px[0][0],
              spread.disparity_offset_px / fit.disparity_offset_px);
  c.save(o.out);
  std::printf("wrote %s\n", o.out.c_str());
  if (!o.overlay.empty()) writeOverlays(o.overlay, c, pairs, r);
  if (!o.rig_out.empty()) {
    const StereoRigParams mounting = o.mounting.empty() ? StereoRigParams() : StereoRig::loadMounting(o.mounting);
    saveCalibratedRig(o.rig_out, mounting, r, deg2rad(o.tilt_sigma_deg), o.column_offset_sigma_px,
                      o.drive_disparity_sigma_px);
    std::printf("wrote %s\n", o.rig_out.c_str());
  }
}

}  // namespace

void add_calibrate_command(CLI::App& app) {
  auto o = std::make_shared<CalibrateOptions>();
  CLI::App* sub = app.add_subcommand(
      "calibrate", "Calibrate a stereo head from checkerboard pairs: an OpenCV calibration file and, with --rig-out, the rig");
  sub->add_option("pairs", o->source,
                  "Folder of left<key>/right<key> images (left_01.png + right_01.png, left01.jpg + right01.jpg), or an "
                  "OpenCV image list (left and right alternating, as stereo_calib.cpp reads)")
      ->required()
      ->check(CLI::ExistingPath);
  sub->add_option("--board", o->board, "Inner corners per row x per column, unequal (e.g. 9x6)")->capture_default_str();
  sub->add_option("--square-mm", o->square_mm, "Side of a square, mm")->capture_default_str()->check(positiveNumber());
  sub->add_option("--out", o->out, "Write the OpenCV stereo calibration (M1 D1 M2 D2 R T, R1 ... Q) here")->required();
  sub->add_option("--distortion", o->distortion, "Distortion coefficients: 4 (k1 k2 p1 p2), 5 (+ k3), 8 (rational)")
      ->capture_default_str()
      ->check(CLI::IsMember({4, 5, 8}));
  sub->add_flag("--same-focal-axes", o->same_focal_axes, "Square pixels: fx = fy per camera");
  sub->add_option("--min-pairs", o->min_pairs, "Pairs showing the whole board in both images needed")
      ->capture_default_str()
      ->check(CLI::Range(3, 100000));
  sub->add_option("--outlier-factor", o->outlier_factor,
                  "Leave out a pair whose right corners lie further than this many times the pairs' median (and 0.5 px) "
                  "from where its left image and the pairs' median stereo geometry put them, the worst first, while more "
                  "than --min-pairs remain; 0 keeps every pair")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber);
  sub->add_option("--overlay", o->overlay,
                  "Also write every pair rectified side by side, rows marked every 16 px and the board's corners "
                  "circled, to this folder (rectified_<left image>.png; left_out_<left image>.png for the pairs not "
                  "used): a corner's two circles on one row");
  CLI::Option* rig_out = sub->add_option(
      "--rig-out", o->rig_out,
      "Also write the rig YAML using the calibration, with its standard deviations for a later --calibrate stereo");
  sub->add_option("--mounting", o->mounting,
                  "Rig YAML, or a file of its mounting keys alone, whose mounting (camera_height_mm and tilt_rad "
                  "required, offset_x_mm) and noise fields the written rig takes (default: the built-in rig's)")
      ->check(CLI::ExistingFile)
      ->needs(rig_out);
  sub->add_option("--tilt-sigma-deg", o->tilt_sigma_deg, "The mounting's tilt uncertainty, deg (the board does not see it)")
      ->capture_default_str()
      ->check(positiveNumber())
      ->needs(rig_out);
  sub->add_option("--column-offset-sigma-px", o->column_offset_sigma_px,
                  "The head's yaw on the robot as a column uncertainty, px (the board does not see it)")
      ->capture_default_str()
      ->check(positiveNumber())
      ->needs(rig_out);
  sub->add_option("--drive-disparity-sigma-px", o->drive_disparity_sigma_px,
                  "Disparity offset a drive adds that the still board cannot show, px: cameras exposing dt apart on a "
                  "robot turning at w shift it by f w dt (0 for synchronised cameras)")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber)
      ->needs(rig_out);
  sub->callback([o] { runCalibrate(*o); });
}

}  // namespace stereoloc::cli
