// `stereoloc selfcheck`: prints the default map and rig, and checks the models numerically
// (projection round trip, Jacobians against central differences). Exit 1 if a check fails.
#include <cstdio>
#include <iostream>
#include <map>
#include <random>

#include "src/core/field_map.h"
#include "src/core/measurement_model.h"
#include "src/core/numeric_diff.h"
#include "src/core/odometry_model.h"
#include "solvers/self_calibration.h"
#include "src/core/stereo_rig.h"
#include "tools/stereoloc/cli_common.h"

namespace stereoloc::cli {
namespace {

struct SelfcheckOptions {
  std::string map_path, rig_path;
  unsigned seed = 1;
  int samples = 1000;
};

bool report(const char* what, double value, double limit, const char* unit) {
  const bool ok = value <= limit;
  std::printf("  %-52s %10.3g %-3s (limit %.0e) %s\n", what, value, unit, limit, ok ? "ok" : "FAILED");
  return ok;
}

// What a rig written by --calibration-out hands to a run (`--rig`).
void printHandover(const CalibrationHandover& h) {
  if (h.wheels)
    std::printf("hands over: wheel scales %.5f +- %.5f, %.5f +- %.5f, wheel base %.2f +- %.2f mm\n", (*h.wheels)[0],
                (*h.wheel_sigmas)[0], (*h.wheels)[1], (*h.wheel_sigmas)[1], (*h.wheels)[2], (*h.wheel_sigmas)[2]);
  if (h.head_sigmas) {
    const CalibrationEstimate::StereoVector& s = *h.head_sigmas;
    std::printf("hands over: head priors tilt %.3f deg, baseline scale %.5f, disparity offset %.2f px, column offset "
                "%.2f px, focal ratio %.5f, focal scale %.5f\n",
                rad2deg(s[0]), s[1], s[2], s[3], s[4], s[5]);
  }
  if (h.row_offset_sigma_px) std::printf("hands over: row offset prior %.2f px\n", *h.row_offset_sigma_px);
  if (h.exposure_offset_sigma_s)
    std::printf("hands over: exposure offset prior %.2f ms\n", 1e3 * *h.exposure_offset_sigma_s);
  if (h.odometry_delay_s) {
    if (h.odometry_delay_sigma_s > 0)
      std::printf("hands over: odometry delay %.3f +- %.3f s\n", *h.odometry_delay_s, h.odometry_delay_sigma_s);
    else
      std::printf("hands over: odometry delay %.3f s\n", *h.odometry_delay_s);
  }
}

void runSelfcheck(const SelfcheckOptions& o) {
  const FieldMap map = o.map_path.empty() ? FieldMap::miroSot() : FieldMap::load(o.map_path);
  const StereoRig rig = o.rig_path.empty() ? StereoRig() : StereoRig::load(o.rig_path);
  std::printf("map: %s, %zu landmarks, bounds x [%.0f, %.0f] y [%.0f, %.0f] mm\n", map.name().c_str(),
              map.landmarks().size(), map.bounds().xmin, map.bounds().xmax, map.bounds().ymin, map.bounds().ymax);
  std::map<std::string, std::pair<int, int>> per_type;
  for (const Landmark& l : map.landmarks()) {
    auto& c = per_type[toString(l.type)];
    ++c.first;
    c.second += l.unique ? 1 : 0;
  }
  for (const auto& [type, c] : per_type) std::printf("  %-14s %3d (%d globally unique)\n", type.c_str(), c.first, c.second);
  const StereoRigParams& p = rig.params();
  std::printf("rig: %dx%d px, f = %.2f px, principal point (%.1f, %.1f), baseline %.1f mm, height %.1f mm, tilt %.3f deg\n",
              p.image_width, p.image_height, rig.focal(), rig.principalU(), rig.principalV(), p.baseline_mm,
              p.camera_height_mm, rad2deg(p.tilt_rad));
  if (!o.rig_path.empty()) printHandover(CalibrationHandover::load(o.rig_path));

  std::mt19937_64 rng(o.seed);
  std::uniform_real_distribution<double> U(-1.0, 1.0);
  double max_roundtrip = 0, max_rig_jac = 0, max_odo_jac = 0, max_meas_jac = 0;
  const OdometryParams odo;
  for (int i = 0; i < o.samples; ++i) {
    const Eigen::Vector3d pt(600 + 500 * U(rng), 400 * U(rng), 60 * U(rng));
    const double pan = 0.5 * U(rng);
    const auto px = rig.project(rig.visionToRobot(pt, 0.0), pan);
    if (!px) continue;
    max_roundtrip = std::max(max_roundtrip, (rig.triangulate(*px, pan) - rig.visionToRobot(pt, 0.0)).norm());
    StereoRig::Matrix24d J;
    rig.rangeBearing(*px, pan, &J);
    const Eigen::Vector4d x(px->u_left, px->v_left, px->u_right, px->v_right);
    auto f = [&](const Eigen::Vector4d& v) {
      const RangeBearing rb = rig.rangeBearing(StereoPixels{v(0), v(1), v(2), v(3)}, pan);
      return Eigen::Vector2d(rb.range, rb.bearing);
    };
    max_rig_jac = std::max(max_rig_jac, relativeJacobianError(J, numericJacobian<2, 4>(f, x)));

    const double dl = 20 * U(rng), dr = 20 * U(rng);
    Matrix32d Ju;
    controlVector(dl, dr, odo.wheel_base_mm, &Ju);
    auto g = [&](const Eigen::Vector2d& d) { return controlVector(d(0), d(1), odo.wheel_base_mm); };
    max_odo_jac = std::max(max_odo_jac, relativeJacobianError(Ju, numericJacobian<3, 2>(g, Eigen::Vector2d(dl, dr))));

    const Pose2 pose(750 + 700 * U(rng), 650 + 600 * U(rng), kPi * U(rng));
    const Eigen::Vector2d lm = map.landmarks()[i % map.landmarks().size()].xy();
    if ((lm - pose.translation()).norm() < 50) continue;
    Matrix23d Jz;
    predictRangeBearing(pose, lm, &Jz);
    auto h = [&](const Eigen::Vector3d& v) { return predictRangeBearing(Pose2(v(0), v(1), v(2)), lm); };
    auto wrapMinus = [](const Eigen::Vector2d& a, const Eigen::Vector2d& b) { return rangeBearingInnovation(a, b); };
    max_meas_jac = std::max(max_meas_jac, relativeJacobianError(Jz, numericJacobian<2, 3>(h, pose.vector(), wrapMinus)));
  }
  std::printf("model checks over %d random samples (seed %u):\n", o.samples, o.seed);
  bool ok = true;
  ok &= report("project -> triangulate round trip", max_roundtrip, 1e-9, "mm");
  ok &= report("rig d(range,bearing)/d(pixels) vs central differences", max_rig_jac, 1e-6, "");
  ok &= report("odometry J_u (B.8) vs central differences", max_odo_jac, 1e-6, "");
  ok &= report("range-bearing d z/d pose (5.27) vs central differences", max_meas_jac, 1e-6, "");
  if (!ok) throw Error("selfcheck: a model check failed");
  std::printf("all model checks passed\n");
}

}  // namespace

void add_selfcheck_command(CLI::App& app) {
  auto opts = std::make_shared<SelfcheckOptions>();
  CLI::App* sub = app.add_subcommand("selfcheck", "Print the map and rig summary and check the models numerically");
  sub->add_option("--map", opts->map_path, "Field map YAML (default: the built-in MiroSot field)")->check(CLI::ExistingFile);
  sub->add_option("--rig", opts->rig_path, "Stereo rig YAML (default: the built-in rig)")->check(CLI::ExistingFile);
  sub->add_option("--seed", opts->seed, "Random seed")->capture_default_str();
  sub->add_option("--samples", opts->samples, "Number of random samples")->capture_default_str()->check(CLI::Range(1, 10000000));
  sub->callback([opts] { runSelfcheck(*opts); });
}

}  // namespace stereoloc::cli
