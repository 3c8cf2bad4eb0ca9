#pragma once
// stereoloc::Localizer: the real-time pipeline a robot program embeds -- the vision frontend
// (thesis chapter 3) and a tracker (the sliding-window smoother by default) behind a few calls.
//
//   stereoloc::LocalizerConfig config;                 // map, rig, odometry model, estimator
//   config.init = stereoloc::knownBelief(start, P0);   // or the default: wait for a global fix
//   stereoloc::Localizer loc(config);
//   loc.addOdometry(step, t, d_left, d_right);         // every encoder reading (mm, s)
//   loc.addImages(frame_step, left, right, head_pan);  // a rectified BGR pair, possibly late
//   const stereoloc::Estimate e = loc.estimate();      // pose and 3x3 covariance now
//   ... loc.smoothedTrajectory();                      // at the end
//
// Steps. The caller numbers its odometry readings, strictly increasing. A step is processed
// when its data are complete: at the next addOdometry/addStep or at estimate(). Observations or
// images of the newest step given before that are fused with it, exactly as the dataset
// commands fuse a step's observations (so `stream` on a replayed run equals `localize`). Those
// of an earlier step are late: the sliding window inserts them at their own pose while it is in
// the window (SlidingWindowSmoother::insertLate) and reports them too late otherwise; the
// filters (EKF and particle filter) go back to their state before that step and process the
// steps since again with them (as robot_localization replays its filter), for the last
// replay_steps steps.
//
// Errors: bad input (a step that does not follow the newest or has an earlier time, non-finite
// values, an unknown landmark id, an unreadable or wrong-size image) throws stereoloc::Error
// with one line and changes nothing, so the caller can go on: an unreadable image loses the
// frame, not the step's odometry. A step the tracker fails on halfway (a global fix plugged in
// that throws, the window's information rank deficient) throws too, and the tracker goes on:
// the window is given up until the next global fix (SlidingWindowSmoother::process), a filter
// goes back to its state before the step and takes the step's odometry alone.
// Memory: bounded by the window W when window.keep_history is false, constant with the
// filters when ekf.keep_history / particle_filter.keep_history are (an unbounded stream);
// otherwise one Estimate per step is kept for smoothedTrajectory().
// Timing: computeMilliseconds() is the wall time spent inside the Localizer since the previous
// estimate() up to the end of the last one (image decoding, frontend, estimator): the latency
// the robot pays for the step.
// Not thread-safe: one Localizer per thread. Deterministic: same calls, same results.
#include <opencv2/core/mat.hpp>
#include <deque>
#include <exception>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <variant>
#include <vector>

#include "solvers/ekf.h"
#include "solvers/particle_filter.h"
#include "solvers/sliding_window_smoother.h"
#include "src/core/exposure_offset.h"
#include "src/core/field_map.h"
#include "src/core/odometry_delay.h"
#include "src/core/odometry_model.h"
#include "src/core/stereo_rig.h"
#include "src/core/types.h"
#include "src/pipeline/frontend_source.h"

namespace stereoloc {

enum class LocalizerMethod { Window, Ekf, ParticleFilter };
std::string toString(LocalizerMethod method);                       // "window", "ekf", "pf"
LocalizerMethod localizerMethodFromString(const std::string& name);  // throws stereoloc::Error

// What happened to observations or images handed to the Localizer.
enum class ObservationDelivery {
  WithStep,     // of the newest step, not processed yet: fused with its odometry
  Inserted,     // late, inserted at their own pose in the window
  TooLate,      // late, and their step has left the window or the filter's replay
  NotTracking,  // late, while the tracker is uninitialised or lost (not fused, as in-time ones)
};
std::string toString(ObservationDelivery delivery);  // "with_step", "inserted", "too_late", "not_tracking"

// The sliding window of `localize --method window`: pixel-column factors for pixel observations.
SlidingWindowConfig realTimeWindowConfig();

struct LocalizerConfig {
  FieldMap map = FieldMap::miroSot();
  StereoRig rig;                     // calibration of the frontend and of pixel observations
  OdometryParams odometry;           // wheel base (mm) and wheel noise
  // Left and right wheel scales (true travel per unit of reading) every step's increments are
  // multiplied by: a wheel calibration handed over from an earlier run (CalibrationHandover).
  Eigen::Vector2d wheel_scales = Eigen::Vector2d::Ones();
  // s, 0 to 10: the odometry runs this late against the camera (a drive's latency, a clock
  // offset; fitted offline by `localize --odometry-delay fit`): each step's scaled increments
  // are re-timed as they come in (OdometryRetimer, src/core/odometry_delay.h), as `localize
  // --odometry-delay` re-times a dataset.
  double odometry_delay_s = 0.0;
  InitialBelief init;                // start belief of the estimator; default: wait for a global fix
  LocalizerMethod method = LocalizerMethod::Window;
  SlidingWindowConfig window = realTimeWindowConfig();  // its init is replaced by `init`, its rig by `rig`
  // Method Ekf (max_iterations > 1: the iterated EKF; ekf.calibration: the self-calibrating
  // EKF); init replaced, its observation model's rig by `rig`.
  EkfConfig ekf;
  // Methods Ekf and ParticleFilter: how many processed steps a late observation may go back
  // (each kept with the filter's state before it, Ekf::saveState, ParticleFilter::saveState:
  // the particle filter's takes about 56 bytes per particle); 0: late observations are too late.
  int replay_steps = 100;
  ParticleFilterConfig particle_filter;  // method ParticleFilter; init replaced
  uint64_t seed = 1;                 // the particle filter's random stream
  ImageFrontendOptions frontend;     // frontend parameters and which landmarks it reports
};

class Localizer {
 public:
  explicit Localizer(LocalizerConfig config);  // throws stereoloc::Error for an invalid config
  ~Localizer();
  Localizer(const Localizer&) = delete;
  Localizer& operator=(const Localizer&) = delete;

