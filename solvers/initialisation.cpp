#include "solvers/initialisation.h"

#include <cmath>

#include "src/core/error.h"

namespace stereoloc {

std::string toString(InitMode mode) {
  switch (mode) {
    case InitMode::Known: return "known";
    case InitMode::Random: return "random";
    case InitMode::Global: return "global";
  }
  return "global";
}

InitMode initModeFromString(const std::string& name) {
  for (InitMode m : {InitMode::Known, InitMode::Random, InitMode::Global})
    if (toString(m) == name) return m;
  throw Error("unknown init mode '" + name + "' (expected known, random or global)");
}

namespace {

void checkSigma(const Eigen::Vector3d& sigma, const char* field) {
  if (!sigma.allFinite() || !(sigma.array() > 0).all())
    throw Error(std::string("init: ") + field + " must be positive and finite");
}

Eigen::Matrix3d diagonalCovariance(const Eigen::Vector3d& sigma) {
  return sigma.cwiseProduct(sigma).asDiagonal();
}

}  // namespace

InitialBelief knownBelief(const Pose2& pose, const Eigen::Matrix3d& covariance) {
  if (!pose.isFinite()) throw Error("init: known pose is not finite");
  if (!covariance.allFinite()) throw Error("init: known covariance is not finite");
  return InitialBelief{InitMode::Known, pose, 0.5 * (covariance + covariance.transpose())};
}

InitialBelief knownBeliefWithNoise(const Pose2& truth, const InitConfig& config, std::mt19937_64& rng) {
  checkSigma(config.known_sigma, "known_sigma");
  std::normal_distribution<double> n01(0.0, 1.0);
  const double ex = n01(rng), ey = n01(rng), et = n01(rng);
  const Eigen::Vector3d noise(config.known_sigma.x() * ex, config.known_sigma.y() * ey, config.known_sigma.z() * et);
  return knownBelief(plus(truth, noise), diagonalCovariance(config.known_sigma));
}

InitialBelief randomBelief(const Bounds& bounds, const InitConfig& config, std::mt19937_64& rng) {
  checkSigma(config.random_sigma, "random_sigma");
  if (!(bounds.xmax > bounds.xmin && bounds.ymax > bounds.ymin)) throw Error("init: map bounds are empty");
  std::uniform_real_distribution<double> ux(bounds.xmin, bounds.xmax), uy(bounds.ymin, bounds.ymax), ut(-kPi, kPi);
  const double x = ux(rng), y = uy(rng), t = ut(rng);
  return InitialBelief{InitMode::Random, Pose2(x, y, t), diagonalCovariance(config.random_sigma)};
}

InitialBelief globalBelief() { return InitialBelief{}; }

InitialBelief makeInitialBelief(InitMode mode, const std::optional<Pose2>& truth, const FieldMap& map,
                                const InitConfig& config, std::mt19937_64& rng) {
  switch (mode) {
    case InitMode::Known:
      if (!truth) throw Error("init: mode 'known' needs the true initial pose (the dataset has none)");
      return knownBeliefWithNoise(*truth, config, rng);
    case InitMode::Random: return randomBelief(map.bounds(), config, rng);
    case InitMode::Global: return globalBelief();
  }
  return globalBelief();
}

GlobalFixFunction defaultGlobalFix(const GlobalFixOptions& options, bool accept_approximate) {
  return [options, accept_approximate](const Step& step, const FieldMap& map) -> std::optional<PoseFix> {
    const GlobalFix fix = globalFix(step, map, options);
    const bool usable =
        fix.status == FixStatus::Ok || (accept_approximate && fix.status == FixStatus::ApproximateNoIntersection);
    if (!usable || !fix.pose.isFinite() || !fix.covariance.allFinite()) return std::nullopt;
    // The robot is inside the field: a fix outside it rests on a grossly wrong observation (e.g.
    // the range of a distant landmark from a miscalibrated disparity) and would mislead the
    // tracker it re-initialises; the next step's observations get another chance.
    const Bounds& b = map.bounds();
    if (fix.pose.x < b.xmin || fix.pose.x > b.xmax || fix.pose.y < b.ymin || fix.pose.y > b.ymax) return std::nullopt;
    return PoseFix{fix.pose, fix.covariance};
  };
}

}  // namespace stereoloc
