#include "frontend/detection_text.h"

#include <cmath>
#include <cstdio>
#include <sstream>

#include "src/core/angles.h"

namespace stereoloc::frontend {
namespace {

std::string num(double v, int prec = 3) {
  char buf[64];
  std::snprintf(buf, sizeof(buf), "%.*f", prec, v);
  return buf;
}

}  // namespace

std::string detectionsJson(const FrontendResult& r) {
  std::ostringstream out;
  out << "{\"segments\": [";
  for (size_t i = 0; i < r.lines.size(); ++i) {
    const LineFeature& l = r.lines[i];
    out << (i ? ", " : "") << "{\"x1\": " << num(l.x(l.t_min)) << ", \"y1\": " << num(l.y(l.t_min))
        << ", \"x2\": " << num(l.x(l.t_max)) << ", \"y2\": " << num(l.y(l.t_max))
        << ", \"marking\": " << (l.marking ? "true" : "false") << "}";
  }
  out << "], \"features\": [";
  for (size_t i = 0; i < r.features.size(); ++i) {
    const PointFeature& f = r.features[i];
    out << (i ? ", " : "") << "{\"type\": \"" << toString(f.type) << "\", \"u\": " << num(f.u) << ", \"v\": " << num(f.v)
        << ", \"landmark_id\": " << f.landmark_id;
    if (f.type == LandmarkType::GoalCorner) out << ", \"color\": \"" << toString(f.color) << "\"";
    out << "}";
  }
  out << "], \"observations\": [";
  for (size_t i = 0; i < r.observations.size(); ++i) {
    const Observation& ob = r.observations[i];
    out << (i ? ", " : "") << "{\"type\": \"" << toString(ob.type) << "\", \"landmark_id\": " << ob.landmark_id
        << ", \"range\": " << num(ob.range) << ", \"bearing\": " << num(ob.bearing, 6);
    if (ob.pixels)
      out << ", \"u_left\": " << num(ob.pixels->u_left) << ", \"u_right\": " << num(ob.pixels->u_right)
          << ", \"v\": " << num(ob.pixels->v_left);
    out << ", \"covariance\": [" << num(ob.covariance(0, 0), 6) << ", " << num(ob.covariance(0, 1), 9) << ", "
        << num(ob.covariance(1, 1), 9) << "]}";
  }
  out << "]}\n";
  return out.str();
}

std::string detectionsTable(const FrontendResult& r) {
  std::ostringstream out;
  char buf[200];
  out << "segments (left image, px): " << r.lines.size() << "\n";
  out << "     x1      y1      x2      y2  class\n";
  for (const LineFeature& l : r.lines) {
    std::snprintf(buf, sizeof(buf), "%7.2f %7.2f %7.2f %7.2f  %s\n", l.x(l.t_min), l.y(l.t_min), l.x(l.t_max), l.y(l.t_max),
                  l.marking ? "marking" : "other");
    out << buf;
  }
  out << "features (left image, px): " << r.features.size() << "\n";
  for (const PointFeature& f : r.features) {
    const std::string goal =
        f.type == LandmarkType::GoalCorner ? "  " + toString(f.color) + " landmark " + std::to_string(f.landmark_id) : "";
    std::snprintf(buf, sizeof(buf), "  %-12s u %7.2f v %7.2f%s\n", toString(f.type).c_str(), f.u, f.v, goal.c_str());
    out << buf;
  }
  out << "observations: " << r.observations.size() << "\n";
  out << "  type         landmark  range_mm  bearing_deg  u_left  u_right       v  sigma_r_mm\n";
  for (const Observation& ob : r.observations) {
    std::snprintf(buf, sizeof(buf), "  %-12s %8d  %8.1f  %11.2f", toString(ob.type).c_str(), ob.landmark_id, ob.range,
                  rad2deg(ob.bearing));
    out << buf;
    if (ob.pixels)
      std::snprintf(buf, sizeof(buf), "  %6.2f  %7.2f  %6.2f", ob.pixels->u_left, ob.pixels->u_right, ob.pixels->v_left);
    else
      std::snprintf(buf, sizeof(buf), "  %6s  %7s  %6s", "-", "-", "-");
    out << buf;
    std::snprintf(buf, sizeof(buf), "  %10.1f\n", std::sqrt(ob.covariance(0, 0)));
    out << buf;
  }
  return out.str();
}

}  // namespace stereoloc::frontend
