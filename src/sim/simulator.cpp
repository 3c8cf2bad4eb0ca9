#include "src/sim/simulator.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <map>
#include <utility>

#include <Eigen/Cholesky>

#include <opencv2/calib3d.hpp>

#include "src/core/error.h"
#include "src/core/measurement_model.h"

namespace stereoloc {
namespace {

// Moves the obstacles by one step: robots wander with slowly changing headings, the ball rolls
// straight; both bounce off the walls and are pushed out of a disc around the simulated robot
// (so they never overlap it or its cameras).
void moveObstacles(std::vector<Obstacle>& obs, std::vector<double>& dir, const FieldGeometry& g,
                   const Pose2& robot, double speed, std::mt19937_64& rng) {
  std::normal_distribution<double> N(0.0, 1.0);
  for (size_t i = 0; i < obs.size(); ++i) {
    Obstacle& o = obs[i];
    const bool ball = o.kind == Obstacle::Kind::Ball;
    if (!ball) dir[i] += 0.2 * N(rng);
    const double v = ball ? 2.0 * speed : speed;
    Eigen::Vector2d p = o.position + v * Eigen::Vector2d(std::cos(dir[i]), std::sin(dir[i]));
    const double m = 0.5 * o.size + 5.0;
    if (p.x() < m || p.x() > g.length - m) {
      dir[i] = kPi - dir[i];
      p.x() = std::clamp(p.x(), m, g.length - m);
    }
    if (p.y() < m || p.y() > g.width - m) {
      dir[i] = -dir[i];
      p.y() = std::clamp(p.y(), m, g.width - m);
    }
    const Eigen::Vector2d away = p - robot.translation();
    const double keep = 0.5 * o.size + 80.0;
    if (away.norm() < keep) p = robot.translation() + keep * (away.norm() > 1e-9 ? away.normalized() : Eigen::Vector2d(1, 0));
    dir[i] = wrapAngle(dir[i]);
    o.position = p;
    if (!ball) o.heading = wrapAngle(dir[i]);
  }
}

// The raw (distorted, unrectified) pixels of a point given in C0, through the true cameras of
// a drawn error profile; nullopt when it is behind either camera.
std::optional<StereoPixels> trueRawPixels(const StereoRig& true_rig, const DrawnErrors& e, size_t step,
                                          const Eigen::Vector3d& p_robot, double pan, const StereoRig& nominal) {
  const Eigen::Vector3d p = true_rig.robotToVision(p_robot, pan);
  const double hb = 0.5 * true_rig.params().baseline_mm;
  double uv[2][2];
  for (int c = 0; c < 2; ++c) {
    // C2 (x forward, y left, z up) -> the ideal camera's OpenCV axes (x right, y down, z forward).
    const cv::Mat X = (cv::Mat_<double>(3, 1) << -(p.y() - (c == 0 ? hb : -hb)), -p.z(), p.x());
    const RawCamera cam = trueCamera(nominal, e, c, step);
    const cv::Mat Xr = cam.R * X;
    if (!(Xr.at<double>(2) > 1.0)) return std::nullopt;
    std::vector<cv::Point2d> out;
    cv::projectPoints(std::vector<cv::Point3d>{cv::Point3d(Xr.at<double>(0), Xr.at<double>(1), Xr.at<double>(2))},
                      cv::Vec3d(0, 0, 0), cv::Vec3d(0, 0, 0), cam.K, cam.D, out);
    uv[c][0] = out[0].x;
    uv[c][1] = out[0].y;
  }
  return StereoPixels{uv[0][0], uv[0][1], uv[1][0], uv[1][1]};
}

// Raw pixels -> rectified pixels of a calibration (in place); false when a point leaves the
// rectified images.
bool rectifyPixels(const StereoCalibration& c, StereoPixels& px) {
  std::vector<cv::Point2d> l{{px.u_left, px.v_left}}, r{{px.u_right, px.v_right}}, lo, ro;
  const cv::TermCriteria crit(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 50, 1e-10);
  cv::undistortPoints(l, lo, c.K1, c.D1, c.R1, c.P1, crit);
  cv::undistortPoints(r, ro, c.K2, c.D2, c.R2, c.P2, crit);
  px = StereoPixels{lo[0].x, lo[0].y, ro[0].x, ro[0].y};
  const double w = c.image_size.width - 0.5, h = c.image_size.height - 0.5;
  auto in = [&](double u, double v) { return u >= -0.5 && u < w && v >= -0.5 && v < h; };
  return in(px.u_left, px.v_left) && in(px.u_right, px.v_right);
}

}  // namespace

Eigen::Matrix4d StereoPixelNoise::covariance() const { return stereoPixelCovariance(sigma_u, sigma_v, sigma_d, corr_ud); }

std::string toString(PixelNoiseModel model) { return model == PixelNoiseModel::PerKind ? "per_kind" : "independent"; }

PixelNoiseModel pixelNoiseModelFromString(const std::string& name) {
  if (name == "per_kind") return PixelNoiseModel::PerKind;
  if (name == "independent") return PixelNoiseModel::Independent;
  throw Error("unknown pixel noise model '" + name + "' (expected independent or per_kind)");
}

const StereoPixelNoise& KindPixelNoise::of(LandmarkType type) const {
  switch (type) {
    case LandmarkType::GoalCorner: return goal;
    case LandmarkType::Junction: return junction;
    case LandmarkType::Intersection: return intersection;
    default: return corner;
  }
}

std::string toString(LandmarkSet set) { return set == LandmarkSet::All ? "all" : "goal_corners"; }

LandmarkSet landmarkSetFromString(const std::string& name) {
  if (name == "all") return LandmarkSet::All;
  if (name == "goal_corners") return LandmarkSet::GoalCorners;
  throw Error("unknown landmark set '" + name + "' (expected goal_corners or all)");
}

void SimulationConfig::validate() const {
  auto nonneg = [](double v, const char* name) {
    if (!(std::isfinite(v) && v >= 0)) throw Error(std::string("simulation: ") + name + " must be a finite number >= 0");
  };
  nonneg(encoder_k, "encoder_k");
  nonneg(compass_sigma, "compass_sigma");
  nonneg(pixel_sigma, "pixel_sigma");
  if (pixel_noise == PixelNoiseModel::PerKind) {
    for (const auto& [name, n] : {std::pair<const char*, const StereoPixelNoise*>{"corner", &kind_noise.corner},
                                  {"junction", &kind_noise.junction},
                                  {"intersection", &kind_noise.intersection},
                                  {"goal", &kind_noise.goal}}) {
      try {
        n->covariance();
      } catch (const Error& e) {
        throw Error(std::string("simulation: kind_noise.") + name + ": " + e.what());
      }
    }
  }
  nonneg(obstacle_speed, "obstacle_speed");
  if (!(std::isfinite(compass_bias))) throw Error("simulation: compass_bias must be finite");
  if (!(std::isfinite(compass_sigma_floor) && compass_sigma_floor > 0))
    throw Error("simulation: compass_sigma_floor must be positive");
  if (!(std::isfinite(wheel_base_mm) && wheel_base_mm > 0)) throw Error("simulation: wheel_base_mm must be positive");
  if (!(std::isfinite(dt) && dt > 0)) throw Error("simulation: dt must be positive");
  if (obstacles < 0 || obstacles > 100) throw Error("simulation: obstacles must be in 0..100");
  if (scenario.steps < 0) throw Error("simulation: steps must be >= 0");
  try {
    profile.validate();
  } catch (const Error& e) {
    throw Error("simulation: profile " + profile.name + ": " + e.what());
  }
}

Pose2 poseAtStep(const Scenario& sc, double step) {
  const double last = static_cast<double>(sc.poses.size() - 1);
  const double t = std::clamp(step, 0.0, last);
  const size_t k = std::min(static_cast<size_t>(t), sc.poses.size() - 1);
  const double a = t - static_cast<double>(k);
  if (a <= 0.0 || k + 1 >= sc.poses.size()) return sc.poses[k];
  const Arc arc = arcBetween(sc.poses[k], sc.poses[k + 1]);
  // Any wheel base gives the same arc; 1 mm keeps the increments well scaled.
  const WheelIncrements w = wheelIncrementsForArc(a * arc.length, a * arc.dtheta, 1.0);
  return compose(sc.poses[k], Pose2::fromVector(controlVector(w.d_left, w.d_right, 1.0)));
}

Eigen::Vector3d cameraCentreWorld(const StereoRig& rig, const Pose2& robot, double head_pan, int camera) {
  const double hb = 0.5 * rig.params().baseline_mm;
  const Eigen::Vector3d c = rig.visionToRobot(Eigen::Vector3d(0.0, camera == 0 ? hb : -hb, 0.0), head_pan);
  const Eigen::Vector2d w = transformToWorld(robot, c.head<2>());
  return Eigen::Vector3d(w.x(), w.y(), c.z());
}

std::vector<VisibleLandmark> visibleLandmarks(const FieldMap& map, const StereoRig& rig, const Scene& scene,
                                              const Pose2& robot, double head_pan, LandmarkSet set) {
  std::vector<VisibleLandmark> out;
  const StereoRigParams& p = rig.params();
  const Eigen::Vector3d cam_l = cameraCentreWorld(rig, robot, head_pan, 0);
  const Eigen::Vector3d cam_r = cameraCentreWorld(rig, robot, head_pan, 1);
  for (const Landmark& l : map.landmarks()) {
    if (set == LandmarkSet::GoalCorners && l.type != LandmarkType::GoalCorner) continue;
    const Eigen::Vector2d local = transformToLocal(robot, l.xy());
    if (local.norm() > p.max_range_mm) continue;
    const auto px = rig.project(Eigen::Vector3d(local.x(), local.y(), l.position.z()), head_pan);
    if (!px || !rig.inImages(*px) || px->disparity() < p.min_disparity_px) continue;
    // Both cameras must be in front (project checks the rig centre only).
    const Eigen::Vector3d pv = rig.robotToVision(Eigen::Vector3d(local.x(), local.y(), l.position.z()), head_pan);
    if (pv.x() <= 1.0) continue;
    if (scene.occluded(cam_l, l.position) || scene.occluded(cam_r, l.position)) continue;
    out.push_back({l.id, *px});
  }
  return out;
}

namespace {

// One simulated run: the scenario, the drawn errors and the random streams, and the steps made
// from them. One random stream per concern (scenario, encoders, compass, obstacles, pixels,
// error profile), each seeded from the seed's master stream. The standard normal N is one
// object for the encoder, compass and pixel draws, and it caches every second draw from the
// stream that made it: the order of the draws within a step is part of a dataset's definition.
class Simulation {
 public:
  Simulation(const std::string& scenario_name, int trial, const SimulationConfig& cfg, uint64_t seed);
  Dataset run(SimulationTrace* trace);

