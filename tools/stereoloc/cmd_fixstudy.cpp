// `stereoloc fixstudy`: the global-localisation studies of thesis sections 6.3 and 6.4
// (src/study/fix_study.h).
#include <CLI/CLI.hpp>
#include <memory>

#include "src/pipeline/usage_error.h"
#include "src/study/fix_study.h"
#include "tools/stereoloc/cli_common.h"

namespace stereoloc::cli {

void add_fixstudy_command(CLI::App& app) {
  auto a = std::make_shared<FixStudyOptions>();
  CLI::App* sub = app.add_subcommand(
      "fixstudy", "Reproduce the thesis's global-fix studies (sections 6.3, 6.4; Tables 6.4-6.13) with the simulator");
  sub->add_option("--category", a->category, "rect, spin-at, rect-spin, line-fixed, line-turn or all")
      ->capture_default_str()
      ->check(CLI::IsMember({"rect", "spin-at", "rect-spin", "line-fixed", "line-turn", "all"}));
  sub->add_option("--method", a->method,
                  "fix1 (one landmark + compass), fix2 (two landmarks), both, multi (least squares over >= 2 "
                  "landmarks + compass, range-bearing and pixel models) or all")
      ->capture_default_str()
      ->check(CLI::IsMember({"fix1", "fix2", "both", "multi", "all"}));
  sub->add_option("--pixel-sigma", a->pixel_sigma, "Gaussian pixel noise on u_l, v_l, u_r, v_r (px)")
      ->capture_default_str()
      ->check(pixelSigma());
  sub->add_flag("--quantise", a->quantise, "Round the noisy pixel coordinates to whole pixels");
  sub->add_option("--covariance", a->covariance,
                  "Covariance of the fixes: first_order (the thesis's (4.15), (4.18)), second_order (plus the dominant "
                  "curvature terms) or sigma_points (mean squared error of the exact closed form over the noise)")
      ->capture_default_str()
      ->check(CLI::IsMember({"first_order", "second_order", "sigma_points"}));
  sub->add_flag("--first-order", a->first_order, "Same as --covariance first_order (the thesis's propagation)");
  sub->add_option("--seed", a->seed, "Study seed (each trial's seed derives from it)")->capture_default_str();
  sub->add_option("--runs", a->runs, "Noise realisations per trial (the thesis ran one)")
      ->capture_default_str()
      ->check(CLI::Range(1, 100000));
  sub->add_option("--out", a->out, "Directory for fixstudy.txt and fixes.csv (created if missing)");
  sub->add_option("--frontend", a->frontend,
                  "Observations: pixels (the simulator's noisy pixels), images (each pose's stereo pair rendered and "
                  "run through the vision frontend) or both (side by side)")
      ->capture_default_str()
      ->check(CLI::IsMember({"pixels", "images", "both"}));
  sub->add_option("--frontend-landmarks", a->frontend_landmarks,
                  "With images: all or goal_corners (the fixes use only identified goal corners either way)")
      ->capture_default_str()
      ->check(CLI::IsMember({"all", "goal_corners"}));
  sub->add_option("--image-noise", a->image_noise, "With images: sensor noise of the rendered pairs, grey levels")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber);
  auto profile = std::make_shared<std::string>("ideal");
  sub->add_option("--profile", *profile,
                  "Worlds, comma-separated: ideal, realistic or error-profile YAML files (see simulate --profile); "
                  "each runs on the same seeds, side by side. Unless only ideal: with images, Table 6.3 (goal-corner "
                  "range error) and the goal-corner recall per world; raw pairs rectified with the given calibration")
      ->capture_default_str();
  sub->add_option("--calibrate", a->calibrate,
                  "With images in a non-ideal world: a self-calibrated column, the frontend with the rig the batch "
                  "smoother estimates on each trial's image sequence with these parts (stereo, odometry,stereo or none)")
      ->capture_default_str();
  sub->add_option("--steps", a->steps, "Poses per trial (0 = the scenario's 100)")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber);
  sub->add_option("--tables", a->tables, "Thesis tables YAML (default: data/thesis_tables.yaml)")
      ->check(CLI::ExistingFile);
  sub->callback([a, profile, sub] {
    a->profiles = splitCommaList(*profile);
    const bool images = a->frontend != "pixels", pixels = a->frontend != "images";
    refuseUnused(*sub, "--frontend-landmarks", images, "--frontend images or both");
    refuseUnused(*sub, "--image-noise", images, "--frontend images or both");
    bool other_world = false;
    for (const std::string& p : a->profiles) other_world |= p != "ideal";
    refuseUnused(*sub, "--calibrate", images && other_world, "--frontend images or both in a world that is not ideal");
    refuseUnused(*sub, "--pixel-sigma", pixels, "--frontend pixels or both");
    refuseUnused(*sub, "--quantise", pixels, "--frontend pixels or both");
    runFixStudy(*a);
  });
}

}  // namespace stereoloc::cli
