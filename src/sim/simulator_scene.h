#pragma once
// The 3D world of the simulator: the MiroSot field's solid parts (walls, goals, corner
// triangles, dynamic obstacles) as convex prisms and spheres, and the painted floor markings.
// Both the visibility test of the simulated sensor (occlusion) and the renderer (ray casting)
// use this one description, so a landmark that the sensor reports is the one the images show.
//
// Layout (FieldGeometry, MiroSot frame, mm): the field floor is [0, length] x [0, width] at
// z = 0. Walls of height wall_height and thickness kWallThickness stand outside the field
// boundary, open at the goal mouths. Each goal is a box of depth goal_depth behind the goal
// line; its side walls' inner faces and its back wall's inner face are coloured (blue goal at
// x = 0, yellow at x = length). The goal-corner landmark is the vertical edge at the goal mouth
// where the white field wall meets the coloured inner face of the goal side wall (thesis 3.6).
// Markings are white strips of width line_width centred on their centrelines (the landmarks lie
// on the centrelines).
#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "src/core/field_map.h"

namespace stereoloc {

constexpr double kWallThickness = 25.0;  // mm (not specified by the thesis)

// A moving object on the field (the thesis's "highly dynamic" environment).
struct Obstacle {
  enum class Kind { Robot, Ball };
  Kind kind = Kind::Robot;
  Eigen::Vector2d position = Eigen::Vector2d::Zero();  // mm, centre on the floor
  double heading = 0.0;                                // rad (robots)
  double size = 75.0;  // mm: robot cube side (its height too), or ball diameter (42.7 mm golf ball)
};
std::string toString(Obstacle::Kind kind);                  // "robot" | "ball"
Obstacle::Kind obstacleKindFromString(const std::string& name);  // throws stereoloc::Error

// Linear RGB colour, components in [0, 1].
using Colour = Eigen::Vector3f;

// Surface classes, for ground truth and tests.
enum class SurfaceClass : uint8_t {
  Background = 0,
  Floor,
  Marking,
  Wall,       // white wall faces and tops, corner triangles
  BlueGoal,   // coloured inner faces of the blue goal
  YellowGoal,
  Robot,
  Ball,
};

struct SceneColours {
  Colour background{0.45f, 0.45f, 0.50f};
  Colour floor{0.08f, 0.08f, 0.08f};
  Colour marking{0.92f, 0.92f, 0.92f};
  Colour wall{0.95f, 0.95f, 0.95f};
  Colour wall_top{0.85f, 0.85f, 0.85f};
  Colour blue_goal{0.05f, 0.15f, 0.85f};
  Colour yellow_goal{0.95f, 0.85f, 0.05f};
  Colour robot{0.20f, 0.20f, 0.22f};
  Colour robot_top{0.85f, 0.15f, 0.60f};
  Colour ball{1.0f, 0.45f, 0.0f};
};

// A right prism: a convex polygon (counter-clockwise, world x-y) extruded over [zmin, zmax].
struct Prism {
  std::vector<Eigen::Vector2d> polygon;
  double zmin = 0.0, zmax = 0.0;
  std::vector<SurfaceClass> side;  // class of the side face from polygon[i] to polygon[i+1]
  SurfaceClass top = SurfaceClass::Wall;
  SurfaceClass bottom = SurfaceClass::Wall;
};

struct Sphere {
  Eigen::Vector3d centre = Eigen::Vector3d::Zero();
  double radius = 0.0;
};

// A floor marking: an axis-aligned or rotated strip (segment with width), or a ring.
struct MarkingStrip {
  Eigen::Vector2d a, b;  // centreline end points (mm)
  double half_width = 5.0;
  double extend_a = 0.0, extend_b = 0.0;  // painted beyond a / b along the line (closes L corners)
};
struct MarkingRing {
  Eigen::Vector2d centre;
  double radius = 0.0, half_width = 5.0;
};

// A named straight 3D edge of the world, for the renderer's ground truth.
struct SceneEdge {
  std::string kind;  // "marking" (centreline), "wall_foot", "wall_top", "goal_post", "goal_foot", "goal_top", "triangle"
  std::string name;
  Eigen::Vector3d a, b;
};

struct RayHit {
  double t = 0.0;
  SurfaceClass cls = SurfaceClass::Background;
  Eigen::Vector3d normal = Eigen::Vector3d::Zero();
  int object = -1;  // index of the prism / sphere hit (-1 floor or background)
};

// One axis of the slab test of a ray against an axis-aligned box: [ta, tb] is where the ray is
// between the two planes of the axis (in either order); the ray's interval [t0, t1] is clipped
// to it, and `face` becomes face_lo (face_hi when ta > tb) when this axis sets t0. Returns
// whether the interval is still non-empty. Scene::intersectPrism and the renderer's hoisted
// test share it, so both give the same hits term for term.
inline bool clipSlab(double ta, double tb, int face_lo, int face_hi, double& t0, double& t1, int& face) {
  int fa = face_lo;
  if (ta > tb) {
    std::swap(ta, tb);
    fa = face_hi;
  }
  if (ta > t0) {
    t0 = ta;
    face = fa;
  }
  if (tb < t1) t1 = tb;
  return t0 <= t1;
}

class Scene {
 public:
  // The MiroSot world of a map with FieldGeometry; throws stereoloc::Error when the map has no
  // geometry. `obstacles` are added as prisms (robots) and spheres (balls).
  static Scene fromMap(const FieldMap& map, const std::vector<Obstacle>& obstacles = {});
  // An empty world (maps without geometry): nothing occludes, nothing can be rendered.
  Scene() = default;

