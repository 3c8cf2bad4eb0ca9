#include "src/pipeline/localizer.h"

#include <algorithm>
#include <chrono>
#include <utility>

#include "solvers/smoother_common.h"
#include "src/core/error.h"

namespace stereoloc {
namespace {
// Steps whose body rate is kept for observations handed over late: 10 s of odometry at 100 Hz,
// longer than any estimator keeps steps to insert or replay them.
constexpr size_t kRatesKept = 1000;
}  // namespace

// Adds the wall time of one public call to the running total.
class Localizer::Timer {
 public:
  explicit Timer(double& total) : total_(total), start_(std::chrono::steady_clock::now()) {}
  ~Timer() { total_ += std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start_).count(); }
  Timer(const Timer&) = delete;
  Timer& operator=(const Timer&) = delete;

 private:
  double& total_;
  std::chrono::steady_clock::time_point start_;
};

std::string toString(LocalizerMethod method) {
  switch (method) {
    case LocalizerMethod::Window: return "window";
    case LocalizerMethod::Ekf: return "ekf";
    case LocalizerMethod::ParticleFilter: return "pf";
  }
  return "unknown";
}

LocalizerMethod localizerMethodFromString(const std::string& name) {
  for (LocalizerMethod m : {LocalizerMethod::Window, LocalizerMethod::Ekf, LocalizerMethod::ParticleFilter})
    if (toString(m) == name) return m;
  throw Error("unknown localizer method '" + name + "' (expected window, ekf or pf)");
}

std::string toString(ObservationDelivery delivery) {
  switch (delivery) {
    case ObservationDelivery::WithStep: return "with_step";
    case ObservationDelivery::Inserted: return "inserted";
    case ObservationDelivery::TooLate: return "too_late";
    case ObservationDelivery::NotTracking: return "not_tracking";
  }
  return "unknown";
}

SlidingWindowConfig realTimeWindowConfig() {
  SlidingWindowConfig c;
  c.observation_model.model = ObservationModel::PixelColumns;
  return c;
}

Localizer::Localizer(LocalizerConfig config)
    : config_(std::move(config)), retimer_(config_.odometry_delay_s) {
  if (!(config_.wheel_scales.allFinite() && (config_.wheel_scales.array() > 0).all()))
    throw Error("localizer: wheel scales must be positive and finite");
  if (config_.replay_steps < 0) throw Error("localizer: replay_steps must be >= 0");
  switch (config_.method) {
    case LocalizerMethod::Window: {
      SlidingWindowConfig c = config_.window;
      c.init = config_.init;
      c.observation_model.rig = config_.rig;
      auto w = std::make_unique<SlidingWindowSmoother>(config_.map, config_.odometry, c);
      window_ = w.get();
      estimator_ = std::move(w);
      break;
    }
    case LocalizerMethod::Ekf: {
      EkfConfig c = config_.ekf;
      c.init = config_.init;
      c.observation_model.rig = config_.rig;
      auto e = std::make_unique<Ekf>(config_.map, config_.odometry, c);
      ekf_ = e.get();
      estimator_ = std::move(e);
      break;
    }
    case LocalizerMethod::ParticleFilter: {
      ParticleFilterConfig c = config_.particle_filter;
      c.init = config_.init;
      c.observation_model.rig = config_.rig;
      auto f = std::make_unique<ParticleFilter>(config_.map, config_.odometry, c, config_.seed);
      pf_ = f.get();
      estimator_ = std::move(f);
      break;
    }
  }
}

Localizer::~Localizer() = default;

void Localizer::check(const std::vector<Observation>& observations, long step) const {
  for (size_t i = 0; i < observations.size(); ++i) {
    const std::string where = "step " + std::to_string(step) + ": observation " + std::to_string(i);
    validateObservation(observations[i], where);
    const int id = observations[i].landmark_id;
    if (id >= 0 && !config_.map.find(id)) throw Error(where + ": unknown landmark id " + std::to_string(id));
  }
}

void Localizer::saveFilterState(FilterState& state) const {
  if (ekf_) {
    state = ekf_->saveState();
    return;
  }
  if (!std::holds_alternative<ParticleFilter::State>(state)) state = ParticleFilter::State();
  pf_->saveState(std::get<ParticleFilter::State>(state));
}

void Localizer::restoreFilterState(const FilterState& state) {
  if (ekf_)
    ekf_->restoreState(std::get<Ekf::State>(state));
  else
    pf_->restoreState(std::get<ParticleFilter::State>(state));
}

