// `stereoloc detect`: runs the vision frontend (thesis ch. 3) on one rectified stereo pair (or,
// with --image, on one monocular image) and prints its segments, point features and
// range-bearing observations (table or JSON).
#include <algorithm>
#include <cctype>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <opencv2/core.hpp>

#include "frontend/detection_text.h"
#include "frontend/frontend.h"
#include "frontend/overlay.h"
#include "src/core/field_map.h"
#include "src/core/stereo_rig.h"
#include "src/io/image_file.h"
#include "src/pipeline/frontend_source.h"
#include "tools/stereoloc/cli_common.h"

namespace stereoloc::cli {
namespace {

struct DetectOptions {
  std::string left, right, image, rig_path, map_path, params_path, overlay;
  double pan = 0.0;
  bool json = false;
};

void writeOverlay(const cv::Mat& img, const frontend::FrontendResult& r, const std::string& path) {
  const std::filesystem::path p(path);
  std::string ext = p.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  if (ext != ".png") throw Error(path + ": the overlay is written as a PNG image (give a .png path)");
  writePngFile(path, frontend::drawDetections(img, r, 2));
}

void runDetect(const DetectOptions& o) {
  const StereoRig rig = o.rig_path.empty() ? StereoRig() : StereoRig::load(o.rig_path);
  const FieldMap map = o.map_path.empty() ? FieldMap::miroSot() : FieldMap::load(o.map_path);
  const frontend::FrontendParams params =
      o.params_path.empty() ? frontend::FrontendParams() : frontend::FrontendParams::load(o.params_path);
  frontend::Frontend fe(rig, map, params);
  const bool mono = !o.image.empty();
  // Of the rig's size: the built-in rig unless --rig gives the camera's.
  const cv::Mat left = mono ? readStereoImage(o.image, rig, "input image") : readStereoImage(o.left, rig, "left image");
  const cv::Mat right = mono ? cv::Mat() : readStereoImage(o.right, rig, "right image");
  const frontend::FrontendResult& r = mono ? fe.detectFeaturesRaw(left) : fe.process(left, right, o.pan);
  // The features are in rectified pixels: draw them on the rectified image.
  if (!o.overlay.empty()) writeOverlay(fe.rectifier() ? fe.rectifier()->rectifiedCopy(0, left) : left, r, o.overlay);
  const std::string text = o.json ? frontend::detectionsJson(r) : frontend::detectionsTable(r);
  std::fputs(text.c_str(), stdout);
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
                  "Write the (left) image as a PNG at 2x with the detections drawn: markings red, other edges green, L / T / X / goal "
                  "corners as distinct markers, with a legend (like Fig. 6.1)");
  sub->add_flag("--json", opts->json, "Print one JSON object instead of tables");
  sub->callback([opts, image, left] {
    if (image->count() == 0 && left->count() == 0) throw CLI::ValidationError("detect", "give --left and --right, or --image");
    runDetect(*opts);
  });
}

}  // namespace stereoloc::cli
