// `stereoloc detect`: runs the vision frontend (thesis ch. 3) on one rectified stereo pair (or,
// with --image, on one monocular image) and prints its segments, point features and
// range-bearing observations (table or JSON).
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <sstream>

#include "frontend/frontend.h"
#include "frontend/overlay.h"
#include "src/core/atomic_file.h"
#include "src/core/field_map.h"
#include "src/core/stereo_rig.h"
#include "tools/stereoloc/cli_common.h"

namespace stereoloc::cli {
namespace {

struct DetectOptions {
  std::string left, right, image, rig_path, map_path, params_path, overlay;
  double pan = 0.0;
  bool json = false;
};

// Reads an image as stored (no silent conversion), so 16-bit or grey files are reported.
cv::Mat readImage(const std::string& path, const char* which) {
  // Checked first: OpenCV would print its own warning for a missing file.
  if (!std::filesystem::is_regular_file(path)) throw Error(path + ": cannot read the " + std::string(which) + " image (no such file)");
  const cv::Mat img = cv::imread(path, cv::IMREAD_UNCHANGED);
  if (img.empty()) throw Error(path + ": cannot read the " + std::string(which) + " image (missing or not an image)");
  if (img.depth() != CV_8U)
    throw Error(path + ": " + which + " image has " + (img.depth() == CV_16U ? "16" : "non-8") +
                "-bit channels; 8-bit BGR is required");
  if (img.channels() == 4) {
    cv::Mat bgr;
    cv::cvtColor(img, bgr, cv::COLOR_BGRA2BGR);
    return bgr;
  }
  if (img.channels() != 3)
    throw Error(path + ": " + which + " image has " + std::to_string(img.channels()) +
                " channel(s); a colour (BGR) image is required for the goal colours");
  return img;
}

std::string num(double v, int prec = 3) {
  char buf[64];
  std::snprintf(buf, sizeof(buf), "%.*f", prec, v);
  return buf;
}

void writeOverlay(const cv::Mat& img, const frontend::FrontendResult& r, const std::string& path) {
  const cv::Mat big = frontend::drawDetections(img, r, 2);
  std::vector<uchar> buf;
  const std::string ext = path.find('.') != std::string::npos ? path.substr(path.find_last_of('.')) : "";
  if (ext.empty() || !cv::imencode(ext, big, buf)) throw Error(path + ": cannot encode the overlay (unknown image extension?)");
  writeFileAtomically(path, std::string(buf.begin(), buf.end()));
}

void runDetect(const DetectOptions& o) {
  const StereoRig rig = o.rig_path.empty() ? StereoRig() : StereoRig::load(o.rig_path);
  const FieldMap map = o.map_path.empty() ? FieldMap::miroSot() : FieldMap::load(o.map_path);
  const frontend::FrontendParams params =
      o.params_path.empty() ? frontend::FrontendParams() : frontend::FrontendParams::load(o.params_path);
  frontend::Frontend fe(rig, map, params);
  const bool mono = !o.image.empty();
  const cv::Mat left = readImage(mono ? o.image : o.left, mono ? "input" : "left");
  cv::Mat right;
  if (!mono) {
    right = readImage(o.right, "right");
    if (left.size() != right.size())
      throw Error(o.right + ": size " + std::to_string(right.cols) + "x" + std::to_string(right.rows) +
                  " differs from the left image's " + std::to_string(left.cols) + "x" + std::to_string(left.rows));
  }
  if (left.cols != rig.params().image_width || left.rows != rig.params().image_height)
    throw Error((mono ? o.image : o.left) + ": size " + std::to_string(left.cols) + "x" + std::to_string(left.rows) +
                " does not match the rig's " + std::to_string(rig.params().image_width) + "x" +
                std::to_string(rig.params().image_height) + " (pass --rig with the camera's calibration)");
  const frontend::FrontendResult& r = mono ? fe.detectFeaturesRaw(left) : fe.process(left, right, o.pan);
  // The features are in rectified pixels: draw them on the rectified image.
  if (!o.overlay.empty()) writeOverlay(fe.rectifier() ? fe.rectifier()->rectifiedCopy(0, left) : left, r, o.overlay);

  std::ostringstream out;
  if (o.json) {
    out << "{\"segments\": [";
    for (size_t i = 0; i < r.lines.size(); ++i) {
      const frontend::LineFeature& l = r.lines[i];
      out << (i ? ", " : "") << "{\"x1\": " << num(l.x(l.t_min)) << ", \"y1\": " << num(l.y(l.t_min))
          << ", \"x2\": " << num(l.x(l.t_max)) << ", \"y2\": " << num(l.y(l.t_max))
          << ", \"marking\": " << (l.marking ? "true" : "false") << "}";
    }
    out << "], \"features\": [";
    for (size_t i = 0; i < r.features.size(); ++i) {
      const frontend::PointFeature& f = r.features[i];
      out << (i ? ", " : "") << "{\"type\": \"" << toString(f.type) << "\", \"u\": " << num(f.u) << ", \"v\": " << num(f.v)
          << ", \"landmark_id\": " << f.landmark_id;
      if (f.type == LandmarkType::GoalCorner) out << ", \"color\": \"" << toString(f.color) << "\"";
      out << "}";
    }
    out << "], \"observations\": [";
    for (size_t i = 0; i < r.observations.size(); ++i) {
      const Observation& ob = r.observations[i];
      out << (i ? ", " : "") << "{\"type\": \"" << toString(ob.type) << "\", \"landmark_id\": " << ob.landmark_id
          << ", \"range\": " << num(ob.range) << ", \"bearing\": " << num(ob.bearing, 6)
          << ", \"u_left\": " << num(ob.pixels->u_left) << ", \"u_right\": " << num(ob.pixels->u_right)
          << ", \"v\": " << num(ob.pixels->v_left) << ", \"covariance\": [" << num(ob.covariance(0, 0), 6) << ", "
          << num(ob.covariance(0, 1), 9) << ", " << num(ob.covariance(1, 1), 9) << "]}";
    }
    out << "]}\n";
  } else {
    out << "segments (left image, px): " << r.lines.size() << "\n";
    out << "     x1      y1      x2      y2  class\n";
    for (const frontend::LineFeature& l : r.lines) {
      char buf[128];
      std::snprintf(buf, sizeof(buf), "%7.2f %7.2f %7.2f %7.2f  %s\n", l.x(l.t_min), l.y(l.t_min), l.x(l.t_max),
                    l.y(l.t_max), l.marking ? "marking" : "other");
      out << buf;
    }
    out << "features (left image, px): " << r.features.size() << "\n";
    for (const frontend::PointFeature& f : r.features) {
      char buf[160];
      std::snprintf(buf, sizeof(buf), "  %-12s u %7.2f v %7.2f%s\n", toString(f.type).c_str(), f.u, f.v,
                    f.type == LandmarkType::GoalCorner ? ("  " + toString(f.color) + " landmark " + std::to_string(f.landmark_id)).c_str() : "");
      out << buf;
    }
    out << "observations: " << r.observations.size() << "\n";
    out << "  type         landmark  range_mm  bearing_deg  u_left  u_right       v  sigma_r_mm\n";
    for (const Observation& ob : r.observations) {
      char buf[200];
      std::snprintf(buf, sizeof(buf), "  %-12s %8d  %8.1f  %11.2f  %6.2f  %7.2f  %6.2f  %10.1f\n", toString(ob.type).c_str(),
                    ob.landmark_id, ob.range, ob.bearing * 180.0 / 3.141592653589793, ob.pixels->u_left, ob.pixels->u_right,
                    ob.pixels->v_left, std::sqrt(ob.covariance(0, 0)));
      out << buf;
    }
  }
  std::fputs(out.str().c_str(), stdout);
}

}  // namespace

void add_detect_command(CLI::App& app) {
  auto opts = std::make_shared<DetectOptions>();
  CLI::App* sub = app.add_subcommand(
      "detect", "Run the vision frontend on one rectified stereo pair, or on one image (thesis ch. 3)");
  CLI::Option* left = sub->add_option("--left", opts->left, "Left image (8-bit BGR, the rig's size)");
  CLI::Option* right = sub->add_option("--right", opts->right, "Right image (8-bit BGR, the rig's size)");
  CLI::Option* image = sub->add_option("--image", opts->image,
                                       "One image (monocular): segments, lines and corners only, no stereo observations");
  left->needs(right);
  right->needs(left);
  image->excludes(left)->excludes(right);
  sub->add_option("--rig", opts->rig_path, "Stereo rig YAML (default: the built-in rig)")->check(CLI::ExistingFile);
  sub->add_option("--map", opts->map_path, "Field map YAML (default: the built-in MiroSot field)")->check(CLI::ExistingFile);
  sub->add_option("--params", opts->params_path, "Frontend parameters YAML (default: data/frontend_default.yaml values)")
      ->check(CLI::ExistingFile);
  sub->add_option("--pan", opts->pan, "Head pan gamma, rad")->capture_default_str();
  sub->add_option("--overlay", opts->overlay,
                  "Write the (left) image at 2x with the detections drawn: markings red, other edges green, L / T / X / goal "
                  "corners as distinct markers, with a legend (like Fig. 6.1)");
  sub->add_flag("--json", opts->json, "Print one JSON object instead of tables");
  sub->callback([opts, image, left] {
    if (image->count() == 0 && left->count() == 0) throw CLI::ValidationError("detect", "give --left and --right, or --image");
    runDetect(*opts);
  });
}

}  // namespace stereoloc::cli