std::exception_ptr Localizer::processFromSaved(Processed& p) {
  try {
    last_ = estimator_->process(p.step);
    return nullptr;
  } catch (...) {
    // A step that fails halfway (a global fix plugged in that throws, say) would leave the
    // filter half-updated: it goes back to its state before the step and takes the step's
    // odometry alone, so that the motion still counts. The failure is reported all the same.
    std::exception_ptr failure = std::current_exception();
    restoreFilterState(p.before);
    p.step.observations.clear();
    p.step.compass.reset();
    try {
      last_ = estimator_->process(p.step);
    } catch (...) {
      restoreFilterState(p.before);  // not even the odometry: the step is dropped
    }
    return failure;
  }
}

void Localizer::flush() {
  if (!pending_) return;
  Step step = std::move(*pending_);
  pending_.reset();  // a step the estimator refuses is dropped, not retried with the next one
  if (window_) {
    last_ = estimator_->process(step);  // a failure halfway gives the window up (its process())
    return;
  }
  // The oldest kept step leaves the replay horizon now; its state's buffers take the new one
  // (without replay, the one state kept for a failed step's return reuses its own).
  Processed p;
  if (config_.replay_steps == 0) {
    p = std::move(unreplayed_);
  } else if (processed_.size() >= static_cast<size_t>(config_.replay_steps)) {
    p = std::move(processed_.front());
    processed_.pop_front();
  }
  saveFilterState(p.before);
  p.step = std::move(step);
  const std::exception_ptr failure = processFromSaved(p);
  if (config_.replay_steps == 0)
    unreplayed_ = std::move(p);
  else
    processed_.push_back(std::move(p));
  if (failure) std::rethrow_exception(failure);
}

ObservationDelivery Localizer::replay(long step, const std::vector<Observation>& observations) {
  auto from = processed_.begin();
  while (from != processed_.end() && from->step.step != step) ++from;
  if (from == processed_.end()) return ObservationDelivery::TooLate;
  // Back to the state before that step, then every step since again, the later ones' states
  // saved anew; a step that fails is taken with its odometry alone and the replay goes on.
  restoreFilterState(from->before);
  from->step.observations.insert(from->step.observations.end(), observations.begin(), observations.end());
  std::exception_ptr first_failure;
  for (auto p = from; p != processed_.end(); ++p) {
    if (p != from) saveFilterState(p->before);
    const std::exception_ptr failure = processFromSaved(*p);
    if (failure && !first_failure) first_failure = failure;
  }
  if (first_failure) std::rethrow_exception(first_failure);
  return ObservationDelivery::Inserted;
}

void Localizer::addStep(const Step& step) {
  const Timer timer(running_ms_);
  if (finished_) throw Error("localizer: step " + std::to_string(step.step) + " after smoothedTrajectory()");
  if (have_step_ && step.step <= newest_step_)
    throw Error("step " + std::to_string(step.step) + " does not follow step " + std::to_string(newest_step_));
  validateStep(step, "localizer");
  if (have_step_ && step.t < newest_t_)
    throw Error("step " + std::to_string(step.step) + ": t " + std::to_string(step.t) + " s is earlier than step " +
                std::to_string(newest_step_) + "'s " + std::to_string(newest_t_) + " s");
  check(step.observations, step.step);
  // Scaled first, then re-timed, as `localize` re-times the steps its --rig scaled.
  const WheelIncrements moved = retimer_.next(step.t, step.d_left * config_.wheel_scales[0],
                                              step.d_right * config_.wheel_scales[1]);
  const long previous = newest_step_;
  std::string failure;
  try {
    flush();
  } catch (const Error& e) {  // reported, but the new step is still taken
    failure = e.what();
  }
  if (config_.rig.params().exposure_offset_s != 0.0) {  // the rates only the offset needs
    if (!rate_tracker_) rate_tracker_.emplace(config_.odometry.wheel_base_mm);
    rates_.emplace_back(step.step,
                        rate_tracker_->add(step.t, moved.d_left, moved.d_right,
                                           stepRotationVariance(moved.d_left, moved.d_right, config_.odometry)));
    if (rates_.size() > kRatesKept) rates_.pop_front();
  }
  pending_ = step;
  pending_->d_left = moved.d_left;
  pending_->d_right = moved.d_right;
  pending_->observations = synchronised(step.step, step.observations);
  newest_step_ = step.step;
  newest_t_ = step.t;
  have_step_ = true;
  if (!failure.empty()) throw Error("step " + std::to_string(previous) + ": " + failure);
}

