#include "tools/stereoloc/localize_common.h"

#include <CLI/CLI.hpp>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <memory>
#include <string>

#include "src/core/atomic_file.h"
#include "src/core/field_map.h"
#include "src/io/csv.h"
#include "src/io/dataset.h"
#include "src/io/estimate_io.h"
#include "src/eval/evaluation.h"
#include "tools/stereoloc/cli_common.h"
#include "src/pipeline/methods.h"

namespace stereoloc::cli {

SelfCalibrationConfig calibrationOptions(const std::string& calibrate, const std::string& consider) {
  if (!calibrate.empty() && !consider.empty())
    throw UsageError("--consider: not with --calibrate (a block is estimated or considered)");
  const bool considering = !consider.empty();
  try {
    SelfCalibrationConfig c = SelfCalibrationConfig::parse(considering ? consider : calibrate);
    c.consider = considering;
    return c;
  } catch (const Error& e) {
    throw UsageError(std::string(considering ? "--consider: " : "--calibrate: ") + e.what());
  }
}

MethodOptions parseMethodOptions(const LocalizeArgs& a) {
  MethodOptions o = a.options;
  try {
    o.init = initModeFromString(a.init);
    o.loss = robustLossFromString(a.loss);
    o.observation_model = observationModelFromString(a.observation_model);
  } catch (const Error& e) {
    throw UsageError(e.what());
  }
  o.calibration = calibrationOptions(a.calibrate, a.consider);
  if (!a.calibration_out.empty() && (o.calibration.consider || !o.calibration.any()))
    throw UsageError("--calibration-out: needs --calibrate");
  if (!a.field_out.empty() && !o.calibration.field) throw UsageError("--field-out: needs --calibrate with field");
  o.calibration.drive_disparity_sigma_px = a.drive_disparity_sigma_px;
  if (!a.noise_model.empty()) o.noise = UnmodelledNoise::load(a.noise_model);
  o.odometry_delay = parseOdometryDelay(a.odometry_delay, &o.given_odometry_delay_s);
  if (!a.odometry_delay_profile.empty() && o.odometry_delay != OdometryDelayMode::Fit)
    throw UsageError("--odometry-delay-profile: needs --odometry-delay fit");
  if (!a.odometry_delay_search.empty()) {
    if (o.odometry_delay != OdometryDelayMode::Fit) throw UsageError("--odometry-delay-search: needs --odometry-delay fit");
    const std::vector<double> v = parseNumbers(a.odometry_delay_search, 3, "--odometry-delay-search", "MIN,MAX,STEP");
    o.odometry_delay_search.min_s = v[0];
    o.odometry_delay_search.max_s = v[1];
    o.odometry_delay_search.step_s = v[2];
    try {
      o.odometry_delay_search.validate();
    } catch (const Error& e) {
      throw UsageError(std::string("--odometry-delay-search: ") + e.what());
    }
  }
  return o;
}

OdometryDelayMode parseOdometryDelay(const std::optional<std::string>& text, double* given_s) {
  if (!text) return OdometryDelayMode::None;
  if (*text == "fit") return OdometryDelayMode::Fit;
  *given_s = parseDelaySeconds(*text, "--odometry-delay");
  return OdometryDelayMode::Given;
}

void recordOdometryDelay(CalibrationEstimate& c, const MethodOptions& o, const std::optional<OdometryDelayEstimate>& fitted,
                         const CalibrationHandover& handover) {
  if (fitted) {
    c.odometry_delay_s = fitted->delay_s;
    c.odometry_delay_sigma_s = fitted->sigma_s;
  } else if (o.odometry_delay == OdometryDelayMode::Given &&
             !(handover.odometry_delay_s && *handover.odometry_delay_s == o.given_odometry_delay_s)) {
    c.odometry_delay_s = o.given_odometry_delay_s;
    c.odometry_delay_sigma_s = 0.0;
  }
}

void writeOdometryDelayProfile(const std::string& path, const std::optional<OdometryDelayEstimate>& fitted) {
  if (path.empty() || !fitted) return;
  std::string csv = "delay_s,cost\n";
  for (const auto& [delay, cost] : fitted->profile) csv += formatDouble(delay) + "," + formatDouble(cost) + "\n";
  writeFileAtomically(path, csv);
}

void printOdometryDelay(const MethodOptions& o, const std::optional<OdometryDelayEstimate>& fitted,
                        const CalibrationHandover& handover) {
  if (o.odometry_delay == OdometryDelayMode::Given)
    std::printf("odometry delay (%s): %.3f s\n",
                handover.odometry_delay_s && *handover.odometry_delay_s == o.given_odometry_delay_s
                    ? "handed over by the rig file"
                    : "given",
                o.given_odometry_delay_s);
  if (fitted) {
    const OdometryDelaySearch& s = o.odometry_delay_search;
    std::printf("odometry delay (fitted by the batch): %.3f +- %.3f s (profile %.3f s, the steps' resolution %.3f s; "
                "%zu delays tried, %.2f to %.2f s)\n",
                fitted->delay_s, fitted->sigma_s, fitted->profile_sigma_s, fitted->resolution_s, fitted->profile.size(),
                s.min_s, s.max_s);
  }
}

void noteConstantWheelsInTheBatch(const MethodOptions& o) {
  if (o.calibration.odometry && o.noise.wheelsDrift())
    std::printf("calibration: the batch estimates one wheel calibration for the whole run; the noise model's wheel "
                "drift is for the window and the EKF\n");
}

void reportCalibration(const std::string& calibration_out, std::FILE* out, const CalibrationEstimate* calibration,
                       const StereoRig& rig, const SelfCalibrationConfig& config, double nominal_wheel_base_mm,
                       const CalibrationHandover& handover) {
  if (!calibration) return;
  const CalibrationEstimate c = handover.carriedOn(*calibration);
  if (!calibration_out.empty()) c.saveAsRig(calibration_out, rig, config.drive_disparity_sigma_px);
  auto sd = [](double variance) { return std::sqrt(std::max(variance, 0.0)); };
  if (c.odometry)
    std::fprintf(out, "calibration: wheel scales %.5f +- %.5f, %.5f +- %.5f, wheel base %.2f +- %.2f mm\n", c.wheels[0],
                 sd(c.wheels_covariance(0, 0)), c.wheels[1], sd(c.wheels_covariance(1, 1)), c.wheels[2],
                 sd(c.wheels_covariance(2, 2)));
  if (c.stereo)
    std::fprintf(
        out,
        "calibration: tilt correction %.3f +- %.3f deg, baseline scale %.5f +- %.5f, disparity offset %.2f +- %.2f px, "
        "column offset %.2f +- %.2f px, focal ratio %.5f +- %.5f, focal scale %.5f +- %.5f\n",
        rad2deg(c.head[0]), rad2deg(sd(c.head_covariance(0, 0))), c.head[1], sd(c.head_covariance(1, 1)), c.head[2],
        sd(c.head_covariance(2, 2)), c.head[3], sd(c.head_covariance(3, 3)), c.head[4], sd(c.head_covariance(4, 4)),
        c.head[5], sd(c.head_covariance(5, 5)));
  if (c.range)
    std::fprintf(out,
                 "calibration: range factor 1 %+.4f (+- %.4f) %+.4f (+- %.4f) b %+.4f (+- %.4f) b^2, bearing offset "
                 "%.3f +- %.3f deg\n",
                 c.range_bearing[0], sd(c.range_bearing_covariance(0, 0)), c.range_bearing[1],
                 sd(c.range_bearing_covariance(1, 1)), c.range_bearing[2], sd(c.range_bearing_covariance(2, 2)),
                 rad2deg(c.range_bearing[3]), rad2deg(sd(c.range_bearing_covariance(3, 3))));
  if (c.field) {
    std::string line = "calibration: field dimensions' change";
    for (int k = 0; k < kFieldDimensionCount; ++k) {
      char part[96];
      const double tenths = std::round(10.0 * c.field_dimensions_mm[k]) / 10.0 + 0.0;  // no "-0.0"
      std::snprintf(part, sizeof part, "%s %s %+.1f +- %.1f mm", k ? "," : "", kFieldDimensions[k].name, tenths,
                    sd(c.field_covariance(k, k)));
      line += part;
    }
    std::fprintf(out, "%s\n", line.c_str());
  }
  const PriorDistance far = furthestFromPrior(*calibration, config, nominal_wheel_base_mm);
  std::fprintf(out, "calibration: furthest from the nominal calibration: %s, %.1f prior sigmas\n", far.parameter.c_str(),
               far.sigmas);
  if (far.sigmas > kImplausiblePriorSigmas)
    std::fprintf(out,
                 "calibration: warning: beyond %.0f prior sigmas, a failed solve (data association, a false kidnap cut) "
                 "or a wrong prior\n",
                 kImplausiblePriorSigmas);
}

void writeMeasuredField(const std::string& path, const FieldMap& map, const CalibrationEstimate* calibration) {
  if (path.empty()) return;
  if (!calibration || !calibration->field) throw UsageError("--field-out: needs --calibrate with field");
  // The field as measured, with how well its dimensions are known: the next drive's map
  // (`--map`, `stream --map`) and, when it calibrates the field again, its prior.
  map.withDimensionChange(calibration->field_dimensions_mm)
      .withDimensionCovariance(calibration->field_covariance)
      .save(path);
  std::printf("field: the map with the estimated dimensions written to %s\n", path.c_str());
}

Dataset loadRunDataset(const LocalizeArgs& a, MethodOptions& o, CalibrationHandover& handover) {
  const FrontendMode mode = frontendModeFromString(a.frontend);
  Dataset d = loadDataset(a.dataset);
  if (!a.map.empty()) useMap(d, a.map, mode == FrontendMode::Images);
  if (!a.rig.empty()) {
    handover = useRig(d, a.rig, mode == FrontendMode::Images);
    handover.applyPriors(o.calibration, o.noise);
    // The delay the file hands over, unless --odometry-delay says otherwise.
    if (handover.odometry_delay_s && o.odometry_delay == OdometryDelayMode::None) {
      o.odometry_delay = OdometryDelayMode::Given;
      o.given_odometry_delay_s = *handover.odometry_delay_s;
    }
  }
  if (mode == FrontendMode::Images) {
    const ImageFrontendStats stats =
        observeDatasetImages(d, a.dataset, imageFrontendOptions(a.frontend_landmarks, a.frontend_params));
    std::printf("%s\n", frontendSummary(stats).c_str());
  }
  synchroniseExposures(d);
  return d;
}

void checkMethodOptions(const LocalizeArgs& a, const CLI::App& sub) {
  const std::string name = parseMethodSpec(a.method, InitMode::Known).first;
  const std::string m = " (method '" + a.method + "')";
  auto refuse = [&](const char* option, bool used, const std::string& who) { refuseUnused(sub, option, used, who, m); };
  const bool smoother = name == "batch" || name == "window", fix = name == "fix1" || name == "fix2";
  refuse("--particles", name == "pf", "the particle filter");
  refuse("--window", name == "window", "the window");
  refuse("--loss", smoother, "the batch and the window");
  refuse("--loss-scale", smoother && a.loss != "none", "the batch and the window with --loss huber or cauchy");
  refuse("--observation-model", smoother || name == "ekf" || name == "iekf", "the smoothers and the EKFs");
  refuse("--frontend-landmarks", a.frontend == "images", "--frontend images");
  refuse("--frontend-params", a.frontend == "images", "--frontend images");
  refuse("--init", !fix, "the trackers");
  refuse("--seed", !fix, "the trackers");
}

void runLocalize(const LocalizeArgs& a) {
  MethodOptions o = parseMethodOptions(a);
  const std::string name = parseMethodSpec(a.method, o.init).first;  // usage errors before reading data
  const bool calibrating_filter = (name == "ekf" || name == "pf") && (o.calibration.any() ||
                                                                      hasCalibrationSuffix(a.method) ||
                                                                      hasConsiderSuffix(a.method));
  if (name != "batch" && name != "window" && !calibrating_filter && (!a.noise_model.empty() || o.pixel_sigma > 0))
    throw UsageError("--noise-model, --pixel-sigma: only the smoothers (batch, window), and ekf and pf with "
                     "--calibrate or --consider use them (method '" + a.method + "')");
  CalibrationHandover handover;
  const Dataset d = loadRunDataset(a, o, handover);
  const MethodRun run = runMethod(a.method, d, a.seed, o);
  printOdometryDelay(o, run.odometry_delay, handover);
  writeOdometryDelayProfile(a.odometry_delay_profile, run.odometry_delay);
  writeEstimatesCsv(a.out, run.estimates);
  if (!a.tum.empty()) writeEstimatesTum(a.tum, run.estimates);
  if (!a.calibration_out.empty() && !run.calibration)
    throw UsageError("--calibration-out: needs --calibrate with batch, window, ekf or pf");
  std::optional<CalibrationEstimate> calibration = run.calibration;
  if (calibration) recordOdometryDelay(*calibration, o, run.odometry_delay, handover);
  if (name == "batch") noteConstantWheelsInTheBatch(o);
  reportCalibration(a.calibration_out, stdout, calibration ? &*calibration : nullptr, d.rig, o.calibration,
                    d.odometry.wheel_base_mm, handover);
  writeMeasuredField(a.field_out, d.map, calibration ? &*calibration : nullptr);
  std::printf("%s: %zu estimates for %zu steps written to %s (%.3f ms/step)\n", a.method.c_str(), run.estimates.size(),
              d.steps.size(), a.out.c_str(), run.ms_per_step);
  printAgainstTruth(trajectoryMetrics(poseErrors(run.estimates, truthByStep(d.steps, d.groundtruth))));
}

void printAgainstTruth(const TrajectoryMetrics& m) {
  if (m.count == 0) return;
  std::printf("against ground truth (%zu poses): position RMSE %.1f mm, theta RMSE %.2f deg, mean NEES %.2f", m.count,
              m.position_rmse, rad2deg(m.theta_rmse), m.mean_nees);
  if (m.nees_count > 0)
    std::printf(" (position %.2f of 2, heading %.2f of 1)", m.mean_position_nees, m.mean_heading_nees);
  std::printf("\n");
}

void addFrontendOptions(CLI::App* sub, std::string& frontend, std::string& landmarks, std::string& params_path) {
  sub->add_option("--frontend", frontend,
                  "Observations: pixels (the dataset's observations.csv) or images (the vision frontend on the "
                  "dataset's images/, written by `simulate --images`)")
      ->capture_default_str()
      ->check(CLI::IsMember({"pixels", "images"}));
  sub->add_option("--frontend-landmarks", landmarks,
                  "With --frontend images: all (goal corners + unidentified corners/junctions, associated by the "
                  "estimator at its current belief) or goal_corners (the thesis's landmarks only)")
      ->capture_default_str()
      ->check(CLI::IsMember({"all", "goal_corners"}));
  sub->add_option("--frontend-params", params_path, "With --frontend images: frontend parameters YAML (default: built-in)")
      ->check(CLI::ExistingFile);
}

void addLocalizeOptions(CLI::App* sub, const std::shared_ptr<LocalizeArgs>& a, bool method_option) {
  sub->add_option("dataset", a->dataset, "Dataset directory (docs/dataset_format.md)")->required()->check(CLI::ExistingDirectory);
  if (method_option)
    sub->add_option("--method", a->method, methodNamesText() + " (optionally :known, :random, :global)")
        ->capture_default_str();
  sub->add_option("--init", a->init, "Start of the trackers: known (truth + noise), random, or global (first global fix)")
      ->capture_default_str();
  if (method_option) {
    sub->add_option("--particles", a->options.particles, "Particles of the particle filter (at least 100)")
        ->capture_default_str()
        ->check(particleCount());
    sub->add_option("--window", a->options.window, "Window size W of the sliding-window smoother")->capture_default_str()->check(positiveNumber());
  }
  sub->add_option("--loss", a->loss, "Robust loss of the batch and window smoothers' observation factors: none, huber or cauchy (the window then runs without the gate)")->capture_default_str();
  sub->add_option("--observation-model", a->observation_model,
                  "How the batch and window smoothers use stereo observations: range_bearing (the thesis's form), "
                  "pixel_columns (pixel factors on u_l, u_r: the same data, no conversion bias) or pixels (also the "
                  "rows: range from the known camera and landmark heights); observations without pixels stay range-bearing")
      ->capture_default_str();
  sub->add_option("--loss-scale", a->options.loss_scale, "Robust loss scale in whitened units")->capture_default_str()->check(positiveNumber());
  sub->add_option("--seed", a->seed, "Seed of the start noise and the particle filter")->capture_default_str();
  sub->add_option("--out", a->out, "Estimates CSV: step,t,x,y,theta,cov_xx,cov_xy,cov_xtheta,cov_yy,cov_ytheta,cov_thetatheta")->required();
  sub->add_option("--tum", a->tum, "Also write the trajectory in TUM format (metres), e.g. for evo");
  addFrontendOptions(sub, a->frontend, a->frontend_landmarks, a->frontend_params);
  sub->add_option("--calibrate", a->calibrate,
                  "Batch, window, ekf and pf: self-calibrate odometry (wheel scales, wheel base), stereo (head tilt, "
                  "baseline scale, disparity and column offsets, focal errors; the smoothers need a pixel observation "
                  "model, pf each particle its own calibration) or both, with priors from the stated uncertainty; "
                  "batch, window and ekf also range (a range-bearing sensor's range factor 1 + c0 + c1 b + c2 b^2 at "
                  "bearing b and its bearing offset) and, with stereo, field (the change of the MiroSot field's nine "
                  "dimensions: a field built by hand), comma-separated");
  if (method_option)
    sub->add_option("--consider", a->consider,
                    "ekf: the blocks of --calibrate (odometry, stereo, range, field, comma-separated) considered, not estimated: "
                    "the calibration stays as given (or as --rig hands it over), its stated uncertainty enters the "
                    "covariance (a Schmidt-Kalman filter; the method ekf:consider in studies); fix1 and fix2: stereo "
                    "only, each fix's covariance gains the calibration's (fix2:consider in studies)");
  sub->add_option("--pixel-sigma", a->options.pixel_sigma,
                  "Batch and window pixel models, ekf with --calibrate or --consider stereo, pf with --calibrate stereo "
                  "(the other methods refuse it): pixel noise [px] replacing the observations' own (0: theirs); about 1 px for the "
                  "realistic error profile (docs/realistic_world.md)")
      ->capture_default_str()
      ->check(pixelSigma());
  sub->add_option("--noise-model", a->noise_model,
                  "Batch, window, and ekf and pf with --calibrate or --consider (the other methods refuse it): YAML of the "
                  "noise the rig and odometry do not state (lens distortion estimate error, camera vibration, wheel "
                  "slip, wheels that drift over a long run; data/noise_realistic.yaml, docs/realistic_world.md)");
  sub->add_option("--rig", a->rig,
                  "Stereo rig YAML in place of the dataset's, e.g. one --calibration-out wrote: its wheel estimate "
                  "scales the wheel increments and sets the wheel base, its standard deviations are the priors of "
                  "--calibrate and --consider (docs/realistic_world.md); a rig with other rectified cameras than the "
                  "dataset's needs --frontend images")
      ->check(CLI::ExistingFile);
  sub->add_option("--map", a->map,
                  "Field map YAML in place of the dataset's, e.g. the field an earlier drive measured (--field-out); "
                  "every landmark the dataset's stored observations name must be in it with its type (with --frontend "
                  "images the frontend identifies the landmarks on it)")
      ->check(CLI::ExistingFile);
  sub->add_option("--odometry-delay", a->odometry_delay,
                  "The odometry runs this late against the camera (a drive's latency, a clock offset), seconds within "
                  "+-2; 'fit': the delay at which the batch smoother (with --calibrate's blocks) fits the data best, "
                  "printed with its standard deviation, before the method runs on the re-timed odometry");
  sub->add_option("--odometry-delay-search", a->odometry_delay_search,
                  "With --odometry-delay fit: MIN,MAX,STEP of the delays tried, seconds (default -0.5,1,0.1)");
  sub->add_option("--odometry-delay-profile", a->odometry_delay_profile,
                  "With --odometry-delay fit: write the batch's cost at every delay tried as CSV delay_s,cost");
  CLI::Option* calibration_out = sub->add_option(
      "--calibration-out", a->calibration_out,
      "With --calibrate: write the rig YAML with the estimated calibration and its standard deviations (usable as --rig)");
  sub->add_option("--field-out", a->field_out,
                  "With --calibrate ...,field (batch, window, ekf): write the field map with the estimated dimensions and "
                  "their covariance, the map of the next drive on this field (--map), whose field calibration takes "
                  "it as its prior");
  sub->add_option("--drive-disparity-sigma-px", a->drive_disparity_sigma_px,
                  "With --calibration-out: the disparity offset's part that another drive does not share, px, added to "
                  "its handed-over standard deviation: cameras exposing dt apart on a robot turning at w shift it by "
                  "f w dt (0 for cameras exposing together; not added when the noise model's exposure_offset_sigma_s "
                  "had the exposure offset estimated)")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber)
      ->needs(calibration_out);
}

}  // namespace stereoloc::cli
