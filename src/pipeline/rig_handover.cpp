#include "src/pipeline/rig_handover.h"

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "src/core/error.h"
#include "src/core/exposure_offset.h"

namespace stereoloc {
namespace {

// Why pixels of one rig are not pixels of the other ("" when they are).
std::string rectifiedDifference(const StereoRig& a, const StereoRig& b) {
  char buf[160];
  auto differs = [](double x, double y) { return std::fabs(x - y) > 1e-9 * std::max(1.0, std::fabs(x)); };
  if (a.params().image_width != b.params().image_width || a.params().image_height != b.params().image_height) {
    std::snprintf(buf, sizeof buf, "image size %dx%d against the dataset's %dx%d", b.params().image_width,
                  b.params().image_height, a.params().image_width, a.params().image_height);
    return buf;
  }
  const double av[4] = {a.focal(), a.principalU(), a.principalV(), a.params().baseline_mm};
  const double bv[4] = {b.focal(), b.principalU(), b.principalV(), b.params().baseline_mm};
  const char* names[4] = {"focal length", "principal point column", "principal point row", "baseline"};
  for (int i = 0; i < 4; ++i) {
    if (!differs(av[i], bv[i])) continue;
    std::snprintf(buf, sizeof buf, "rectified %s %.6g against the dataset's %.6g", names[i], bv[i], av[i]);
    return buf;
  }
  return "";
}

}  // namespace

CalibrationHandover useRig(Dataset& d, const std::string& rig_path, bool images_measured_again) {
  const StereoRig rig = StereoRig::load(rig_path);
  const CalibrationHandover handover = CalibrationHandover::load(rig_path);
  if (!images_measured_again) {
    bool pixels = false;
    for (const Step& s : d.steps)
      for (const Observation& o : s.observations) pixels |= o.pixels.has_value();
    if (pixels) {
      const std::string why = rectifiedDifference(d.rig, rig);
      if (!why.empty())
        throw Error(rig_path + ": " + why + ": the dataset's pixel observations were rectified with its own rig; " +
                    (d.has_images ? "measure its images again with this one (--frontend images)"
                                  : "it has no images to measure again with this one"));
      for (Step& s : d.steps) {
        for (Observation& o : s.observations) {
          if (!o.pixels) continue;
          const double slide_gain = o.slide_gain;
          try {
            o = observationFromPixels(rig, o.landmark_id, o.type, *o.pixels, o.head_pan, o.pixel_covariance);
          } catch (const GeometryError& e) {
            throw Error(rig_path + ": step " + std::to_string(s.step) + ": " + e.what());
          }
          o.slide_gain = slide_gain;
        }
      }
    }
  }
  d.rig = rig;
  if (handover.wheels) applyWheelCalibration(d, *handover.wheels);
  return handover;
}

void useMap(Dataset& d, const std::string& map_path, bool images_measured_again) {
  FieldMap map = FieldMap::load(map_path);
  if (images_measured_again) {
    d.map = std::move(map);
    return;
  }
  for (const Step& s : d.steps)
    for (const Observation& o : s.observations) {
      if (o.landmark_id < 0) continue;
      const Landmark* l = map.find(o.landmark_id);
      const std::string seen = " (the dataset sees it at step " + std::to_string(s.step) + ")";
      if (!l) throw Error(map_path + ": landmark " + std::to_string(o.landmark_id) + ": not in the map" + seen);
      if (l->type != o.type)
        throw Error(map_path + ": landmark " + std::to_string(o.landmark_id) + ": type " + toString(l->type) +
                    ", the dataset's map has " + toString(o.type) + seen);
    }
  d.map = std::move(map);
}

void synchroniseExposures(Dataset& d) {
  if (d.rig.params().exposure_offset_s == 0.0) return;
  BodyRateTracker rates(d.odometry.wheel_base_mm);
  for (Step& s : d.steps) {
    const BodyRate rate = rates.add(s.t, s.d_left, s.d_right, stepRotationVariance(s.d_left, s.d_right, d.odometry));
    for (size_t i = 0; i < s.observations.size(); ++i) {
      try {
        s.observations[i] = synchronisedObservation(d.rig, s.observations[i], rate);
      } catch (const GeometryError& e) {
        throw Error("step " + std::to_string(s.step) + ": observation " + std::to_string(i) + ": " + e.what());
      }
    }
  }
}

}  // namespace stereoloc