void Localizer::addOdometry(long step, double t, double d_left, double d_right) {
  Step s;
  s.step = step;
  s.t = t;
  s.d_left = d_left;
  s.d_right = d_right;
  addStep(s);
}

ObservationDelivery Localizer::deliver(long step, const std::vector<Observation>& observations) {
  if (finished_) throw Error("localizer: observations after smoothedTrajectory()");
  if (!have_step_ || step > newest_step_)
    throw Error("observations of step " + std::to_string(step) + " before its odometry" +
                (have_step_ ? " (the newest step is " + std::to_string(newest_step_) + ")" : ""));
  check(observations, step);
  const std::vector<Observation> now = synchronised(step, observations);
  if (pending_ && pending_->step == step) {
    pending_->observations.insert(pending_->observations.end(), now.begin(), now.end());
    return ObservationDelivery::WithStep;
  }
  if (!window_) return replay(step, now);
  const LateObservationResult r = window_->insertLate(step, now);
  switch (r.status) {
    case LateObservationStatus::Inserted:
      // The newest estimate is the window's; a waiting step is processed on top of it.
      if (!pending_) last_ = r.estimate;
      return ObservationDelivery::Inserted;
    case LateObservationStatus::TooLate: return ObservationDelivery::TooLate;
    case LateObservationStatus::NotTracking: return ObservationDelivery::NotTracking;
  }
  return ObservationDelivery::TooLate;
}

std::vector<Observation> Localizer::synchronised(long step, const std::vector<Observation>& observations) const {
  if (config_.rig.params().exposure_offset_s == 0.0) return observations;
  const auto at = std::find_if(rates_.rbegin(), rates_.rend(), [step](const auto& r) { return r.first == step; });
  // Older than the rates kept: too late for every estimator's buffer as well.
  if (at == rates_.rend()) return observations;
  std::vector<Observation> out;
  out.reserve(observations.size());
  for (size_t i = 0; i < observations.size(); ++i) {
    try {
      out.push_back(synchronisedObservation(config_.rig, observations[i], at->second));
    } catch (const GeometryError& e) {
      throw Error("step " + std::to_string(step) + ": observation " + std::to_string(i) + ": " + e.what());
    }
  }
  return out;
}

ObservationDelivery Localizer::addObservations(long step, const std::vector<Observation>& observations) {
  const Timer timer(running_ms_);
  return deliver(step, observations);
}

ImageObserver& Localizer::observer() {
  if (!observer_) observer_ = std::make_unique<ImageObserver>(config_.rig, config_.map, config_.frontend);
  return *observer_;
}

ObservationDelivery Localizer::addImages(long step, const cv::Mat& left, const cv::Mat& right, double head_pan) {
  const Timer timer(running_ms_);
  if (!have_step_ || step > newest_step_)  // before running the frontend for nothing
    return deliver(step, {});
  const cv::Size size(config_.rig.params().image_width, config_.rig.params().image_height);
  if (left.type() != CV_8UC3 || right.type() != CV_8UC3 || left.size() != size || right.size() != size)
    throw Error("step " + std::to_string(step) + ": images must be 8-bit BGR of the rig's size " +
                std::to_string(size.width) + "x" + std::to_string(size.height));
  return deliver(step, observer().observe(left, right, head_pan));
}

ObservationDelivery Localizer::addImageFiles(long step, const std::string& left_path, const std::string& right_path,
                                             double head_pan) {
  const Timer timer(running_ms_);
  if (!have_step_ || step > newest_step_) return deliver(step, {});
  const cv::Mat left = readStereoImage(left_path, config_.rig);
  const cv::Mat right = readStereoImage(right_path, config_.rig);
  return deliver(step, observer().observe(left, right, head_pan));
}

Estimate Localizer::estimate() {
  {
    const Timer timer(running_ms_);
    flush();
    if (window_ && have_step_) last_ = window_->current();
  }
  compute_ms_ = running_ms_;
  running_ms_ = 0;
  if (!have_step_) {
    Estimate e;
    e.status = EstimateStatus::Uninitialised;
    return e;
  }
  return last_;
}

std::vector<Estimate> Localizer::smoothedTrajectory() {
  const Timer timer(running_ms_);
  flush();
  finished_ = true;
  return estimator_->finish();
}

ImageFrontendStats Localizer::frontendStats() const { return observer_ ? observer_->stats() : ImageFrontendStats(); }

}  // namespace stereoloc
