#pragma once
// Angles: the ONE wrap function of stereoloc, plus degree helpers for human-facing text.
// All code and files use radians; degrees appear only in printed text.
#include <cmath>
#include <type_traits>

#include "src/core/error.h"

namespace stereoloc {

constexpr double kPi = 3.14159265358979323846;
constexpr double kTwoPi = 2.0 * kPi;

constexpr double deg2rad(double deg) { return deg * kPi / 180.0; }
constexpr double rad2deg(double rad) { return rad * 180.0 / kPi; }

// Wraps an angle to [-pi, pi). Works for double and for ceres::Jet (the derivative passes
// through unchanged, since wrapping only subtracts a constant multiple of 2*pi).
// A non-finite double is rejected with stereoloc::Error: a NaN angle is always a bug upstream.
template <typename T>
T wrapAngle(const T& angle) {
  using std::floor;
  if constexpr (std::is_floating_point_v<T>) {
    if (!std::isfinite(angle)) throw Error("wrapAngle: angle is not finite");
    if (angle >= -kPi && angle < kPi) return angle;
    // std::remainder is exact, so large multiples of 2*pi keep full precision.
    T r = std::remainder(angle, T(kTwoPi));
    if (r >= T(kPi)) r -= T(kTwoPi);
    if (r < T(-kPi)) r += T(kTwoPi);
    return r;
  } else {
    T r = angle - T(kTwoPi) * floor((angle + T(kPi)) / T(kTwoPi));
    if (r >= T(kPi)) r -= T(kTwoPi);
    if (r < T(-kPi)) r += T(kTwoPi);
    return r;
  }
}

// Signed smallest difference a - b, wrapped.
template <typename T>
T angleDiff(const T& a, const T& b) {
  return wrapAngle<T>(a - b);
}

}  // namespace stereoloc
