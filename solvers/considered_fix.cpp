#include "solvers/considered_fix.h"

#include <Eigen/Eigenvalues>
#include <cmath>
#include <optional>
#include <vector>

#include "solvers/calibrated_models.h"
#include "src/core/angles.h"
#include "src/core/error.h"

namespace stereoloc {

namespace {

// Whether the fix reads this sighting through the stereo calibration.
bool seenThroughCalibration(const Observation& o) { return o.pixels.has_value() && o.landmark_id >= 0; }

// The step's identified stereo sightings as the cameras of calibration q see them: each one's
// range and bearing moved by what q changes in them from z0 (the rig's own triangulation at the
// nominal q, one per such sighting in order), its covariance kept. Nullopt when a sighting cannot
// be triangulated through q.
std::optional<Step> seenThrough(const Step& step, const std::vector<Eigen::Vector2d>& z0, const StereoRig& rig,
                                const CalibrationEstimate::StereoVector& q) {
  Step out = step;
  size_t k = 0;
  try {
    for (Observation& o : out.observations) {
      if (!seenThroughCalibration(o)) continue;
      const Eigen::Vector2d z = calibratedRangeBearing(o, rig, q).z;
      o.range += z[0] - z0[k][0];
      o.bearing = wrapAngle(o.bearing + wrapAngle(z[1] - z0[k][1]));
      ++k;
    }
  } catch (const GeometryError&) {
    return std::nullopt;
  }
  return out;
}

// The fix through calibration q when it is the same fix (method and landmarks) as `fix`.
std::optional<Eigen::Vector3d> sameFixThrough(const GlobalFix& fix, const Step& step,
                                              const std::vector<Eigen::Vector2d>& z0, const FieldMap& map,
                                              const GlobalFixOptions& options, const StereoRig& rig,
                                              const CalibrationEstimate::StereoVector& q) {
  const std::optional<Step> seen = seenThrough(step, z0, rig, q);
  if (!seen) return std::nullopt;
  const GlobalFix moved = globalFix(*seen, map, options);
  if (!moved.hasPose() || moved.method != fix.method || moved.landmark_ids != fix.landmark_ids)
    return std::nullopt;
  return Eigen::Vector3d(moved.pose.x, moved.pose.y, moved.pose.theta);
}

}  // namespace

GlobalFix considerStereoCalibration(const GlobalFix& fix, const Step& step, const FieldMap& map,
                                    const GlobalFixOptions& options, const StereoRig& rig,
                                    const CalibrationEstimate::StereoMatrix& Cq) {
  if (!Cq.allFinite() || Cq.diagonal().minCoeff() < 0)
    throw Error("considered fix: the calibration's covariance must be finite with a diagonal >= 0");
  if (!fix.hasPose() || Cq.isZero(0.0)) return fix;
  const CalibrationEstimate::StereoVector nominal = CalibrationEstimate{}.head;
  const Eigen::Vector3d at(fix.pose.x, fix.pose.y, fix.pose.theta);
  std::vector<Eigen::Vector2d> z0;
  try {
    for (const Observation& o : step.observations)
      if (seenThroughCalibration(o)) z0.push_back(calibratedRangeBearing(o, rig, nominal).z);
  } catch (const GeometryError&) {  // not triangulated at the given calibration: no fix to move
    GlobalFix out = fix;
    out.status = FixStatus::Degenerate;
    return out;
  }
  // Sigma points at +-sqrt(3) sigma along the principal axes of Cq; the mean squared change of
  // the fix about it, as the fix's own covariance is taken (FixCovariance::SigmaPoints).
  const Eigen::SelfAdjointEigenSolver<CalibrationEstimate::StereoMatrix> axes(0.5 * (Cq + Cq.transpose()));
  Eigen::Matrix3d added = Eigen::Matrix3d::Zero();
  for (int j = 0; j < 6; ++j) {
    if (!(axes.eigenvalues()[j] > 0)) continue;
    const CalibrationEstimate::StereoVector axis = std::sqrt(axes.eigenvalues()[j]) * axes.eigenvectors().col(j);
    bool done = false;
    for (const double h : {std::sqrt(3.0), 0.1}) {
      Eigen::Vector3d d[2];
      bool ok = true;
      for (int side = 0; side < 2 && ok; ++side) {
        const std::optional<Eigen::Vector3d> moved =
            sameFixThrough(fix, step, z0, map, options, rig, nominal + (side == 0 ? h : -h) * axis);
        ok = moved.has_value();
        if (ok) {
          d[side] = (*moved - at) / h;  // per sigma along the axis
          d[side][2] = wrapAngle(moved->z() - at.z()) / h;
        }
      }
      if (!ok) continue;
      // The Gauss-Hermite rule of degree 5: weights 1/6 on the changes at +-sqrt(3) sigma, which
      // is 1/2 on the changes per sigma; at a tenth of sigma, the linearisation's 1/2.
      added += 0.5 * (d[0] * d[0].transpose() + d[1] * d[1].transpose());
      done = true;
      break;
    }
    if (!done) {
      GlobalFix out = fix;
      out.status = FixStatus::Degenerate;
      return out;
    }
  }
  GlobalFix out = fix;
  out.covariance = fix.covariance + added;
  out.covariance = 0.5 * (out.covariance + out.covariance.transpose());
  return out;
}

}  // namespace stereoloc
