#include "src/sim/simulator_scene.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>

#include "src/core/error.h"

namespace stereoloc {
namespace {

Prism box(double x0, double y0, double x1, double y1, double z0, double z1, SurfaceClass cls = SurfaceClass::Wall) {
  Prism p;
  p.polygon = {{x0, y0}, {x1, y0}, {x1, y1}, {x0, y1}};
  p.zmin = z0;
  p.zmax = z1;
  p.side.assign(4, cls);
  p.top = cls;
  p.bottom = cls;
  return p;
}

}  // namespace

std::string toString(Obstacle::Kind kind) { return kind == Obstacle::Kind::Robot ? "robot" : "ball"; }

Obstacle::Kind obstacleKindFromString(const std::string& name) {
  if (name == "robot") return Obstacle::Kind::Robot;
  if (name == "ball") return Obstacle::Kind::Ball;
  throw Error("unknown obstacle kind '" + name + "' (expected robot or ball)");
}

Scene Scene::fromMap(const FieldMap& map, const std::vector<Obstacle>& obstacles) {
  if (!map.geometry()) throw Error("map '" + map.name() + "' has no field geometry: cannot build the 3D scene");
  Scene s;
  s.geometry_ = *map.geometry();
  s.addWalls();
  s.addGoals();
  s.addCornerTriangles();
  s.addMarkings();
  s.addWallAndGoalEdges();
  s.addObstacles(obstacles);
  s.precompute();
  return s;
}

// Long walls (with the corners) and the goal-line walls beside the goal mouths. Cut into pieces
// of at most kPiece mm along their length: the renderer culls by image bounding box, and a
// short piece that lies wholly in front of (or behind) the camera gets a tight (or no) box.
void Scene::addWalls() {
  const FieldGeometry& g = geometry_;
  const double L = g.length, W = g.width, H = g.wall_height, T = kWallThickness;
  const double cy = 0.5 * W, y_lo = cy - 0.5 * g.goal_width, y_hi = cy + 0.5 * g.goal_width;
  constexpr double kPiece = 300.0;
  auto wall = [&](double x0, double y0, double x1, double y1) {
    const bool along_x = (x1 - x0) >= (y1 - y0);
    const double len = along_x ? x1 - x0 : y1 - y0;
    const int pieces = std::max(1, static_cast<int>(std::ceil(len / kPiece)));
    for (int k = 0; k < pieces; ++k) {
      const double a = k * len / pieces, b = (k + 1 == pieces) ? len : (k + 1) * len / pieces;
      prisms_.push_back(along_x ? box(x0 + a, y0, x0 + b, y1, 0, H) : box(x0, y0 + a, x1, y0 + b, 0, H));
    }
  };
  wall(-T, -T, L + T, 0);
  wall(-T, W, L + T, W + T);
  wall(-T, 0, 0, y_lo - T);
  wall(-T, y_hi + T, 0, W);
  wall(L, 0, L + T, y_lo - T);
  wall(L, y_hi + T, L + T, W);
}

// Goals: side walls from the mouth to the back, and the back wall. Polygon edges run
// (x0,y0)->(x1,y0)->(x1,y1)->(x0,y1): side 0 faces -y, 1 faces +x, 2 faces +y, 3 faces -x.
void Scene::addGoals() {
  const FieldGeometry& g = geometry_;
  const double L = g.length, H = g.wall_height, T = kWallThickness, D = g.goal_depth;
  const double cy = 0.5 * g.width, y_lo = cy - 0.5 * g.goal_width, y_hi = cy + 0.5 * g.goal_width;
  for (int side = 0; side < 2; ++side) {
    const SurfaceClass c = side == 0 ? SurfaceClass::BlueGoal : SurfaceClass::YellowGoal;
    const double xm = side == 0 ? 0.0 : L;          // goal line
    const double xb = side == 0 ? -D : L + D;       // inner face of the back wall
    const double x0 = std::min(xm, xb), x1 = std::max(xm, xb);
    Prism lower = box(x0, y_lo - T, x1, y_lo, 0, H);
    lower.side[2] = c;  // inner face (+y) coloured; the face on the goal line stays white
    Prism upper = box(x0, y_hi, x1, y_hi + T, 0, H);
    upper.side[0] = c;
    Prism back = side == 0 ? box(xb - T, y_lo - T, xb, y_hi + T, 0, H) : box(xb, y_lo - T, xb + T, y_hi + T, 0, H);
    back.side[side == 0 ? 1 : 3] = c;
    prisms_.push_back(lower);
    prisms_.push_back(upper);
    prisms_.push_back(back);
  }
}

// Corner triangles (solid 7 cm isosceles triangles, L1906), counter-clockwise.
void Scene::addCornerTriangles() {
  const FieldGeometry& g = geometry_;
  const double L = g.length, W = g.width, H = g.wall_height, t = g.corner_triangle;
  auto triangle = [&](Eigen::Vector2d a, Eigen::Vector2d b, Eigen::Vector2d c) {
    Prism p;
    const double cross = (b - a).x() * (c - a).y() - (b - a).y() * (c - a).x();
    p.polygon = cross > 0 ? std::vector<Eigen::Vector2d>{a, b, c} : std::vector<Eigen::Vector2d>{a, c, b};
    p.zmin = 0;
    p.zmax = H;
    p.side.assign(3, SurfaceClass::Wall);
    prisms_.push_back(p);
    edges_.push_back({"triangle", "triangle_foot", {b.x(), b.y(), 0.0}, {c.x(), c.y(), 0.0}});
    edges_.push_back({"triangle", "triangle_top", {b.x(), b.y(), H}, {c.x(), c.y(), H}});
  };
  triangle({0, 0}, {t, 0}, {0, t});
  triangle({L, 0}, {L - t, 0}, {L, t});
  triangle({0, W}, {t, W}, {0, W - t});
  triangle({L, W}, {L - t, W}, {L, W - t});
}

// Markings (centrelines; landmarks lie on them).
void Scene::addMarkings() {
  const FieldGeometry& g = geometry_;
  const double L = g.length, W = g.width, cy = 0.5 * W, hw = 0.5 * g.line_width;
  auto strip = [&](const std::string& name, Eigen::Vector2d a, Eigen::Vector2d b, double ea, double eb) {
    strips_.push_back({a, b, hw, ea, eb});
    edges_.push_back({"marking", name, {a.x(), a.y(), 0.0}, {b.x(), b.y(), 0.0}});
  };
  strip("halfway_line", {0.5 * L, 0.0}, {0.5 * L, W}, 0, 0);
  rings_.push_back({{0.5 * L, cy}, g.centre_circle_radius, hw});
  struct Area {
    const char* name;
    double depth, width;
  };
  for (const Area& a : {Area{"goal_area", g.goal_area_depth, g.goal_area_width},
                        Area{"penalty_area", g.penalty_area_depth, g.penalty_area_width}}) {
    for (int side = 0; side < 2; ++side) {
      const double xg = side == 0 ? 0.0 : L, xd = side == 0 ? a.depth : L - a.depth;
      const std::string pre = std::string(side == 0 ? "blue_" : "yellow_") + a.name;
      const double ylo = cy - 0.5 * a.width, yhi = cy + 0.5 * a.width;
      strip(pre + "_front", {xd, ylo}, {xd, yhi}, hw, hw);
      strip(pre + "_side_lo", {xg, ylo}, {xd, ylo}, 0, hw);
      strip(pre + "_side_hi", {xg, yhi}, {xd, yhi}, 0, hw);
    }
  }
}

// The straight edges of walls and goals the images' truth reports (feet, tops, posts).
void Scene::addWallAndGoalEdges() {
  const FieldGeometry& g = geometry_;
  const double L = g.length, W = g.width, H = g.wall_height, D = g.goal_depth, t = g.corner_triangle;
  const double cy = 0.5 * W, y_lo = cy - 0.5 * g.goal_width, y_hi = cy + 0.5 * g.goal_width;
  auto edge = [&](const char* kind, const std::string& name, Eigen::Vector3d a, Eigen::Vector3d b) {
    edges_.push_back({kind, name, a, b});
  };
  for (double z : {0.0, H}) {
    const char* kind = z == 0.0 ? "wall_foot" : "wall_top";
    edge(kind, "wall_y0", {t, 0, z}, {L - t, 0, z});
    edge(kind, "wall_y" + std::to_string(static_cast<long>(W)), {t, W, z}, {L - t, W, z});
    edge(kind, "wall_blue_lo", {0, t, z}, {0, y_lo, z});
    edge(kind, "wall_blue_hi", {0, y_hi, z}, {0, W - t, z});
    edge(kind, "wall_yellow_lo", {L, t, z}, {L, y_lo, z});
    edge(kind, "wall_yellow_hi", {L, y_hi, z}, {L, W - t, z});
    const char* gkind = z == 0.0 ? "goal_foot" : "goal_top";
    for (int side = 0; side < 2; ++side) {
      const double xm = side == 0 ? 0.0 : L, xb = side == 0 ? -D : L + D;
      const std::string pre = side == 0 ? "blue_goal" : "yellow_goal";
      edge(gkind, pre + "_side_lo", {xm, y_lo, z}, {xb, y_lo, z});
      edge(gkind, pre + "_side_hi", {xm, y_hi, z}, {xb, y_hi, z});
      edge(gkind, pre + "_back", {xb, y_lo, z}, {xb, y_hi, z});
    }
  }
  for (int side = 0; side < 2; ++side) {
    const double xm = side == 0 ? 0.0 : L;
    const std::string pre = side == 0 ? "blue_goal" : "yellow_goal";
    edge("goal_post", pre + "_post_lo", {xm, y_lo, 0}, {xm, y_lo, H});
    edge("goal_post", pre + "_post_hi", {xm, y_hi, 0}, {xm, y_hi, H});
  }
}

// Robots as upright square prisms, balls as spheres resting on the floor.
void Scene::addObstacles(const std::vector<Obstacle>& obstacles) {
  for (const Obstacle& o : obstacles) {
    if (!(o.position.allFinite() && std::isfinite(o.heading) && std::isfinite(o.size) && o.size > 0))
      throw Error("obstacle: position, heading and size must be finite, size positive");
    if (o.kind == Obstacle::Kind::Ball) {
      spheres_.push_back({{o.position.x(), o.position.y(), 0.5 * o.size}, 0.5 * o.size});
    } else {
      Prism p;
      const double h = 0.5 * o.size, c = std::cos(o.heading), sn = std::sin(o.heading);
      for (auto [lx, ly] : {std::pair{-h, -h}, std::pair{h, -h}, std::pair{h, h}, std::pair{-h, h}})
        p.polygon.emplace_back(o.position.x() + c * lx - sn * ly, o.position.y() + sn * lx + c * ly);
      p.zmin = 0;
      p.zmax = o.size;
      p.side.assign(4, SurfaceClass::Robot);
      p.top = SurfaceClass::Robot;
      p.bottom = SurfaceClass::Robot;
      prisms_.push_back(p);
    }
  }
}

void Scene::precompute() {
  box_rects_.clear();
  for (const Prism& p : prisms_) {
    const auto& q = p.polygon;
    const bool box = q.size() == 4 && q[0].y() == q[1].y() && q[1].x() == q[2].x() && q[2].y() == q[3].y() &&
                     q[3].x() == q[0].x() && q[0].x() < q[1].x() && q[1].y() < q[2].y();
    box_rects_.push_back(box ? Eigen::Vector4d(q[0].x(), q[0].y(), q[2].x(), q[2].y())
                             : Eigen::Vector4d(std::nan(""), 0, 0, 0));
  }
  strip_rects_.clear();
  for (const MarkingStrip& m : strips_) {
    const Eigen::Vector2d u = (m.b - m.a).normalized();
    const Eigen::Vector2d lo = m.a - m.extend_a * u, hi = m.b + m.extend_b * u;
    if (u.x() == 0.0 || u.y() == 0.0) {
      const double hx = u.x() == 0.0 ? m.half_width : 0.0, hy = u.y() == 0.0 ? m.half_width : 0.0;
      strip_rects_.emplace_back(std::min(lo.x(), hi.x()) - hx, std::min(lo.y(), hi.y()) - hy,
                                std::max(lo.x(), hi.x()) + hx, std::max(lo.y(), hi.y()) + hy);
    } else {
      strip_rects_.emplace_back(std::nan(""), 0, 0, 0);
    }
  }
  // Cell grid of floorClass over the only region where the floor is not background.
  const FieldGeometry& g = geometry_;
  constexpr double kCell = 20.0, kMargin = 1.0;  // mm; the margin keeps the lists conservative
  cell_size_ = kCell;
  cell_x0_ = -g.goal_depth;
  cell_y0_ = 0.0;
  cells_nx_ = std::max(1, static_cast<int>(std::ceil((g.length + 2 * g.goal_depth) / kCell)));
  cells_ny_ = std::max(1, static_cast<int>(std::ceil(g.width / kCell)));
  std::vector<std::vector<uint32_t>> lists(static_cast<size_t>(cells_nx_) * cells_ny_);
  auto addBox = [&](double x0, double y0, double x1, double y1, uint32_t item) {
    const int i0 = std::max(0, static_cast<int>(std::floor((x0 - kMargin - cell_x0_) / kCell)));
    const int i1 = std::min(cells_nx_ - 1, static_cast<int>(std::floor((x1 + kMargin - cell_x0_) / kCell)));
    const int j0 = std::max(0, static_cast<int>(std::floor((y0 - kMargin - cell_y0_) / kCell)));
    const int j1 = std::min(cells_ny_ - 1, static_cast<int>(std::floor((y1 + kMargin - cell_y0_) / kCell)));
    for (int j = j0; j <= j1; ++j)
      for (int i = i0; i <= i1; ++i) lists[static_cast<size_t>(j) * cells_nx_ + i].push_back(item);
  };
  for (size_t k = 0; k < strips_.size(); ++k) {
    const MarkingStrip& m = strips_[k];
    const Eigen::Vector2d u = (m.b - m.a).normalized();
    const Eigen::Vector2d lo = m.a - m.extend_a * u, hi = m.b + m.extend_b * u;
    addBox(std::min(lo.x(), hi.x()) - m.half_width, std::min(lo.y(), hi.y()) - m.half_width,
           std::max(lo.x(), hi.x()) + m.half_width, std::max(lo.y(), hi.y()) + m.half_width, static_cast<uint32_t>(k));
  }
  for (size_t k = 0; k < rings_.size(); ++k) {
    const MarkingRing& r = rings_[k];
    const double lo = r.radius - r.half_width - kMargin, hi = r.radius + r.half_width + kMargin;
    for (int j = 0; j < cells_ny_; ++j)
      for (int i = 0; i < cells_nx_; ++i) {
        // Distance range from the centre to the cell's box.
        const double bx0 = cell_x0_ + i * kCell, by0 = cell_y0_ + j * kCell;
        const double nx = std::clamp(r.centre.x(), bx0, bx0 + kCell) - r.centre.x();
        const double ny = std::clamp(r.centre.y(), by0, by0 + kCell) - r.centre.y();
        const double fx = std::max(std::fabs(bx0 - r.centre.x()), std::fabs(bx0 + kCell - r.centre.x()));
        const double fy = std::max(std::fabs(by0 - r.centre.y()), std::fabs(by0 + kCell - r.centre.y()));
        if (std::hypot(nx, ny) <= hi && std::hypot(fx, fy) >= lo)
          lists[static_cast<size_t>(j) * cells_nx_ + i].push_back(static_cast<uint32_t>(strips_.size() + k));
      }
  }
  cell_start_.assign(lists.size() + 1, 0);
  cell_items_.clear();
  cell_state_.assign(lists.size(), kCellTest);
  for (size_t c = 0; c < lists.size(); ++c) {
    cell_items_.insert(cell_items_.end(), lists[c].begin(), lists[c].end());
    cell_start_[c + 1] = static_cast<uint32_t>(cell_items_.size());
    // The cell grown by the margin against the field and the goals' floor (onFloor).
    const double x0 = cell_x0_ + static_cast<double>(c % cells_nx_) * kCell - kMargin, x1 = x0 + kCell + 2 * kMargin;
    const double y0 = cell_y0_ + static_cast<double>(c / cells_nx_) * kCell - kMargin, y1 = y0 + kCell + 2 * kMargin;
    const double goal_y0 = 0.5 * (g.width - g.goal_width), goal_y1 = 0.5 * (g.width + g.goal_width);
    const bool in_field = x0 >= 0 && x1 <= g.length && y0 >= 0 && y1 <= g.width;
    const bool in_goal = y0 >= goal_y0 && y1 <= goal_y1 && x0 >= -g.goal_depth && x1 <= g.length + g.goal_depth;
    const bool off_field = x1 < 0 || x0 > g.length || y1 < 0 || y0 > g.width;
    const bool off_goal = y1 < goal_y0 || y0 > goal_y1 || x1 < -g.goal_depth || x0 > g.length + g.goal_depth;
    if (lists[c].empty() && (in_field || in_goal)) cell_state_[c] = kCellFloor;
    if (off_field && off_goal) cell_state_[c] = kCellBackground;
  }
}

bool Scene::floorIsPlain(double x0, double y0, double x1, double y1) const {
  if (cell_state_.empty() || !(x0 <= x1 && y0 <= y1)) return false;
  const double fx0 = std::floor((x0 - cell_x0_) / cell_size_), fx1 = std::floor((x1 - cell_x0_) / cell_size_);
  const double fy0 = std::floor((y0 - cell_y0_) / cell_size_), fy1 = std::floor((y1 - cell_y0_) / cell_size_);
  if (!(fx0 >= 0 && fy0 >= 0 && fx1 < cells_nx_ && fy1 < cells_ny_)) return false;
  for (int j = static_cast<int>(fy0); j <= static_cast<int>(fy1); ++j)
    for (int i = static_cast<int>(fx0); i <= static_cast<int>(fx1); ++i)
      if (cell_state_[static_cast<size_t>(j) * cells_nx_ + i] != kCellFloor) return false;
  return true;
}

bool Scene::intersectPrism(size_t i, const Eigen::Vector3d& o, const Eigen::Vector3d& d, double t_min,
                           double t_max, RayHit* hit) const {
  const Prism& p = prisms_[i];
  if (i < box_rects_.size() && !std::isnan(box_rects_[i][0])) {
    // Slab test for axis-aligned boxes (the walls and goals): the common case, kept cheap.
    const Eigen::Vector4d& r = box_rects_[i];
    double t0 = t_min, t1 = t_max;
    int face = -3;
    auto slab = [&](double o_k, double d_k, double lo, double hi, int face_lo, int face_hi) {
      if (d_k == 0.0) return o_k >= lo && o_k <= hi;
      const double inv = 1.0 / d_k;
      return clipSlab((lo - o_k) * inv, (hi - o_k) * inv, face_lo, face_hi, t0, t1, face);
    };
    // Faces: 0 = -y side, 1 = +x side, 2 = +y side, 3 = -x side, -1 = top, -2 = bottom.
    if (!slab(o.x(), d.x(), r[0], r[2], 3, 1) || !slab(o.y(), d.y(), r[1], r[3], 0, 2) ||
        !slab(o.z(), d.z(), p.zmin, p.zmax, -2, -1))
      return false;
    if (face == -3 || !(t0 > t_min)) return false;  // starts inside the box: not a visible hit
    if (hit) {
      hit->t = t0;
      hit->object = static_cast<int>(i);
      static const Eigen::Vector3d normals[4] = {{0, -1, 0}, {1, 0, 0}, {0, 1, 0}, {-1, 0, 0}};
      if (face == -1) {
        hit->cls = p.top;
        hit->normal = Eigen::Vector3d(0, 0, 1);
      } else if (face == -2) {
        hit->cls = p.bottom;
        hit->normal = Eigen::Vector3d(0, 0, -1);
      } else {
        hit->cls = p.side[face];
        hit->normal = normals[face];
      }
    }
    return true;
  }
  // Cyrus-Beck clipping against the half-spaces of the convex prism.
  double t_enter = -std::numeric_limits<double>::infinity(), t_exit = std::numeric_limits<double>::infinity();
  int enter_face = -3;  // -1 top, -2 bottom, >= 0 side index
  auto clip = [&](double num, double den, int face) {
    // Inside when num + t den <= 0.
    if (den == 0.0) return num <= 0.0;
    const double tt = -num / den;
    if (den < 0) {
      if (tt > t_enter) {
        t_enter = tt;
        enter_face = face;
      }
    } else if (tt < t_exit) {
      t_exit = tt;
    }
    return t_enter <= t_exit;
  };
  if (!clip(o.z() - p.zmax, d.z(), -1)) return false;
  if (!clip(p.zmin - o.z(), -d.z(), -2)) return false;
  const size_t n = p.polygon.size();
  for (size_t k = 0; k < n; ++k) {
    const Eigen::Vector2d& a = p.polygon[k];
    const Eigen::Vector2d& b = p.polygon[(k + 1) % n];
    const double nx = b.y() - a.y(), ny = a.x() - b.x();  // outward normal of a CCW polygon edge
    if (!clip(nx * (o.x() - a.x()) + ny * (o.y() - a.y()), nx * d.x() + ny * d.y(), static_cast<int>(k))) return false;
  }
  if (!(t_enter <= t_exit) || !(t_enter > t_min) || !(t_enter < t_max)) return false;
  if (hit) {
    hit->t = t_enter;
    hit->object = static_cast<int>(i);
    if (enter_face == -1) {
      hit->cls = p.top;
      hit->normal = Eigen::Vector3d(0, 0, 1);
    } else if (enter_face == -2) {
      hit->cls = p.bottom;
      hit->normal = Eigen::Vector3d(0, 0, -1);
    } else {
      const Eigen::Vector2d& a = p.polygon[enter_face];
      const Eigen::Vector2d& b = p.polygon[(enter_face + 1) % n];
      hit->cls = p.side[enter_face];
      hit->normal = Eigen::Vector3d(b.y() - a.y(), a.x() - b.x(), 0).normalized();
    }
  }
  return true;
}

bool Scene::intersectSphere(size_t i, const Eigen::Vector3d& o, const Eigen::Vector3d& d, double t_min,
                            double t_max, RayHit* hit) const {
  const Sphere& s = spheres_[i];
  const Eigen::Vector3d oc = o - s.centre;
  const double a = d.squaredNorm(), b = oc.dot(d), c = oc.squaredNorm() - s.radius * s.radius;
  const double disc = b * b - a * c;
  if (disc < 0 || a == 0) return false;
  const double tt = (-b - std::sqrt(disc)) / a;
  if (!(tt > t_min && tt < t_max)) return false;
  if (hit) {
    hit->t = tt;
    hit->cls = SurfaceClass::Ball;
    hit->object = static_cast<int>(prisms_.size() + i);
    hit->normal = (o + tt * d - s.centre).normalized();
  }
  return true;
}

bool Scene::onFloor(double x, double y) const {
  const FieldGeometry& g = geometry_;
  const bool in_field = x >= 0 && x <= g.length && y >= 0 && y <= g.width;
  const bool in_goal = std::fabs(y - 0.5 * g.width) <= 0.5 * g.goal_width && x >= -g.goal_depth &&
                       x <= g.length + g.goal_depth;
  return in_field || in_goal;
}

bool Scene::markingCovers(size_t item, double x, double y) const {
  if (item >= strips_.size()) {
    const MarkingRing& r = rings_[item - strips_.size()];
    const double dx = x - r.centre.x(), dy = y - r.centre.y(), d2 = dx * dx + dy * dy;
    const double lo = r.radius - r.half_width, hi = r.radius + r.half_width;
    return d2 >= lo * lo && d2 <= hi * hi;
  }
  const Eigen::Vector4d& r = strip_rects_[item];
  if (!std::isnan(r[0])) return x >= r[0] && x <= r[2] && y >= r[1] && y <= r[3];
  const MarkingStrip& m = strips_[item];
  const Eigen::Vector2d e = m.b - m.a;
  const double len = e.norm();
  const Eigen::Vector2d u = e / len;
  const double px = x - m.a.x(), py = y - m.a.y();
  const double along = px * u.x() + py * u.y();
  if (along < -m.extend_a || along > len + m.extend_b) return false;
  return std::fabs(-px * u.y() + py * u.x()) <= m.half_width;
}

SurfaceClass Scene::floorClassLinearScan(double x, double y) const {
  if (!onFloor(x, y)) return SurfaceClass::Background;
  for (size_t i = 0; i < strips_.size() + rings_.size(); ++i)
    if (markingCovers(i, x, y)) return SurfaceClass::Marking;
  return SurfaceClass::Floor;
}

SurfaceClass Scene::floorClass(double x, double y) const {
  if (cell_state_.empty()) return onFloor(x, y) ? SurfaceClass::Floor : SurfaceClass::Background;  // no markings
  const double qx = (x - cell_x0_) / cell_size_, qy = (y - cell_y0_) / cell_size_;
  if (qx >= 0 && qy >= 0 && qx < cells_nx_ && qy < cells_ny_) {
    // Truncation is floor here. Most floor samples land in a cell that settles the class (a
    // point that rounding puts in the neighbouring cell is within that cell's 1 mm margin).
    const size_t cell = static_cast<size_t>(qy) * cells_nx_ + static_cast<size_t>(qx);
    if (cell_state_[cell] == kCellFloor) return SurfaceClass::Floor;
    if (cell_state_[cell] == kCellBackground || !onFloor(x, y)) return SurfaceClass::Background;
    for (uint32_t k = cell_start_[cell]; k < cell_start_[cell + 1]; ++k)
      if (markingCovers(cell_items_[k], x, y)) return SurfaceClass::Marking;
    return SurfaceClass::Floor;
  }
  // Outside the grid (it covers every point on the floor, but a point on its far border rounds out).
  if (!onFloor(x, y)) return SurfaceClass::Background;
  const int ci = std::clamp(static_cast<int>(std::floor(qx)), 0, cells_nx_ - 1);
  const int cj = std::clamp(static_cast<int>(std::floor(qy)), 0, cells_ny_ - 1);
  const size_t cell = static_cast<size_t>(cj) * cells_nx_ + ci;
  for (uint32_t k = cell_start_[cell]; k < cell_start_[cell + 1]; ++k)
    if (markingCovers(cell_items_[k], x, y)) return SurfaceClass::Marking;
  return SurfaceClass::Floor;
}

RayHit Scene::trace(const Eigen::Vector3d& o, const Eigen::Vector3d& d, double t_min, double t_max) const {
  RayHit best;
  best.t = t_max;
  bool any = false;
  RayHit h;
  for (size_t i = 0; i < prisms_.size(); ++i)
    if (intersectPrism(i, o, d, t_min, best.t, &h)) {
      best = h;
      any = true;
    }
  for (size_t i = 0; i < spheres_.size(); ++i)
    if (intersectSphere(i, o, d, t_min, best.t, &h)) {
      best = h;
      any = true;
    }
  if (d.z() < 0 && o.z() > 0) {
    const double tf = -o.z() / d.z();
    if (tf > t_min && tf < best.t) {
      best.t = tf;
      best.cls = floorClass(o.x() + tf * d.x(), o.y() + tf * d.y());
      best.normal = Eigen::Vector3d(0, 0, 1);
      best.object = -1;
      any = true;
    }
  }
  if (!any) {
    best.cls = SurfaceClass::Background;
    best.object = -1;
    best.t = std::numeric_limits<double>::infinity();
  }
  return best;
}

bool Scene::occluded(const Eigen::Vector3d& from, const Eigen::Vector3d& to, double tolerance_mm) const {
  const Eigen::Vector3d d = to - from;
  const double len = d.norm();
  if (len <= tolerance_mm) return false;
  const double t_max = 1.0 - tolerance_mm / len;
  for (size_t i = 0; i < prisms_.size(); ++i)
    if (intersectPrism(i, from, d, 0.0, t_max, nullptr)) return true;
  for (size_t i = 0; i < spheres_.size(); ++i)
    if (intersectSphere(i, from, d, 0.0, t_max, nullptr)) return true;
  return false;
}

}  // namespace stereoloc
