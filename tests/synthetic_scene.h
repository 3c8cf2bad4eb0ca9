#pragma once
// Synthetic scenes for the frontend's tests: a floor with white markings ray-cast into the rig's
// cameras, and the field's colours (BGR) as the goal tests paint them.
#include <opencv2/core.hpp>

#include <Eigen/Core>
#include <cmath>
#include <cstdint>
#include <vector>

#include "src/core/stereo_rig.h"

namespace stereoloc::test {

inline const cv::Vec3b kWhite(235, 235, 235), kYellow(40, 225, 245), kBlue(235, 100, 50), kDark(25, 25, 25);

struct Strip {  // floor marking in C0 (mm): centreline a -> b, half width
  Eigen::Vector2d a, b;
  double hw = 5.0;
};

struct Ring {  // floor marking in C0 (mm): a circle of the given centre and radius, half width
  Eigen::Vector2d centre;
  double radius = 250.0, hw = 5.0;
};

// Ray-casts a floor scene (dark floor, white strips and rings, optional white region
// x >= wall_x) into the left or right camera, 4x4 samples per pixel.
inline cv::Mat renderFloor(const StereoRig& rig, bool right, const std::vector<Strip>& strips, double wall_x = 1e9,
                           const std::vector<Ring>& rings = {}) {
  const int w = rig.params().image_width, h = rig.params().image_height;
  const double f = rig.focal(), yc = (right ? -0.5 : 0.5) * rig.params().baseline_mm;
  const Eigen::Vector3d o = rig.visionToRobot(Eigen::Vector3d(0, yc, 0), 0.0);
  auto dir = [&](double u, double v) -> Eigen::Vector3d {
    return rig.visionToRobot(Eigen::Vector3d(1.0, yc - (u - rig.principalU()) / f, -(v - rig.principalV()) / f), 0.0) - o;
  };
  const Eigen::Vector3d d00 = dir(0, 0), du = dir(1, 0) - d00, dv = dir(0, 1) - d00;
  auto white = [&](const Eigen::Vector2d& p) {
    if (p.x() >= wall_x) return true;
    for (const Ring& r : rings)
      if (std::fabs((p - r.centre).norm() - r.radius) <= r.hw) return true;
    for (const Strip& s : strips) {
      const Eigen::Vector2d t = (s.b - s.a).normalized();
      const double along = (p - s.a).dot(t), across = std::fabs(t.x() * (p - s.a).y() - t.y() * (p - s.a).x());
      if (along >= -s.hw && along <= (s.b - s.a).norm() + s.hw && across <= s.hw) return true;
    }
    return false;
  };
  cv::Mat img(h, w, CV_8UC3);
  for (int v = 0; v < h; ++v)
    for (int u = 0; u < w; ++u) {
      int n = 0;
      for (int k = 0; k < 16; ++k) {
        const Eigen::Vector3d d = d00 + (u - 0.5 + (k % 4 + 0.5) / 4) * du + (v - 0.5 + (k / 4 + 0.5) / 4) * dv;
        if (d.z() >= 0) continue;  // sky: dark
        const double s = -o.z() / d.z();
        n += white(Eigen::Vector2d(o.x() + s * d.x(), o.y() + s * d.y())) ? 1 : 0;
      }
      const uint8_t g = static_cast<uint8_t>(20 + 210 * n / 16);
      img.at<cv::Vec3b>(v, u) = cv::Vec3b(g, g, g);
    }
  return img;
}

// The left camera's pixel of the floor point (x, y) in C0 (mm).
inline Eigen::Vector2d floorPixel(const StereoRig& rig, double x, double y) {
  const auto p = rig.project(Eigen::Vector3d(x, y, 0.0), 0.0);
  return Eigen::Vector2d(p->u_left, p->v_left);
}

}  // namespace stereoloc::test
