// `stereoloc simulate`: runs a thesis scenario with noisy sensors and writes a stereoloc dataset
// (docs/dataset_format.md), optionally with rendered stereo images.
#include <cstdio>
#include <filesystem>
#include <memory>

#include "src/io/dataset.h"
#include "src/sim/calibration_target.h"
#include "src/sim/error_profile.h"
#include "src/sim/renderer.h"
#include "src/sim/simulator.h"
#include "tools/stereoloc/cli_common.h"

namespace stereoloc::cli {
namespace {

struct SimulateOptions {
  std::string scenario, trial = "0", out, map_path, rig_path, landmarks = "goal_corners", profile = "ideal";
  int steps = 0, obstacles = 0, calibration_views = 0;
  uint64_t seed = 1;
  bool images = false, force = false, no_compass = false, quantise = false, head_scan = false;
  double encoder_k = SimulationConfig().encoder_k;
  double compass_sigma_deg = 3.5, compass_bias_deg = 0.0, pixel_sigma = 0.5;
  RenderOptions render;
};

// Trials are named by the thesis's letters (a, b, ...) or by 0-based index.
int parseTrial(const std::string& s, const std::string& scenario) {
  int trial = -1;
  if (s.size() == 1 && s[0] >= 'a' && s[0] <= 'z') {
    trial = s[0] - 'a';
  } else {
    try {
      size_t pos = 0;
      trial = std::stoi(s, &pos);
      if (pos != s.size()) trial = -1;
    } catch (const std::exception&) {
      trial = -1;
    }
  }
  const int count = scenarioTrialCount(scenario);
  if (trial < 0 || trial >= count)
    throw UsageError("--trial: '" + s + "' is not a trial of '" + scenario + "' (0.." + std::to_string(count - 1) +
                     " or a.." + std::string(1, static_cast<char>('a' + count - 1)) + ")");
  return trial;
}

void runSimulate(const SimulateOptions& o) {
  bool known = false;
  for (const std::string& n : scenarioNames()) known |= n == o.scenario;
  if (!known) {
    std::string list;
    for (const std::string& n : scenarioNames()) list += (list.empty() ? "" : ", ") + n;
    throw UsageError("--scenario: unknown scenario '" + o.scenario + "' (expected one of: " + list + ")");
  }
  const int trial = parseTrial(o.trial, o.scenario);
  {
    std::error_code ec;
    if (!o.force && std::filesystem::is_directory(o.out, ec) && !std::filesystem::is_empty(o.out, ec))
      throw UsageError("--out: '" + o.out + "' exists and is not empty (use --force to replace it)");
  }
  SimulationConfig cfg;
  if (!o.map_path.empty()) cfg.map = FieldMap::load(o.map_path);
  if (!o.rig_path.empty()) cfg.rig = StereoRig::load(o.rig_path).params();
  cfg.encoder_k = o.encoder_k;
  cfg.compass = !o.no_compass;
  cfg.compass_sigma = deg2rad(o.compass_sigma_deg);
  cfg.compass_bias = deg2rad(o.compass_bias_deg);
  cfg.pixel_sigma = o.pixel_sigma;
  cfg.quantise = o.quantise;
  try {
    cfg.landmarks = landmarkSetFromString(o.landmarks);
  } catch (const Error& e) {
    throw UsageError(std::string("--landmarks: ") + e.what());
  }
  cfg.obstacles = o.obstacles;
  cfg.images = o.images;
  cfg.scenario.steps = o.steps;
  cfg.scenario.head_scan = o.head_scan;
  try {
    cfg.profile = ErrorProfile::named(o.profile);
  } catch (const Error& e) {
    throw UsageError(std::string("--profile: ") + e.what());
  }
  try {
    cfg.validate();
  } catch (const Error& e) {
    throw UsageError(e.what());
  }
  SimulationTrace trace;
  const Dataset d = simulate(o.scenario, trial, cfg, o.seed, &trace);
  DatasetExtraWriter extra;
  if (o.images) {
    try {
      o.render.validate();
    } catch (const Error& e) {
      throw UsageError(e.what());
    }
  }
  if (o.images || !cfg.profile.isIdeal() || o.calibration_views > 0)
    extra = [&](const std::string& tmp) {
      if (o.images) writeDatasetImages(d, trace, o.render, o.seed, tmp);
      if (o.calibration_views > 0) {
        // What the robot's own cameras see of a checkerboard before the drive.
        CalibrationViewOptions views;
        views.views = o.calibration_views;
        writeCalibrationViews((std::filesystem::path(tmp) / "calibration").string(),
                              trueCameraCalibration(StereoRig(trace.nominal_rig), trace.errors), CheckerBoard(), views,
                              o.seed ^ 0x5ca1ab1eULL);
      }
      // The truth of every drawn error, for scoring what the estimators recover.
      if (!cfg.profile.isIdeal()) trace.errors.save((std::filesystem::path(tmp) / "errors.yaml").string(), cfg.profile);
    };
  saveDataset(d, o.out, o.force, extra);
  size_t n_obs = 0, seen = 0;
  for (const Step& s : d.steps) {
    n_obs += s.observations.size();
    seen += s.observations.empty() ? 0 : 1;
  }
  std::printf("%s: %s\n", o.out.c_str(), d.description.c_str());
  std::printf("  %zu steps, %zu observations, %zu steps with at least one observation%s\n", d.steps.size(), n_obs,
              seen, o.images ? ", images written" : "");
}

}  // namespace

void add_simulate_command(CLI::App& app) {
  auto o = std::make_shared<SimulateOptions>();
  CLI::App* sub = app.add_subcommand("simulate", "Simulate a thesis scenario and write a stereoloc dataset");
  std::string names;
  for (const std::string& n : scenarioNames()) names += (names.empty() ? "" : ", ") + n;
  sub->add_option("--scenario", o->scenario, "Scenario: " + names)->required();
  sub->add_option("--trial", o->trial, "Trial of the scenario: thesis letter (a, b, ...) or 0-based index")
      ->capture_default_str();
  sub->add_option("--steps", o->steps, "Number of steps (0 = the scenario's default)")->check(CLI::Range(0, 10000000));
  sub->add_option("--seed", o->seed, "Random seed (same seed => byte-identical dataset)")->capture_default_str();
  sub->add_flag("--images", o->images, "Render stereo image pairs with ground truth into images/");
  sub->add_option("--obstacles", o->obstacles, "K moving robots (plus a ball) occluding landmarks")
      ->check(CLI::Range(0, 100));
  sub->add_option("--out", o->out, "Output dataset directory")->required();
  sub->add_flag("--force", o->force, "Replace a non-empty output directory");
  sub->add_option("--map", o->map_path, "Field map YAML (default: the built-in MiroSot field)")->check(CLI::ExistingFile);
  sub->add_option("--rig", o->rig_path, "Stereo rig YAML (default: the built-in rig)")->check(CLI::ExistingFile);
  sub->add_option("--encoder-k", o->encoder_k, "Wheel encoder variance per mm travelled, mm^2/mm")
      ->capture_default_str()->check(CLI::Range(0.0, 100.0));
  sub->add_flag("--no-compass", o->no_compass, "Do not write compass readings");
  sub->add_option("--compass-sigma", o->compass_sigma_deg, "Compass noise sigma, degrees")
      ->capture_default_str()->check(CLI::Range(0.0, 360.0));
  sub->add_option("--compass-bias", o->compass_bias_deg, "Constant compass bias, degrees")->capture_default_str();
  sub->add_option("--pixel-sigma", o->pixel_sigma, "Pixel noise sigma, px")->capture_default_str()->check(pixelSigma());
  sub->add_flag("--quantise", o->quantise, "Round observed pixel coordinates to whole pixels");
  sub->add_option("--landmarks", o->landmarks, "Landmarks the detector reports: goal_corners (thesis) or all")
      ->capture_default_str();
  sub->add_option("--image-noise", o->render.noise_sigma, "Image sensor noise sigma, grey levels (with --images)")
      ->capture_default_str();
  sub->add_option("--image-blur", o->render.blur_sigma, "Image Gaussian blur sigma, px (with --images)")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 10.0));
  sub->add_option("--brightness", o->render.brightness, "Added to every image channel, grey levels (bad illumination)")
      ->capture_default_str();
  sub->add_option("--contrast", o->render.contrast, "Image contrast factor about mid-grey (bad illumination)")
      ->capture_default_str();
  sub->add_option("--profile", o->profile,
                  "Error profile: ideal (exact world), realistic (calibration, lens, blur, vibration and odometry "
                  "errors; src/sim/error_profile.h) or a profile YAML file")
      ->capture_default_str();
  sub->add_option("--calibration-views", o->calibration_views,
                  "Also render N checkerboard pairs (9x6 corners, 15 mm squares) through the true cameras into "
                  "calibration/, for `stereoloc calibrate`")
      ->check(CLI::Range(0, 1000));
  sub->add_flag("--head-scan", o->head_scan, "Sweep the head pan (+-30 deg) instead of looking straight ahead");
  sub->callback([o] { runSimulate(*o); });
}

}  // namespace stereoloc::cli
