// `stereoloc stream`: the real-time pipeline (src/pipeline/localizer.h) on JSON Lines, one step
// per line on stdin (or a replayed dataset, --from DIR), one estimate per line on stdout as soon
// as it is computed; the line formats are in src/pipeline/stream_io.h. The tracker is the
// sliding window (default), the EKF (iterated: iekf; self-calibrating with --calibrate, its
// calibration considered with --consider) or the particle filter; each option of one tracker is
// refused with another. A bad line (not JSON, a step going backwards, a missing or unusable
// image, observations older than the window or a filter's replay) gets one error on stderr
// naming the line; the line's odometry is still used when it is valid, and the stream goes on.
// The exit code at the end is 1 if any line was bad.
#include <iostream>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "src/core/types.h"
#include "src/io/dataset.h"
#include "src/pipeline/localizer.h"
#include "src/pipeline/methods.h"
#include "src/pipeline/rig_handover.h"
#include "src/pipeline/stream_io.h"
#include "tools/stereoloc/cli_common.h"
#include "tools/stereoloc/localize_common.h"

namespace stereoloc::cli {
namespace {

struct StreamArgs {
  std::string method = "window";
  int window = 20, max_iterations = 5, particles = ParticleFilterConfig().particles;
  int replay_steps = LocalizerConfig().replay_steps;
  uint64_t seed = 1;
  std::string from, setup, map_path, rig_path, init = "auto";
  std::vector<double> pose, pose_sigma = {30.0, 30.0, 0.0872664626};
  double compass_sigma = 0, wheel_base = OdometryParams().wheel_base_mm;
  bool no_gate = false, smoothed = false;
  std::string frontend = "pixels", frontend_landmarks = "all", frontend_params, observation_model = "pixel_columns";
  std::string calibrate, consider, calibration_out, noise_model;
  double drive_disparity_sigma_px = SelfCalibrationConfig().drive_disparity_sigma_px;
  std::optional<std::string> odometry_delay;  // seconds, >= 0
};

// `d`: the dataset of --from or --setup, on --rig's rig already (useRig); `handover`: what --rig
// hands over.
LocalizerConfig configFrom(const StreamArgs& a, const Dataset* d, const CalibrationHandover& handover,
                           double* compass_sigma) {
  LocalizerConfig c;
  std::optional<Pose2> start;
  if (d) {
    c.map = d->map;
    c.rig = d->rig;
    c.odometry = d->odometry;
    *compass_sigma = d->compass_sigma;
    start = d->initial_pose;
  } else {
    if (!a.map_path.empty()) c.map = FieldMap::load(a.map_path);
    if (!a.rig_path.empty()) c.rig = StereoRig::load(a.rig_path);
    c.odometry.wheel_base_mm = handover.wheels ? (*handover.wheels)[2] : a.wheel_base;
  }
  // Steps read from stdin are the robot's raw increments; a replayed dataset's were scaled by useRig.
  if (handover.wheels && a.from.empty()) c.wheel_scales = handover.wheels->head<2>();
  if (a.compass_sigma > 0) *compass_sigma = a.compass_sigma;
  if (!a.pose.empty()) start = Pose2(a.pose[0], a.pose[1], a.pose[2]);
  if (a.pose_sigma.size() != 3 || !(a.pose_sigma[0] > 0 && a.pose_sigma[1] > 0 && a.pose_sigma[2] > 0))
    throw UsageError("--pose-sigma takes three positive numbers (mm, mm, rad)");
  if (a.init == "known" || (a.init == "auto" && start)) {
    if (!start) throw UsageError("--init known needs --pose (or a dataset with an initial pose)");
    const Eigen::Vector3d s(a.pose_sigma[0], a.pose_sigma[1], a.pose_sigma[2]);
    c.init = knownBelief(*start, s.cwiseAbs2().asDiagonal());
  }
  ObservationModelConfig observation_model;
  try {
    observation_model.model = observationModelFromString(a.observation_model);
  } catch (const Error& e) {
    throw UsageError(std::string("--observation-model: ") + e.what());
  }
  SelfCalibrationConfig calibration = calibrationOptions(a.calibrate, a.consider);
  calibration.drive_disparity_sigma_px = a.drive_disparity_sigma_px;
  const bool calibrating = calibration.any() && !calibration.consider;
  if (a.method == "pf" && (calibration.range || calibration.field))
    throw UsageError("--calibrate: the particle filter self-calibrates odometry and stereo only (method 'pf')");

  if (calibration.stereo && observation_model.model == ObservationModel::RangeBearing)
    throw UsageError(std::string(calibration.consider ? "--consider" : "--calibrate") +
                     " stereo: needs a pixel observation model (--observation-model pixel_columns or pixels)");
  if (!a.calibration_out.empty() && !calibrating) throw UsageError("--calibration-out: needs --calibrate");
  if (!a.noise_model.empty()) observation_model.unmodelled = UnmodelledNoise::load(a.noise_model);
  handover.applyPriors(calibration, observation_model.unmodelled);
  c.method = localizerMethodFromString(a.method == "iekf" ? "ekf" : a.method);
  c.window.observation_model = observation_model;
  c.window.calibration = calibration;
  c.window.window = a.window;
  c.window.max_iterations = a.max_iterations;
  c.window.gate_enabled = !a.no_gate;
  c.window.keep_history = a.smoothed;  // otherwise memory stays bounded by W
  c.ekf.observation_model = observation_model;
  c.ekf.calibration = calibration;
  c.ekf.gate_enabled = !a.no_gate;
  if (a.method == "iekf") c.ekf.max_iterations = kIteratedEkfIterations;
  // Only the window smooths: the filters keep just their newest estimate, so an unbounded
  // stream runs in constant memory whatever the tracker.
  c.ekf.keep_history = false;
  c.particle_filter.particles = a.particles;
  c.particle_filter.observation_model = observation_model;
  c.particle_filter.calibration = calibration;
  c.particle_filter.keep_history = false;
  c.seed = a.seed;
  c.replay_steps = a.replay_steps;
  if (!a.odometry_delay && handover.odometry_delay_s) {
    if (*handover.odometry_delay_s < 0)
      throw Error(a.rig_path + ": odometry_delay_s: a stream is re-timed by a delay >= 0 (a negative one needs the "
                  "odometry that comes after)");
    c.odometry_delay_s = *handover.odometry_delay_s;
  }
  if (a.odometry_delay) {
    if (*a.odometry_delay == "fit")
      throw UsageError("--odometry-delay: a stream cannot fit it (the fit needs the whole run); fit it with `localize` "
                       "or `refine --odometry-delay fit` and give the seconds");
    c.odometry_delay_s = parseDelaySeconds(*a.odometry_delay, "--odometry-delay");
    if (c.odometry_delay_s < 0)
      throw UsageError("--odometry-delay: a stream is re-timed by a delay >= 0 (a negative one needs the odometry "
                       "that comes after)");
  }
  c.frontend = imageFrontendOptions(a.frontend_landmarks, a.frontend_params);
  return c;
}

void print(const std::string& line) {
  std::fwrite(line.data(), 1, line.size(), stdout);
  std::fflush(stdout);  // as soon as it is computed
}

// Each tracker's options are refused with another tracker, rather than silently ignored.
void checkMethodOptions(const StreamArgs& a, const CLI::App& sub) {
  const std::string m = "(method '" + a.method + "')";
  auto refuse = [&](const char* option, const char* who) { refuseUnused(sub, option, false, who, " " + m); };
  refuseUnused(sub, "--frontend-landmarks", a.frontend == "images", "--frontend images");
  refuseUnused(sub, "--frontend-params", a.frontend == "images", "--frontend images");
  if (a.method != "window") {
    refuse("--window", "the window");
    refuse("--max-iterations", "the window");
    refuse("--smoothed", "the window, which smooths,");
  } else {
    refuse("--replay-steps", "the filters, which replay,");
  }
  if (a.method != "pf") {
    refuse("--particles", "the particle filter");
    refuse("--seed", "the particle filter");
  }
  const bool calibrating = !a.calibrate.empty() || !a.consider.empty();
  if (!a.calibrate.empty() && a.method != "window" && a.method != "ekf" && a.method != "pf")
    throw UsageError("--calibrate: only the window, ekf and pf self-calibrate " + m);
  if (a.method != "ekf") refuse("--consider", "ekf");
  if (a.method == "pf") refuse("--no-gate", "the window and the EKFs");
  if (a.method != "window" && !((a.method == "ekf" || a.method == "pf") && calibrating)) {
    refuse("--noise-model", "the window, and ekf and pf with --calibrate or --consider");
    refuse("--observation-model", "the window, and ekf and pf with --calibrate or --consider");
  }
}

void runStream(const StreamArgs& a, const CLI::App& sub) {
  checkMethodOptions(a, sub);
  if (a.frontend != "pixels" && a.frontend != "images") throw UsageError("--frontend: expected pixels or images");
  if (a.frontend == "images" && a.from.empty())
    throw UsageError("--frontend images needs --from DIR; on stdin a line names its images (\"left\", \"right\")");
  if (!a.pose.empty() && a.pose.size() != 3) throw UsageError("--pose takes x,y,theta (mm, mm, rad)");
  std::unique_ptr<Dataset> d;
  if (!a.from.empty() || !a.setup.empty()) d = std::make_unique<Dataset>(loadDataset(a.from.empty() ? a.setup : a.from));
  if (a.frontend == "images" && !d->has_images) throw Error(a.from + ": the dataset has no images/");
  // With --from --frontend images the Localizer's frontend measures the images with the new rig;
  // stdin lines bring their own pixels, measured with the rig the user names.
  CalibrationHandover handover;
  if (!a.rig_path.empty())
    handover = d ? useRig(*d, a.rig_path, a.frontend == "images" || a.from.empty()) : CalibrationHandover::load(a.rig_path);
  if (handover.wheels && sub.count("--wheel-base") > 0)
    throw UsageError("--wheel-base: the --rig hands over its wheel estimate (wheel base " +
                     std::to_string((*handover.wheels)[2]) + " mm)");
  double compass_sigma = 0;
  Localizer loc(configFrom(a, d.get(), handover, &compass_sigma));
  long bad = 0;
  auto run = [&](const std::string& where, const StreamLine& s) {
    const StreamLineResult r = feedStreamLine(loc, s);
    for (const std::string& e : r.errors) std::cerr << "stereoloc stream: " << where << ": " << e << std::endl;
    bad += r.errors.empty() ? 0 : 1;
    print(r.output);
  };
  if (!a.from.empty()) {
    for (const Step& st : d->steps)
      run(a.from + ": step " + std::to_string(st.step), streamLineOf(st, a.from, a.frontend == "images"));
  } else {
    std::string line;
    for (long n = 1; std::getline(std::cin, line); ++n) {
      if (line.find_first_not_of(" \t\r") == std::string::npos) continue;  // blank line
      const std::string where = "stdin:" + std::to_string(n);
      try {
        run(where, parseStreamLine(line, loc.config().rig, compass_sigma));
      } catch (const Error& e) {
        ++bad;
        std::cerr << "stereoloc stream: " << where << ": " << e.what() << std::endl;
      }
    }
  }
  if (a.frontend == "images") std::cerr << "stereoloc stream: " << frontendSummary(loc.frontendStats()) << std::endl;
  if (a.smoothed) {
    StreamOutputExtras x;
    x.smoothed = true;
    for (const Estimate& e : loc.smoothedTrajectory()) print(formatStreamEstimate(e, x));
  }
  // Standard output carries only estimate lines: the calibration's summary goes to stderr (a
  // considered calibration is the given one: nothing to report).
  std::optional<CalibrationEstimate> c = loc.calibration();
  // The delay it ran with (given by --odometry-delay; one the rig file handed over goes on
  // through carriedOn with its sigma).
  if (c && a.odometry_delay) {
    c->odometry_delay_s = loc.config().odometry_delay_s;
    c->odometry_delay_sigma_s = 0.0;
  }
  if (c && !loc.config().ekf.calibration.consider)
    reportCalibration(a.calibration_out, stderr, &*c, loc.config().rig,
                      loc.config().method == LocalizerMethod::Ekf              ? loc.config().ekf.calibration
                      : loc.config().method == LocalizerMethod::ParticleFilter ? loc.config().particle_filter.calibration
                                                                               : loc.config().window.calibration,
                      loc.config().odometry.wheel_base_mm, handover);
  if (bad > 0) throw Error("stream: " + std::to_string(bad) + " bad line(s) (see the messages above)");
}

}  // namespace

void add_stream_command(CLI::App& app) {
  auto a = std::make_shared<StreamArgs>();
  CLI::App* sub = app.add_subcommand(
      "stream",
      "Real-time localization on JSON Lines: one step per line on stdin (odometry with observations or a stereo "
      "pair's image files, possibly of an earlier step: \"obs_step\"), or --from DIR; one estimate per line on "
      "stdout with its compute time (formats: src/pipeline/stream_io.h)");
  sub->add_option("--method", a->method,
                  "Tracker: window (sliding-window smoother), ekf, iekf (iterated updates) or pf (particle filter); "
                  "the window inserts late observations, the filters replay their last steps for them "
                  "(--replay-steps)")
      ->capture_default_str()
      ->check(CLI::IsMember({"window", "ekf", "iekf", "pf"}));
  sub->add_option("--window", a->window, "Window: size W (poses)")->capture_default_str()->check(CLI::Range(1, 100000));
  sub->add_option("--observation-model", a->observation_model,
                  "How the window and ekf with --calibrate use pixel observations: range_bearing, pixel_columns or pixels "
                  "(see `localize --help`); range-bearing observations stay range-bearing")
      ->capture_default_str();
  CLI::Option* from = sub->add_option("--from", a->from, "Replay a dataset directory instead of reading stdin");
  CLI::Option* setup =
      sub->add_option("--setup", a->setup, "Map, rig, odometry model and compass sigma of this dataset directory (--from has its own)")
          ->excludes(from);
  sub->add_option("--map", a->map_path, "Map YAML (default: the MiroSot field); not with --from/--setup, which have theirs")
      ->excludes(from)
      ->excludes(setup);
  sub->add_option("--rig", a->rig_path,
                  "Stereo rig YAML: the frontend's and pixel observations' calibration, also in place of the rig of "
                  "--from/--setup; a rig --calibration-out wrote also hands over its wheel estimate and its standard "
                  "deviations as the priors of --calibrate (see `localize --help`)")
      ->check(CLI::ExistingFile);
  sub->add_option("--init", a->init, "Start: auto (known when a pose is given), known, global (first global fix)")
      ->capture_default_str()
      ->check(CLI::IsMember({"auto", "known", "global"}));
  sub->add_option("--pose", a->pose, "Initial pose x,y,theta (mm, mm, rad)")->delimiter(',')->expected(3);
  sub->add_option("--pose-sigma", a->pose_sigma, "Initial sigmas x,y,theta (mm, mm, rad)")
      ->delimiter(',')
      ->expected(3)
      ->capture_default_str()
      ->check(CLI::Range(1e-6, 1e6));
  sub->add_option("--compass-sigma", a->compass_sigma, "Compass sigma (rad) for lines without compass_sigma")
      ->check(CLI::Range(kMinCompassSigmaRad, kMaxCompassSigmaRad));
  sub->add_option("--wheel-base", a->wheel_base,
                  "Wheel base (mm); not with --from/--setup, which have theirs, nor with a --rig that hands over a "
                  "wheel estimate")
      ->capture_default_str()
      ->check(CLI::Range(1.0, 1e5))
      ->excludes(from)
      ->excludes(setup);
  sub->add_option("--max-iterations", a->max_iterations, "Window: solver iterations per step")
      ->capture_default_str()
      ->check(CLI::Range(1, 1000));
  sub->add_option("--particles", a->particles, "Particles of the particle filter (at least 100)")
      ->capture_default_str()
      ->check(particleCount());
  sub->add_option("--seed", a->seed, "Seed of the particle filter's random stream")->capture_default_str();
  sub->add_option("--odometry-delay", a->odometry_delay,
                  "The odometry runs this late against the camera, seconds, 0 to 2 (a drive's latency; `localize "
                  "--odometry-delay fit` finds it): each step's increments are re-timed as they come in");
  sub->add_option("--replay-steps", a->replay_steps,
                  "Filters: how many processed steps a late observation may go back (each kept with the filter's "
                  "state: the particle filter's about 56 bytes per particle); older ones are too late, and with 0 "
                  "every late one is")
      ->capture_default_str()
      ->check(CLI::Range(0, 1000000));
  sub->add_flag("--no-gate", a->no_gate, "Window and EKFs: fuse every observation (no validation gate)");
  sub->add_flag("--smoothed", a->smoothed, "Window: after the input ends, print the smoothed trajectory (\"smoothed\":true)");
  addFrontendOptions(sub, a->frontend, a->frontend_landmarks, a->frontend_params);
  sub->add_option("--calibrate", a->calibrate,
                  "Self-calibrate in the window, the EKF or the particle filter: odometry (wheel scales, wheel base), "
                  "stereo (head tilt, baseline scale, pixel offsets, focal ratio; a pixel observation model) or both; "
                  "the window and the EKF also range (a range-bearing sensor's range factor and bearing offset) and, "
                  "with stereo, field (the MiroSot field's nine dimensions), comma-separated");
  sub->add_option("--consider", a->consider,
                  "ekf: the blocks of --calibrate considered, not estimated: the calibration stays as given, its "
                  "stated uncertainty enters the covariance (see `localize --help`)");
  sub->add_option("--noise-model", a->noise_model,
                  "YAML of the noise the rig and odometry do not state, for the window, and ekf and pf with "
                  "--calibrate or --consider (see `localize --help`)")
      ->check(CLI::ExistingFile);
  CLI::Option* calibration_out =
      sub->add_option("--calibration-out", a->calibration_out,
                      "With --calibrate: after the input ends, write the rig YAML with the tracker's calibration "
                      "estimate and its standard deviations (usable as --rig)");
  sub->add_option("--drive-disparity-sigma-px", a->drive_disparity_sigma_px,
                  "With --calibration-out: the disparity offset's part that another drive does not share, px, added to "
                  "its handed-over standard deviation (see `localize --help`)")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber)
      ->needs(calibration_out);
  sub->callback([a, sub] { runStream(*a, *sub); });
}

}  // namespace stereoloc::cli
