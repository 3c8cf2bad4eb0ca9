#include <gtest/gtest.h>

#include <cmath>
#include <map>

#include "frontend/stereo_match.h"

#include "src/core/error.h"
#include "src/core/measurement_model.h"
#include "src/core/odometry_model.h"
#include "src/sim/simulator.h"

namespace stereoloc {
namespace {

SimulationConfig noiseFree() {
  SimulationConfig c;
  c.encoder_k = 0;
  c.compass_sigma = 0;
  c.pixel_sigma = 0;
  return c;
}

size_t stepsWithObservations(const Dataset& d) {
  size_t n = 0;
  for (const Step& s : d.steps) n += s.observations.empty() ? 0 : 1;
  return n;
}

TEST(Simulator, SameSeedSameDatasetOtherSeedDiffers) {
  SimulationConfig cfg;
  cfg.obstacles = 2;
  const Dataset a = simulate("circle", 0, cfg, 42), b = simulate("circle", 0, cfg, 42), c = simulate("circle", 0, cfg, 43);
  ASSERT_EQ(a.steps.size(), b.steps.size());
  bool differs = false;
  for (size_t i = 0; i < a.steps.size(); ++i) {
    EXPECT_EQ(a.steps[i].d_left, b.steps[i].d_left);
    EXPECT_EQ(a.steps[i].d_right, b.steps[i].d_right);
    EXPECT_EQ(*a.steps[i].compass, *b.steps[i].compass);
    ASSERT_EQ(a.steps[i].observations.size(), b.steps[i].observations.size());
    for (size_t k = 0; k < a.steps[i].observations.size(); ++k)
      EXPECT_EQ(a.steps[i].observations[k].z(), b.steps[i].observations[k].z());
    differs |= a.steps[i].d_left != c.steps[i].d_left;
  }
  EXPECT_TRUE(differs);
}

TEST(Simulator, NoiseFreeOdometryReproducesTheGroundTruth) {
  for (const char* name : {"circle", "line", "spin", "kidnap"}) {
    const Dataset d = simulate(name, 0, noiseFree(), 1);
    ASSERT_TRUE(d.initial_pose);
    Pose2 p = *d.initial_pose;
    EXPECT_EQ(d.steps[0].d_left, 0.0);
    for (size_t s = 1; s < d.steps.size(); ++s) {
      if (std::string(name) == "kidnap" && s == 100) {
        EXPECT_EQ(d.steps[s].d_left, 0.0);  // carried: the wheels did not turn
        EXPECT_EQ(d.steps[s].d_right, 0.0);
        p = *d.groundtruth[s];
        continue;
      }
      p = predictPose(p, Eigen::Matrix3d::Zero(), d.steps[s].d_left, d.steps[s].d_right, d.odometry).pose;
      EXPECT_LT((p.translation() - d.groundtruth[s]->translation()).norm(), 1e-6) << name << " " << s;
      EXPECT_NEAR(angleDiff(p.theta, d.groundtruth[s]->theta), 0, 1e-9);
    }
  }
}

TEST(Simulator, EncoderNoiseHasVarianceKTimesDistance) {
  SimulationConfig cfg = noiseFree();
  cfg.encoder_k = 0.05;
  cfg.scenario.steps = 4000;
  const Dataset d = simulate("random-walk", 0, cfg, 3);
  const Dataset exact = simulate("random-walk", 0, [] {
    SimulationConfig c = noiseFree();
    c.scenario.steps = 4000;
    return c;
  }(), 3);
  double sum2 = 0;
  size_t n = 0;
  for (size_t s = 1; s < d.steps.size(); ++s) {
    for (auto [m, t] : {std::pair{d.steps[s].d_left, exact.steps[s].d_left}, std::pair{d.steps[s].d_right, exact.steps[s].d_right}}) {
      const double z = (m - t) / std::sqrt(0.05 * std::fabs(t));
      sum2 += z * z;
      ++n;
    }
  }
  EXPECT_NEAR(sum2 / n, 1.0, 0.05);
  EXPECT_EQ(d.odometry.k_left, 0.05);
  EXPECT_EQ(d.odometry.k_right, 0.05);
}

TEST(Simulator, CompassNoiseAndBias) {
  SimulationConfig cfg;
  cfg.scenario.steps = 4000;
  cfg.compass_bias = deg2rad(2.0);
  const Dataset d = simulate("random-walk", 0, cfg, 5);
  double sum = 0, sum2 = 0;
  for (size_t s = 0; s < d.steps.size(); ++s) {
    ASSERT_TRUE(d.steps[s].compass);
    const double e = angleDiff(*d.steps[s].compass, d.groundtruth[s]->theta);
    sum += e;
    sum2 += e * e;
    EXPECT_EQ(d.steps[s].compass_sigma, deg2rad(3.5));
  }
  const double mean = sum / d.steps.size(), sd = std::sqrt(sum2 / d.steps.size() - mean * mean);
  EXPECT_NEAR(mean, deg2rad(2.0), deg2rad(0.2));
  EXPECT_NEAR(sd, deg2rad(3.5), deg2rad(0.15));
  EXPECT_EQ(d.compass_sigma, deg2rad(3.5));
  cfg.compass = false;
  cfg.scenario.steps = 10;
  const Dataset none = simulate("random-walk", 0, cfg, 5);
  EXPECT_EQ(none.compass_sigma, 0.0);
  EXPECT_FALSE(none.steps[3].compass);
}

TEST(Simulator, NoiseFreeObservationsMatchTheMeasurementModel) {
  for (const char* name : {"circle", "line", "spin"}) {
    SimulationConfig cfg = noiseFree();
    cfg.landmarks = LandmarkSet::All;
    const Dataset d = simulate(name, 0, cfg, 1);
    size_t count = 0;
    for (size_t s = 0; s < d.steps.size(); ++s)
      for (const Observation& o : d.steps[s].observations) {
        const Eigen::Vector2d z = predictRangeBearing(*d.groundtruth[s], d.map.at(o.landmark_id).xy());
        EXPECT_NEAR(o.range, z.x(), 1e-6 * z.x());
        EXPECT_NEAR(angleDiff(o.bearing, z.y()), 0, 1e-9);
        EXPECT_EQ(o.type, d.map.at(o.landmark_id).type);
        EXPECT_GT(o.covariance(0, 0), 0);
        ++count;
      }
    EXPECT_GT(count, 20u) << name;
  }
}

TEST(Simulator, PixelNoiseAndQuantisation) {
  SimulationConfig cfg;
  cfg.landmarks = LandmarkSet::All;
  cfg.quantise = true;
  const Dataset d = simulate("circle", 0, cfg, 9);
  size_t count = 0;
  for (const Step& s : d.steps)
    for (const Observation& o : s.observations) {
      ASSERT_TRUE(o.pixels);
      EXPECT_EQ(o.pixels->u_left, std::round(o.pixels->u_left));
      EXPECT_EQ(o.pixels->v_right, std::round(o.pixels->v_right));
      ++count;
    }
  EXPECT_GT(count, 0u);
  EXPECT_NEAR(d.rig.params().pixel_sigma, std::sqrt(0.25 + 1.0 / 12.0), 1e-12);
}

TEST(Simulator, PerKindPixelNoiseHasTheModelsCovariance) {
  // Monte Carlo: the drawn pixel errors (noisy minus exact, matched by step and landmark) of each
  // landmark kind have the sample covariance of its (u, v, d) model, correlations included.
  SimulationConfig noisy = noiseFree();
  noisy.landmarks = LandmarkSet::All;
  noisy.pixel_noise = PixelNoiseModel::PerKind;
  noisy.scenario.steps = 1500;
  SimulationConfig exact = noisy;
  exact.pixel_noise = PixelNoiseModel::Independent;
  const Dataset a = simulate("random-walk", 0, noisy, 5), b = simulate("random-walk", 0, exact, 5);
  const Dataset again = simulate("random-walk", 0, noisy, 5);
  std::map<LandmarkType, Eigen::Matrix4d> second;
  std::map<LandmarkType, long> n;
  for (size_t s = 0; s < a.steps.size(); ++s) {
    ASSERT_EQ(a.steps[s].observations.size(), again.steps[s].observations.size());
    for (size_t k = 0; k < a.steps[s].observations.size(); ++k) {
      const Observation& o = a.steps[s].observations[k];
      EXPECT_EQ(o.z(), again.steps[s].observations[k].z());  // deterministic per seed
      EXPECT_EQ(o.pixel_covariance, noisy.kind_noise.of(o.type).covariance());
      for (const Observation& t : b.steps[s].observations) {
        if (t.landmark_id != o.landmark_id) continue;
        const Eigen::Vector4d e(o.pixels->u_left - t.pixels->u_left, o.pixels->v_left - t.pixels->v_left,
                                o.pixels->u_right - t.pixels->u_right, o.pixels->v_right - t.pixels->v_right);
        second.try_emplace(o.type, Eigen::Matrix4d::Zero()).first->second += e * e.transpose();
        ++n[o.type];
      }
    }
  }
  ASSERT_GE(n.size(), 3u);
  for (const auto& [type, count] : n) {
    ASSERT_GT(count, 200) << toString(type);
    const Eigen::Matrix4d S = second.at(type) / static_cast<double>(count);
    const Eigen::Matrix4d C = noisy.kind_noise.of(type).covariance();
    for (int i = 0; i < 4; ++i)
      for (int j = 0; j < 4; ++j) {
        // Standard error of a sample covariance entry of a Gaussian: sqrt((C_ii C_jj + C_ij^2) / n).
        const double se = std::sqrt((C(i, i) * C(j, j) + C(i, j) * C(i, j)) / static_cast<double>(count));
        EXPECT_NEAR(S(i, j), C(i, j), 4.5 * se) << toString(type) << " (" << i << ", " << j << ")";
      }
    // The marking features' left and right columns are strongly correlated in the model (0.5-0.7;
    // a goal corner's nearly not), which independent noise would miss.
    if (type != LandmarkType::GoalCorner) {
      EXPECT_GT(S(0, 2) / std::sqrt(S(0, 0) * S(2, 2)), 0.4) << toString(type);
    }
  }
}

TEST(Simulator, PerKindDefaultsAreTheFrontendModel) {
  const KindPixelNoise sim;
  const frontend::StereoParams fe;
  for (LandmarkType t : {LandmarkType::MarkingCorner, LandmarkType::Junction, LandmarkType::Intersection, LandmarkType::GoalCorner}) {
    EXPECT_EQ(sim.of(t).sigma_u, fe.noise(t).sigma_u) << toString(t);
    EXPECT_EQ(sim.of(t).sigma_v, fe.noise(t).sigma_v) << toString(t);
    EXPECT_EQ(sim.of(t).sigma_d, fe.noise(t).sigma_d) << toString(t);
    EXPECT_EQ(sim.of(t).corr_ud, fe.noise(t).corr_ud) << toString(t);
  }
  EXPECT_EQ(pixelNoiseModelFromString(toString(PixelNoiseModel::PerKind)), PixelNoiseModel::PerKind);
  EXPECT_EQ(pixelNoiseModelFromString("independent"), PixelNoiseModel::Independent);
  EXPECT_THROW(pixelNoiseModelFromString("perkind"), Error);
  SimulationConfig bad;
  bad.pixel_noise = PixelNoiseModel::PerKind;
  bad.kind_noise.junction.corr_ud = 1.0;
  EXPECT_THROW(bad.validate(), Error);
}

TEST(Simulator, VisibilityRespectsFieldOfViewRangeAndOcclusion) {
  const FieldMap map = FieldMap::miroSot();
  const StereoRig rig;
  const Scene scene = Scene::fromMap(map);
  // At (400, 650) facing the blue goal, both blue goal corners are visible, none of the yellow.
  const Pose2 pose(400, 650, kPi);
  auto ids = [&](const Scene& sc, const StereoRig& r) {
    std::vector<int> out;
    for (const auto& v : visibleLandmarks(map, r, sc, pose, 0.0, LandmarkSet::GoalCorners)) out.push_back(v.id);
    return out;
  };
  EXPECT_EQ(ids(scene, rig), (std::vector<int>{0, 2}));
  // Turned around it sees the yellow goal instead; with the head panned by 180 deg the blue one.
  auto idsAt = [&](const Pose2& p, double pan) {
    std::vector<int> out;
    for (const auto& v : visibleLandmarks(map, rig, scene, p, pan, LandmarkSet::GoalCorners)) out.push_back(v.id);
    return out;
  };
  EXPECT_EQ(idsAt(Pose2(400, 650, 0), 0.0), (std::vector<int>{1, 3}));
  EXPECT_EQ(idsAt(Pose2(400, 650, 0), kPi), (std::vector<int>{0, 2}));
  // Facing a side wall: nothing.
  EXPECT_TRUE(idsAt(Pose2(400, 650, kPi / 2), 0.0).empty());
  // Out of range.
  StereoRigParams p;
  p.max_range_mm = 300;
  EXPECT_TRUE(ids(scene, StereoRig(p)).empty());
  // A robot standing between the camera and the corner at (0, 450) hides it.
  Obstacle o;
  o.position = Eigen::Vector2d(200, 550);
  const Scene blocked = Scene::fromMap(map, {o});
  EXPECT_EQ(ids(blocked, rig), (std::vector<int>{2}));
  // A ball hides it too.
  o.kind = Obstacle::Kind::Ball;
  o.size = 42.7;
  o.position = Eigen::Vector2d(100, 500);
  EXPECT_EQ(ids(Scene::fromMap(map, {o}), rig), (std::vector<int>{2}));
}

TEST(Simulator, CornerTrianglesOccludeWallCorners) {
  const FieldMap map = FieldMap::miroSot();
  const Scene scene = Scene::fromMap(map);
  // Wall corner (70, 0) seen from along the wall behind the triangle at (0, 0): blocked by the
  // triangle's solid prism; from the field it is visible.
  const Eigen::Vector3d lm = map.at(24).position;  // wall_corner_x70_y0
  ASSERT_EQ(map.at(24).type, LandmarkType::WallCorner);
  ASSERT_NEAR(lm.x(), 70, 1e-9);
  EXPECT_TRUE(scene.occluded(Eigen::Vector3d(-100, 5, 20), lm));
  EXPECT_FALSE(scene.occluded(Eigen::Vector3d(400, 500, 70), lm));
}

TEST(Simulator, ObstaclesOccludeSomeObservations) {
  SimulationConfig cfg;
  cfg.landmarks = LandmarkSet::All;
  size_t with = 0, without = 0;
  for (uint64_t seed = 1; seed <= 3; ++seed) {
    without += stepsWithObservations(simulate("circle", 0, cfg, seed));
    SimulationTrace trace;
    SimulationConfig c2 = cfg;
    c2.obstacles = 6;
    const Dataset d = simulate("circle", 0, c2, seed, &trace);
    ASSERT_EQ(trace.obstacles.size(), d.steps.size());
    ASSERT_EQ(trace.obstacles[0].size(), 7u);  // six robots and the ball
    for (size_t s = 0; s < d.steps.size(); ++s)
      for (const Obstacle& o : trace.obstacles[s])
        EXPECT_GT((o.position - d.groundtruth[s]->translation()).norm(), 0.5 * o.size + 79.0);
    size_t obs_with = 0, obs_without = 0;
    for (const Step& s : d.steps) obs_with += s.observations.size();
    for (const Step& s : simulate("circle", 0, cfg, seed).steps) obs_without += s.observations.size();
    EXPECT_LE(obs_with, obs_without);
    with += obs_with;
  }
  EXPECT_GT(without, 0u);
  EXPECT_GT(with, 0u);
}

TEST(Simulator, ThesisScenarioVisibilityIsPlausible) {
  // Circle (L2315): landmarks seen only in part of the steps; line (L2329): almost always.
  const Dataset circle = simulate("circle", 0, SimulationConfig(), 1);
  const size_t c = stepsWithObservations(circle);
  EXPECT_GT(c, 15u);
  EXPECT_LT(c, 70u);
  EXPECT_TRUE(circle.steps[0].observations.empty());
  // Line (L2329): a landmark in 99 of 100 steps; spin (L2330): in 44 steps (29-72), two in 15.
  // With the default rig (60 deg field of view) we get 98 and 49 (two in 15).
  EXPECT_GE(stepsWithObservations(simulate("line", 0, SimulationConfig(), 1)), 95u);
  const Dataset spin = simulate("spin", 0, SimulationConfig(), 1);
  const size_t sp = stepsWithObservations(spin);
  EXPECT_GE(sp, 40u);
  EXPECT_LE(sp, 55u);
  size_t two = 0;
  for (const Step& st : spin.steps) two += st.observations.size() >= 2 ? 1 : 0;
  EXPECT_GE(two, 10u);
  EXPECT_LE(two, 20u);
  // Global-fix scenarios produce datasets too.
  const Dataset r = simulate("rect-spin", 0, SimulationConfig(), 1);
  EXPECT_EQ(r.steps.size(), 100u);
  EXPECT_GT(stepsWithObservations(r), 0u);
}

TEST(Simulator, RejectsBadConfig) {
  SimulationConfig cfg;
  cfg.encoder_k = -1;
  EXPECT_THROW(simulate("circle", 0, cfg, 1), Error);
  cfg = SimulationConfig();
  cfg.pixel_sigma = std::nan("");
  EXPECT_THROW(simulate("circle", 0, cfg, 1), Error);
  EXPECT_THROW(simulate("nope", 0, SimulationConfig(), 1), Error);
}

TEST(Simulator, LandmarkSetNames) {
  EXPECT_EQ(landmarkSetFromString(toString(LandmarkSet::All)), LandmarkSet::All);
  EXPECT_EQ(landmarkSetFromString(toString(LandmarkSet::GoalCorners)), LandmarkSet::GoalCorners);
  EXPECT_THROW(landmarkSetFromString("some"), Error);
  EXPECT_EQ(obstacleKindFromString(toString(Obstacle::Kind::Ball)), Obstacle::Kind::Ball);
  EXPECT_EQ(obstacleKindFromString(toString(Obstacle::Kind::Robot)), Obstacle::Kind::Robot);
  EXPECT_THROW(obstacleKindFromString("cat"), Error);
}

}  // namespace
}  // namespace stereoloc
