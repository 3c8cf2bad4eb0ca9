#pragma once
// The estimation methods by name, run over a whole Dataset: what `stereoloc localize`, `refine`
// and the studies offer. A method spec is NAME or NAME:INIT, e.g. "ekf", "ekf:random",
// "pf:global", "window", "batch", "fix2", "deadreckoning".
#include <cstdint>
#include <string>
#include <vector>

#include <optional>

#include "solvers/batch_smoother.h"
#include "solvers/initialisation.h"
#include "solvers/odometry_delay_profile.h"
#include "solvers/particle_filter.h"
#include "solvers/self_calibration.h"
#include "solvers/smoother_common.h"
#include "src/io/dataset.h"
#include "src/core/types.h"
#include "src/sim/error_profile.h"

namespace stereoloc {

enum class OdometryDelayMode { None, Given, Fit };

struct MethodOptions {
  InitMode init = InitMode::Known;   // overridden by a ":init" suffix in the method spec
  InitConfig init_config;            // noise of the known start, spread of the random start
  int particles = 3000;              // pf (the bound N_max with KLD-sampling)
  ParticleProposal pf_proposal = ParticleProposal::LinearisedOptimal;  // pf; Prior = Algorithm 6 as printed
  bool pf_kld = false;               // pf: KLD-sampling with KldSamplingConfig's defaults
  int window = 20;                   // window
  RobustLoss loss = RobustLoss::None;  // batch and window observation factors
  // Batch and window, with the dataset's rig. The CLI default is the pixel columns: the same
  // data as range-bearing, without the conversion bias (solvers/smoother_common.h); observations
  // without pixels (real range-bearing data) stay range-bearing.
  ObservationModel observation_model = ObservationModel::PixelColumns;
  double loss_scale = 2.0;           // whitened units
  bool gate_enabled = true;          // ekf, window
  // batch, window, ekf and pf: self-calibration (solvers/self_calibration.h) when either part is on.
  SelfCalibrationConfig calibration;
  // Batch and window pixel models, the self-calibrating EKF's and PF's stereo update: px, > 0 replaces the observations' own pixel sigma (an
  // honest noise for a world with vibration and blur, docs/realistic_world.md); 0 keeps theirs.
  double pixel_sigma = 0.0;
  // Batch, window and the self-calibrating EKF: the errors the rig and odometry do not state
  // (lens estimate, vibration: the pixel models; slip: the odometry's noise). Zero: none.
  UnmodelledNoise noise{};
  // Every method: the odometry runs this late against the camera (src/core/odometry_delay.h),
  // given or fitted by the batch smoother with these options (solvers/odometry_delay_profile.h)
  // before the method runs on the re-timed steps.
  OdometryDelayMode odometry_delay = OdometryDelayMode::None;
  double given_odometry_delay_s = 0.0;  // s, with OdometryDelayMode::Given
  OdometryDelaySearch odometry_delay_search;  // with OdometryDelayMode::Fit
};

// What the user of a robot with error profile `profile` states (its sigmas, not its draws):
// the noise model (the distortion estimate's error, vibration, slip) and the self-calibration's
// priors (the calibration's uncertainty), on a rig of focal length `focal_px`
// (docs/realistic_world.md, "Noise model"). An ideal profile leaves `options` as they are.
void applyErrorProfile(const ErrorProfile& profile, double focal_px, MethodOptions& options);

struct MethodRun {
  std::string method;                // the spec as given
  std::vector<Estimate> estimates;   // one per step that produced a pose (fixes: steps with a fix)
  double ms_per_step = 0;            // wall-clock, mean over steps
  long attempted_steps = 0;          // fixes: steps with at least one observation
  long fixed_steps = 0;              // fixes: steps that gave a fix
  std::optional<CalibrationEstimate> calibration;  // batch, window or ekf with MethodOptions::calibration
  std::optional<OdometryDelayEstimate> odometry_delay;  // with OdometryDelayMode::Fit
};

// The names accepted before the optional ":init" ("iekf": the EKF with iterated updates), and
// them comma-separated for help texts and errors.
const std::vector<std::string>& methodNames();
std::string methodNamesText();

// Gauss-Newton iterations of the iterated EKF's updates ("iekf"; solvers/ekf.h); it stops
// earlier when converged, typically after 2-3.
constexpr int kIteratedEkfIterations = 10;

// Whether the method `name` (without ":init") can self-calibrate (MethodOptions::calibration):
// the smoothers, the EKF (solvers/ekf.h, "Self-calibration") and the particle filter (its
// odometry and stereo blocks); kSelfCalibratingText names them for errors.
bool selfCalibrates(const std::string& name);
inline const std::string kSelfCalibratingText = "batch, window, ekf and pf";
// Whether the method `name` can consider its calibration (SelfCalibrationConfig::consider): the
// EKF (all its blocks) and the fixes (the stereo block, solvers/considered_fix.h).
bool considers(const std::string& name);
inline const std::string kConsideringText = "ekf, fix1 and fix2";

// A spec may end in ":calib" ("batch:calib", "window:known:calib", "ekf:calib", "pf:calib"): the method with
// odometry and stereo self-calibration (MethodOptions::calibration), for the studies' calibrated
// variants; or, for the EKF and the fixes, in ":consider" ("ekf:consider", "fix2:consider"): the
// same blocks considered, not estimated (SelfCalibrationConfig::consider; a fix the stereo block).
// ":calib-field" ("batch:calib-field", "window:calib-field", "ekf:calib-field"): the method also
// estimating the field's dimensions (SelfCalibrationConfig::field).
bool hasCalibrationSuffix(const std::string& spec);  // ":calib" or ":calib-field"
bool hasFieldSuffix(const std::string& spec);        // ":calib-field"
bool hasConsiderSuffix(const std::string& spec);     // ":consider"
std::string withoutCalibrationSuffix(const std::string& spec);  // without either

// Splits "ekf:random" into ("ekf", Random); throws UsageError for an unknown name or init.
std::pair<std::string, InitMode> parseMethodSpec(const std::string& spec, InitMode default_init);

// The batch smoother's configuration as runMethod makes it for `spec` ("batch", "batch:global"):
// the start belief (drawn from `seed`), the loss and the observation model. `refine` runs the same
// smoother with progress reports.
BatchSmootherConfig batchConfigFor(const std::string& spec, const Dataset& dataset, uint64_t seed,
                                   const MethodOptions& options);

// The dataset's steps with the odometry delay of `options` (src/core/odometry_delay.h): as they
// are (OdometryDelayMode::None), re-timed by the given delay, or by the one the batch smoother
// finds with the options, start and self-calibration of `spec` (solvers/odometry_delay_profile.h;
// the estimate in *fitted when not null). Throws stereoloc::Error when the fit fails.
std::vector<Step> stepsWithOdometryDelay(const std::string& spec, const Dataset& dataset, uint64_t seed,
                                         const MethodOptions& options, std::optional<OdometryDelayEstimate>* fitted);

// Runs a method over a whole dataset (with an odometry delay in `options`, over
// stepsWithOdometryDelay's steps). `seed` drives the known-start noise, the random start and
// the particle filter, so a run is reproducible.
MethodRun runMethod(const std::string& spec, const Dataset& dataset, uint64_t seed, const MethodOptions& options);

}  // namespace stereoloc
