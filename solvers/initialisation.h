#pragma once
// How a tracker (EKF, particle filter, sliding window) obtains its first belief, thesis
// section 6.5 and 5.1.4:
//   known  - the true pose plus noise, with a small covariance ("initialized manually");
//   random - a random pose with a huge covariance approximating a uniform belief (5.1.4);
//   global - no belief until the first global fix (chapter 4); status Uninitialised until then.
// Also the hook through which trackers ask for a global fix when initialising or when lost.
#include <Eigen/Core>
#include <functional>
#include <optional>
#include <random>
#include <string>

#include "solvers/global_fix.h"
#include "src/core/field_map.h"
#include "src/core/pose2.h"
#include "src/core/types.h"

namespace stereoloc {

enum class InitMode { Known, Random, Global };
std::string toString(InitMode mode);            // "known", "random", "global"
InitMode initModeFromString(const std::string& name);  // throws stereoloc::Error

struct InitConfig {
  // Known: standard deviation of the noise added to the true pose, and sqrt of the diagonal of
  // P0 (mm, mm, rad). The thesis states only "low uncertainty" (section 6.5).
  Eigen::Vector3d known_sigma = Eigen::Vector3d(30.0, 30.0, deg2rad(5.0));
  // Random: sqrt of the diagonal of P0 (mm, mm, rad), "a very high uncertainty" (5.1.4). The
  // field is 1500 x 1300 mm, so 1000 mm covers it; pi rad makes the heading prior flat.
  Eigen::Vector3d random_sigma = Eigen::Vector3d(1000.0, 1000.0, kPi);
};

// The belief a tracker starts from. For Global the pose and covariance are unused.
struct InitialBelief {
  InitMode mode = InitMode::Global;
  Pose2 pose;                                            // mm, rad
  Eigen::Matrix3d covariance = Eigen::Matrix3d::Zero();  // (x, y, theta): mm^2, mm*rad, rad^2
};

// Known start from an exact pose and covariance (no noise added).
InitialBelief knownBelief(const Pose2& pose, const Eigen::Matrix3d& covariance);
// Known start as in section 6.5: truth + N(0, diag(known_sigma^2)), P0 = diag(known_sigma^2).
InitialBelief knownBeliefWithNoise(const Pose2& truth, const InitConfig& config, std::mt19937_64& rng);
// Random start: position uniform in the map bounds, heading uniform in [-pi, pi),
// P0 = diag(random_sigma^2). (The particle filter ignores the pose and spreads its particles
// uniformly; a Gaussian cannot represent that.)
InitialBelief randomBelief(const Bounds& bounds, const InitConfig& config, std::mt19937_64& rng);
InitialBelief globalBelief();
// Dispatches on the mode; `truth` is required for Known (throws stereoloc::Error otherwise).
InitialBelief makeInitialBelief(InitMode mode, const std::optional<Pose2>& truth, const FieldMap& map,
                                const InitConfig& config, std::mt19937_64& rng);

// A pose with its covariance, as a global fix delivers it.
struct PoseFix {
  Pose2 pose;
  Eigen::Matrix3d covariance = Eigen::Matrix3d::Identity();
};

// The global localisation service the trackers call when uninitialised or lost: returns a fix
// from one step's observations (and compass), or nullopt when none is possible.
using GlobalFixFunction = std::function<std::optional<PoseFix>(const Step& step, const FieldMap& map)>;

// The thesis's global fixes (solvers/global_fix.h, chapter 4: globalFix on the step's
// identified observations and compass). Fixes with status Ok are accepted, and with
// accept_approximate also ApproximateNoIntersection (range circles that miss by noise, still
// within max_gap_sigma); Ambiguous, Degenerate and NotEnoughLandmarks never.
// A fix whose position lies outside the map's bounds is refused: the robot is in the field.
GlobalFixFunction defaultGlobalFix(const GlobalFixOptions& options = trackerFixOptions(),
                                   bool accept_approximate = true);

}  // namespace stereoloc