  bool empty() const { return prisms_.empty() && spheres_.empty() && strips_.empty(); }
  const std::vector<Prism>& prisms() const { return prisms_; }
  const std::vector<Sphere>& spheres() const { return spheres_; }
  const std::vector<SceneEdge>& edges() const { return edges_; }
  const FieldGeometry& geometry() const { return geometry_; }

  // The nearest solid hit of the ray o + t d with t in (t_min, t_max); the floor counts as solid
  // inside the field and goals (class Floor or Marking) and as Background outside.
  RayHit trace(const Eigen::Vector3d& o, const Eigen::Vector3d& d, double t_min, double t_max) const;
  // Solid objects only (prisms, spheres), with index; used by the renderer's culled loop.
  bool intersectPrism(size_t i, const Eigen::Vector3d& o, const Eigen::Vector3d& d, double t_min, double t_max,
                      RayHit* hit) const;
  bool intersectSphere(size_t i, const Eigen::Vector3d& o, const Eigen::Vector3d& d, double t_min, double t_max,
                       RayHit* hit) const;
  // The floor at (x, y): Floor, Marking, or Background when outside the field and goals.
  SurfaceClass floorClass(double x, double y) const;
  // True only when floorClass is Floor at every point of the rectangle [x0, x1] x [y0, y1] and
  // within 1 mm of it (conservative: false when unsure). The renderer uses it to know, without
  // tracing them, the colour of all rays of an image tile that reach plain floor.
  bool floorIsPlain(double x0, double y0, double x1, double y1) const;
  // (x0, y0, x1, y1) of prism i when it is an axis-aligned box (the walls and goals), whose
  // intersectPrism is a slab test; x0 is NaN otherwise. The renderer repeats that slab test with
  // the ray-independent terms hoisted.
  const Eigen::Vector4d& boxRect(size_t i) const { return box_rects_[i]; }
  // The same by testing every marking (no cell grid): the reference floorClass is tested against.
  SurfaceClass floorClassLinearScan(double x, double y) const;

  // True when a solid object blocks the straight line from `from` to `to` (mm), ignoring the
  // last `tolerance_mm` before `to` (the landmark sits on a surface).
  bool occluded(const Eigen::Vector3d& from, const Eigen::Vector3d& to, double tolerance_mm = 1.0) const;

 private:
  FieldGeometry geometry_;
  std::vector<Prism> prisms_;
  std::vector<Sphere> spheres_;
  std::vector<MarkingStrip> strips_;
  std::vector<Eigen::Vector4d> strip_rects_;  // (xmin, ymin, xmax, ymax) of axis-aligned strips, NaN otherwise
  std::vector<Eigen::Vector4d> box_rects_;    // (x0, y0, x1, y1) of prisms that are axis-aligned boxes in the
                                              // (x0,y0)->(x1,y0)->(x1,y1)->(x0,y1) order, NaN otherwise
  // floorClass's cell grid over the field and goals: the strips (index i) and rings (index
  // strips_.size() + j) that may cover some point of each cell, so that a floor point tests only
  // the markings near it (the renderer calls floorClass for every floor sample).
  double cell_x0_ = 0.0, cell_y0_ = 0.0, cell_size_ = 1.0;
  int cells_nx_ = 0, cells_ny_ = 0;
  std::vector<uint32_t> cell_start_;  // cells_nx_ * cells_ny_ + 1 offsets into cell_items_
  std::vector<uint32_t> cell_items_;
  // Per cell, what floorClass is within 1 mm of it: Floor (no marking near, inside the field or
  // a goal), Background (outside both), or test (onFloor and the cell's markings).
  enum : uint8_t { kCellTest = 0, kCellFloor = 1, kCellBackground = 2 };
  std::vector<uint8_t> cell_state_;
  // fromMap's pieces, in the order it adds them (prisms' order decides equal-distance hits).
  void addWalls();
  void addGoals();
  void addCornerTriangles();
  void addMarkings();
  void addWallAndGoalEdges();
  void addObstacles(const std::vector<Obstacle>& obstacles);
  void precompute();
  bool onFloor(double x, double y) const;  // inside the field or a goal
  bool markingCovers(size_t item, double x, double y) const;  // strip item, or ring item - strips_.size()
  std::vector<MarkingRing> rings_;
  std::vector<SceneEdge> edges_;
};

}  // namespace stereoloc
