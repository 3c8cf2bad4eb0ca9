#include "src/pipeline/pixel_noise.h"

#include <cmath>
#include <algorithm>
#include <limits>
#include <optional>
#include <random>

#include "frontend/frontend.h"
#include "src/core/angles.h"
#include "src/pipeline/frontend_source.h"
#include "src/sim/renderer.h"

namespace stereoloc {

namespace {

std::optional<StereoPixels> projectLandmark(const StereoRig& rig, const Pose2& robot, double pan, const Landmark& l) {
  const double c = std::cos(robot.theta), s = std::sin(robot.theta);
  const double dx = l.position.x() - robot.x, dy = l.position.y() - robot.y;
  const Eigen::Vector3d p0(c * dx + s * dy, -s * dx + c * dy, l.position.z());
  return rig.project(p0, pan);
}

Eigen::Vector4d asVector(const StereoPixels& p) { return Eigen::Vector4d(p.u_left, p.v_left, p.u_right, p.v_right); }

}  // namespace

std::vector<PixelErrorSample> measurePixelErrors(const FieldMap& map, const StereoRig& rig,
                                                 const frontend::FrontendParams& params,
                                                 const PixelNoiseOptions& options) {
  double x0 = std::numeric_limits<double>::infinity(), x1 = -x0, y0 = x0, y1 = -x0;
  for (const Landmark& l : map.landmarks()) {
    x0 = std::min(x0, l.position.x());
    x1 = std::max(x1, l.position.x());
    y0 = std::min(y0, l.position.y());
    y1 = std::max(y1, l.position.y());
  }
  x0 += options.margin_mm;
  x1 -= options.margin_mm;
  y0 += options.margin_mm;
  y1 -= options.margin_mm;
  RenderOptions ro;
  ro.compute_truth = false;
  ro.threads = 1;
  const StereoRenderer renderer(map, rig, ro);
  frontend::Frontend fe(rig, map, params);
  std::mt19937_64 rng(options.seed);
  std::uniform_real_distribution<double> ux(x0, x1), uy(y0, y1), uth(-kPi, kPi);
  std::vector<PixelErrorSample> out;
  const int n = options.poses.empty() ? options.pairs : options.pairs * static_cast<int>(options.poses.size());
  for (int k = 0; k < n; ++k) {
    const size_t i = options.poses.empty() ? 0 : static_cast<size_t>(k) % options.poses.size();
    const Pose2 robot = options.poses.empty() ? Pose2(ux(rng), uy(rng), uth(rng)) : options.poses[i];
    const double pan = i < options.head_pans.size() ? options.head_pans[i] : 0.0;
    StereoImages im = renderer.render(robot, pan, {});
    addSensorNoise(im.left, im.right, options.image_noise, options.seed * 1000003ULL + static_cast<uint64_t>(k));
    const frontend::FrontendResult& r = fe.process(im.left, im.right, pan);
    for (const frontend::StereoFeature& m : r.matched) {
      const Landmark* best = nullptr;
      std::optional<StereoPixels> best_px;
      double d1 = std::numeric_limits<double>::infinity(), d2 = d1;
      for (const Landmark& l : map.landmarks()) {
        if (l.type != m.feature.type) continue;
        if (m.feature.landmark_id >= 0 && l.id != m.feature.landmark_id) continue;
        const auto px = projectLandmark(rig, robot, pan, l);
        if (!px) continue;
        const double d = std::hypot(px->u_left - m.pixels.u_left, px->v_left - m.pixels.v_left);
        if (d < d1) {
          d2 = d1;
          d1 = d;
          best = &l;
          best_px = px;
        } else if (d < d2) {
          d2 = d;
        }
      }
      if (!best || d1 > options.match_px || d2 < 2 * options.match_px) continue;
      if (std::hypot(best_px->u_right - m.pixels.u_right, best_px->v_right - m.pixels.v_right) > options.match_px)
        continue;
      PixelErrorSample s;
      s.type = best->type;
      s.landmark_id = best->id;
      s.truth = asVector(*best_px);
      s.error = asVector(m.pixels) - s.truth;
      s.range_mm = std::hypot(best->position.x() - robot.x, best->position.y() - robot.y);
      s.located_in_both_images = m.located_in_both_images;
      out.push_back(s);
    }
  }
  return out;
}

PixelErrorMoments pixelErrorMoments(const std::vector<PixelErrorSample>& samples) {
  PixelErrorMoments m;
  m.n = static_cast<long>(samples.size());
  if (m.n == 0) return m;
  for (const PixelErrorSample& s : samples) {
    m.mean += s.error;
    m.second += s.error * s.error.transpose();
  }
  m.mean /= static_cast<double>(m.n);
  m.second /= static_cast<double>(m.n);
  if (m.n > 1)
    m.covariance = (m.second - m.mean * m.mean.transpose()) * (static_cast<double>(m.n) / static_cast<double>(m.n - 1));
  return m;
}

std::map<LandmarkType, std::vector<PixelErrorSample>> samplesByType(const std::vector<PixelErrorSample>& samples) {
  std::map<LandmarkType, std::vector<PixelErrorSample>> out;
  for (const PixelErrorSample& s : samples) out[s.type].push_back(s);
  return out;
}

std::map<int, std::vector<PixelErrorSample>> samplesByLandmark(const std::vector<PixelErrorSample>& samples) {
  std::map<int, std::vector<PixelErrorSample>> out;
  for (const PixelErrorSample& s : samples) out[s.landmark_id].push_back(s);
  return out;
}

}  // namespace stereoloc