  // A new step: its wheel increments (mm since the previous step), time (s), optional compass
  // and head pan, and the observations it already has. The previous step is processed now.
  void addStep(const Step& step);
  void addOdometry(long step, double t, double d_left, double d_right);
  // Observations of step `step` (the newest or an earlier one), in the robot frame.
  ObservationDelivery addObservations(long step, const std::vector<Observation>& observations);
  // The frontend on a rectified 8-bit BGR pair of the rig's size taken at step `step` with the
  // head at `head_pan` (rad); its observations then go as addObservations.
  ObservationDelivery addImages(long step, const cv::Mat& left, const cv::Mat& right, double head_pan = 0.0);
  // The same from image files (PNG, ...); errors name the file.
  ObservationDelivery addImageFiles(long step, const std::string& left_path, const std::string& right_path,
                                    double head_pan = 0.0);

  // Processes the newest step if it is waiting and returns the real-time estimate of it
  // (status Uninitialised before the first pose or before the first step).
  Estimate estimate();
  // See the header comment; 0 before the first estimate().
  double computeMilliseconds() const { return compute_ms_; }
  // The whole trajectory, smoothed by the smoothers (finish()); nothing may be added afterwards.
  std::vector<Estimate> smoothedTrajectory();

  long newestStep() const { return newest_step_; }  // -1 before the first step
  const LocalizerConfig& config() const { return config_; }
  ImageFrontendStats frontendStats() const;  // what the frontend did so far
  // The window, for its statistics (nullptr for the other methods).
  const SlidingWindowSmoother* window() const { return window_; }
  // The window's or the EKF's self-calibration estimate with its covariance after the newest
  // step (window.calibration, ekf.calibration; with ekf.calibration.consider the given
  // calibration and its prior, Ekf::calibration); nullopt without it or for the particle filter.
  std::optional<CalibrationEstimate> calibration() const {
    if (window_) return window_->calibration();
    if (pf_) return pf_->calibration();
    return ekf_ ? ekf_->calibration() : std::nullopt;
  }

 private:
  class Timer;
  void flush();
  void check(const std::vector<Observation>& observations, long step) const;
  ObservationDelivery deliver(long step, const std::vector<Observation>& observations);
  // A filter's late observations: replays the processed steps from `step` on with them.
  ObservationDelivery replay(long step, const std::vector<Observation>& observations);
  using FilterState = std::variant<Ekf::State, ParticleFilter::State>;
  // Into `state`; the particle filter's reuses the particle buffers `state` already holds.
  void saveFilterState(FilterState& state) const;
  void restoreFilterState(const FilterState& state);
  ImageObserver& observer();

  LocalizerConfig config_;
  std::unique_ptr<Estimator> estimator_;
  SlidingWindowSmoother* window_ = nullptr;  // estimator_, when it is the window
  Ekf* ekf_ = nullptr;                       // estimator_, when it is the EKF
  ParticleFilter* pf_ = nullptr;             // estimator_, when it is the particle filter
  std::unique_ptr<ImageObserver> observer_;  // created with the first images
  std::optional<Step> pending_;              // the newest step, not processed yet
  // The body rate of the recent steps (BodyRateTracker on their re-timed increments), for the
  // rig's exposure offset (synchronisedObservation) on observations handed over late.
  std::deque<std::pair<long, BodyRate>> rates_;
  std::optional<BodyRateTracker> rate_tracker_;
  std::vector<Observation> synchronised(long step, const std::vector<Observation>& observations) const;
  OdometryRetimer retimer_;                  // config_.odometry_delay_s
  // A filter's last processed steps, each with the filter's state before it (replay_steps).
  struct Processed {
    Step step;
    FilterState before;
  };
  // The filter on p.step from the state p.before holds (restored only on a failure): a step
  // that fails halfway is taken again from there with its odometry alone (p.step loses its
  // observations and compass) and its exception returned; null when it went through.
  std::exception_ptr processFromSaved(Processed& p);
  std::deque<Processed> processed_;
  Processed unreplayed_;  // with replay_steps 0: the state before the step being processed
  Estimate last_;                            // the newest estimate
  long newest_step_ = -1;
  double newest_t_ = 0.0;  // s, of newest_step_
  bool have_step_ = false;
  bool finished_ = false;
  double running_ms_ = 0;  // time spent since the previous estimate()
  double compute_ms_ = 0;
};

}  // namespace stereoloc