 private:
  std::string description(uint64_t seed) const;
  void placeObstacles();
  std::vector<WheelIncrements> scenarioWheelTravel() const;
  void driveWheels(size_t s, Step* st);
  void observe(size_t s, const Scene& world, Step* st);

  const std::string scenario_name_;
  const int trial_;
  const SimulationConfig& cfg_;
  std::mt19937_64 master_;
  std::mt19937_64 rng_scenario_, rng_encoder_, rng_compass_, rng_obstacles_, rng_pixels_;
  std::normal_distribution<double> N_{0.0, 1.0};
  const bool ideal_;
  const Scenario sc_;
  double q_ = 0.0;  // quantisation step, px (0: none)
  StereoRigParams rp_;
  Dataset d_;
  StereoRig nominal_;
  DrawnErrors drawn_;
  FieldMap true_map_;  // the field the world is built on (the given map unless the field is off)
  std::vector<Obstacle> obstacles_;
  std::vector<double> obstacle_dir_;
  // Per-kind model: C per landmark type and its lower Cholesky factor (C = L L^T).
  std::map<LandmarkType, std::pair<Eigen::Matrix4d, Eigen::Matrix4d>> kind_model_;
};

Simulation::Simulation(const std::string& scenario_name, int trial, const SimulationConfig& cfg, uint64_t seed)
    : scenario_name_(scenario_name), trial_(trial), cfg_(cfg), master_(seed),
      rng_scenario_(master_()), rng_encoder_(master_()), rng_compass_(master_()), rng_obstacles_(master_()),
      rng_pixels_(master_()), ideal_(cfg.profile.isIdeal()),
      sc_(makeScenario(scenario_name, trial, cfg.scenario, rng_scenario_)) {
  const size_t n = sc_.poses.size();
  if (n == 0) throw Error("simulation: scenario has no steps");
  q_ = cfg_.quantise ? 1.0 : 0.0;
  const double sigma_eff = std::sqrt(cfg_.pixel_sigma * cfg_.pixel_sigma + q_ / 12.0);
  rp_ = cfg_.rig;
  // The rig must carry a positive sigma even for noise-free pixels: observations need an R.
  rp_.pixel_sigma = std::max(sigma_eff, 1e-3);
  d_.name = scenario_name_;
  d_.map = cfg_.map;
  d_.rig = StereoRig(rp_);
  nominal_ = d_.rig;
  if (!ideal_) {
    std::mt19937_64 rng_profile(master_());
    drawn_ = drawErrors(cfg_.profile, n, rng_profile, scenarioWheelTravel());
    d_.rig = StereoRig(rp_, givenCalibration(nominal_, drawn_));
  }
  true_map_ = trueFieldMap(cfg_.map, drawn_);
  d_.odometry = OdometryParams();
  d_.odometry.wheel_base_mm = cfg_.wheel_base_mm;
  d_.odometry.k_left = d_.odometry.k_right = cfg_.encoder_k;
  d_.odometry.validate();
  d_.compass_sigma = cfg_.compass ? std::max(cfg_.compass_sigma, cfg_.compass_sigma_floor) : 0.0;
  d_.initial_pose = sc_.poses[0];
  d_.has_images = cfg_.images;
  d_.description = description(seed);
  placeObstacles();
  if (cfg_.pixel_noise == PixelNoiseModel::PerKind)
    for (const Landmark& l : cfg_.map.landmarks())
      if (!kind_model_.count(l.type)) {
        const Eigen::Matrix4d C = cfg_.kind_noise.of(l.type).covariance();
        kind_model_[l.type] = {C + (q_ / 12.0) * Eigen::Matrix4d::Identity(), C.llt().matrixL()};
      }
}

std::string Simulation::description(uint64_t seed) const {
  char buf[600];
  std::snprintf(buf, sizeof(buf),
                "simulated %s trial %d seed %llu: %s; encoder k %.6g mm^2/mm, compass %s sigma %.6g deg bias %.6g "
                "deg, pixel sigma %.6g px%s, landmarks %s, obstacles %d, head scan %s",
                scenario_name_.c_str(), trial_, static_cast<unsigned long long>(seed), sc_.description.c_str(),
                cfg_.encoder_k, cfg_.compass ? "on" : "off", rad2deg(cfg_.compass_sigma), rad2deg(cfg_.compass_bias),
                cfg_.pixel_sigma, cfg_.quantise ? " quantised" : "", toString(cfg_.landmarks).c_str(), cfg_.obstacles,
                cfg_.scenario.head_scan ? "on" : "off");
  std::string text = buf;
  if (!ideal_) text += ", error profile " + cfg_.profile.name;
  return text;
}

// Obstacles: K robots and a ball at random places away from the robot's start.
void Simulation::placeObstacles() {
  if (cfg_.obstacles <= 0) return;
  if (!cfg_.map.geometry()) throw Error("simulation: obstacles need a map with field geometry");
  const FieldGeometry& g = *cfg_.map.geometry();
  std::uniform_real_distribution<double> ux(100.0, g.length - 100.0), uy(100.0, g.width - 100.0), ua(-kPi, kPi);
  for (int k = 0; k <= cfg_.obstacles; ++k) {
    Obstacle o;
    o.kind = k < cfg_.obstacles ? Obstacle::Kind::Robot : Obstacle::Kind::Ball;
    o.size = o.kind == Obstacle::Kind::Robot ? 75.0 : 42.7;
    do {
      o.position = Eigen::Vector2d(ux(rng_obstacles_), uy(rng_obstacles_));
    } while ((o.position - sc_.poses[0].translation()).norm() < 200.0);
    o.heading = ua(rng_obstacles_);
    obstacles_.push_back(o);
    obstacle_dir_.push_back(o.heading);
  }
}

Dataset Simulation::run(SimulationTrace* trace) {
  if (trace) {
    trace->scenario = sc_;
    trace->obstacles.clear();
    trace->profile = cfg_.profile;
    trace->errors = drawn_;
    trace->nominal_rig = rp_;
  }
  const size_t n = sc_.poses.size();
  const Scene static_scene = true_map_.geometry().has_value() ? Scene::fromMap(true_map_) : Scene();
  d_.steps.resize(n);
  d_.groundtruth.resize(n);
  for (size_t s = 0; s < n; ++s) {
    Step& st = d_.steps[s];
    const Pose2& pose = sc_.poses[s];
    st.step = static_cast<long>(s);
    st.t = static_cast<double>(s) * cfg_.dt;
    st.head_pan = sc_.head_pan[s];
    d_.groundtruth[s] = pose;
    driveWheels(s, &st);
    if (cfg_.compass) {
      st.compass = wrapAngle(pose.theta + cfg_.compass_bias + cfg_.compass_sigma * N_(rng_compass_));
      st.compass_sigma = d_.compass_sigma;
    }
    if (!obstacles_.empty())
      moveObstacles(obstacles_, obstacle_dir_, *cfg_.map.geometry(), pose, cfg_.obstacle_speed, rng_obstacles_);
    if (trace) trace->obstacles.push_back(obstacles_);
    const Scene scene = obstacles_.empty() ? Scene() : Scene::fromMap(true_map_, obstacles_);
    observe(s, obstacles_.empty() ? static_scene : scene, &st);
  }
  return std::move(d_);
}

// Each step's wheel travel on the nominal wheel base, for a wheel drift's walk (empty without one).
std::vector<WheelIncrements> Simulation::scenarioWheelTravel() const {
  if (!(cfg_.profile.wheel_radius_drift > 0 || cfg_.profile.wheel_base_drift > 0)) return {};
  std::vector<WheelIncrements> travel(sc_.poses.size());
  for (size_t s = 1; s < sc_.poses.size(); ++s) {
    if (sc_.carried[s]) continue;
    const Arc arc = arcBetween(sc_.poses[s - 1], sc_.poses[s]);
    travel[s] = wheelIncrementsForArc(arc.length, arc.dtheta, cfg_.wheel_base_mm);
  }
  return travel;
}

// The wheel increments of step s (none on the first step and while the robot is carried).
void Simulation::driveWheels(size_t s, Step* st) {
  if (s == 0 || sc_.carried[s]) return;
  if (!ideal_) {
    // The odometry clock runs `time_offset_s` ahead of the images; the wheels roll the true
    // arc with the true wheel base, and the encoders convert wheel angle with the nominal
    // radius (reading = true distance / (1 + e)); a slipping wheel reads more than it moved.
    const double clock_shift = drawn_.time_offset_s / cfg_.dt;  // steps
    const Arc arc = arcBetween(poseAtStep(sc_, static_cast<double>(s) - 1.0 + clock_shift),
                               poseAtStep(sc_, static_cast<double>(s) + clock_shift));
    const bool drift = !drawn_.wheel_base_drift.empty();
    const double base_rel = drawn_.wheel_base_rel + (drift ? drawn_.wheel_base_drift[s] : 0.0);
    const double radius_left = drawn_.wheel_radius_rel[0] + (drift ? drawn_.wheel_radius_drift_left[s] : 0.0);
    const double radius_right = drawn_.wheel_radius_rel[1] + (drift ? drawn_.wheel_radius_drift_right[s] : 0.0);
    const WheelIncrements w = wheelIncrementsForArc(arc.length, arc.dtheta, cfg_.wheel_base_mm * (1.0 + base_rel));
    const double l = w.d_left / (1.0 + radius_left) * (1.0 + drawn_.slip_left[s]);
    const double r = w.d_right / (1.0 + radius_right) * (1.0 + drawn_.slip_right[s]);
    st->d_left = l + std::sqrt(cfg_.encoder_k * std::fabs(l)) * N_(rng_encoder_);
    st->d_right = r + std::sqrt(cfg_.encoder_k * std::fabs(r)) * N_(rng_encoder_);
  } else {
    const Arc arc = arcBetween(sc_.poses[s - 1], sc_.poses[s]);
    const WheelIncrements w = wheelIncrementsForArc(arc.length, arc.dtheta, cfg_.wheel_base_mm);
    // (B.6): independent wheel errors with variance proportional to the distance travelled.
    st->d_left = w.d_left + std::sqrt(cfg_.encoder_k * std::fabs(w.d_left)) * N_(rng_encoder_);
    st->d_right = w.d_right + std::sqrt(cfg_.encoder_k * std::fabs(w.d_right)) * N_(rng_encoder_);
  }
}

// The noisy pixels of every landmark visible at step s, as observations.
void Simulation::observe(size_t s, const Scene& world, Step* st) {
  const Pose2& pose = sc_.poses[s];
  const StereoRig true_rig(trueRigParams(nominal_.params(), drawn_, s));
  for (const VisibleLandmark& v : visibleLandmarks(true_map_, d_.rig, world, pose, st->head_pan, cfg_.landmarks)) {
    const Landmark& landmark = true_map_.at(v.id);
    StereoPixels px = v.pixels;
    if (!ideal_) {
      const Eigen::Vector2d local = transformToLocal(pose, landmark.xy());
      const auto raw = trueRawPixels(true_rig, drawn_, s, Eigen::Vector3d(local.x(), local.y(), landmark.position.z()),
                                     st->head_pan, nominal_);
      if (!raw) continue;
      px = *raw;
    }
    const auto kind = kind_model_.find(landmark.type);
    if (kind != kind_model_.end()) {
      Eigen::Vector4d white;
      for (int i = 0; i < 4; ++i) white(i) = N_(rng_pixels_);
      const Eigen::Vector4d e = kind->second.second * white;
      px.u_left += e(0);
      px.v_left += e(1);
      px.u_right += e(2);
      px.v_right += e(3);
      if (cfg_.quantise)
        for (double* c : {&px.u_left, &px.v_left, &px.u_right, &px.v_right}) *c = std::round(*c);
    } else {
      for (double* c : {&px.u_left, &px.v_left, &px.u_right, &px.v_right}) {
        *c += cfg_.pixel_sigma * N_(rng_pixels_);
        if (cfg_.quantise) *c = std::round(*c);
      }
    }
    if (!ideal_ && !rectifyPixels(*d_.rig.calibration(), px)) continue;
    // A detector cannot triangulate what the noise pushed below the minimum disparity.
    if (!(px.disparity() >= d_.rig.params().min_disparity_px)) continue;
    if (kind != kind_model_.end())
      st->observations.push_back(observationFromPixels(d_.rig, v.id, landmark.type, px, st->head_pan, kind->second.first));
    else
      st->observations.push_back(
          observationFromPixels(d_.rig, v.id, landmark.type, px, st->head_pan, d_.rig.params().pixel_sigma));
  }
}

}  // namespace

Dataset simulate(const std::string& scenario_name, int trial, const SimulationConfig& cfg, uint64_t seed,
                 SimulationTrace* trace) {
  cfg.validate();
  return Simulation(scenario_name, trial, cfg, seed).run(trace);
}

}  // namespace stereoloc
