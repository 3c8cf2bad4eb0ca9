#pragma once
// The known map: landmarks (id, type, 3D position, uniqueness) and, for the FIRA MiroSot
// field of the thesis, the field geometry the simulator renders.
//
// MiroSot frame: origin at the bottom-left field corner on the floor, x along the length
// (blue goal at x = 0, yellow goal at x = length), y across, z up. mm.
#include <Eigen/Core>
#include <optional>
#include <string>
#include <unordered_map>
#include <vector>

namespace stereoloc {

enum class LandmarkType {
  GoalCorner,     // vertical edge where the white wall meets a coloured goal (colour transition)
  MarkingCorner,  // L corner of two white markings
  Junction,       // T-junction of a marking with the boundary (wall foot)
  Intersection,   // crossing of two markings (e.g. halfway line and centre circle)
  WallCorner,     // foot of the vertical edge where a corner triangle meets a wall
  Point,          // a generic point landmark (e.g. a barcode in real data)
};
std::string toString(LandmarkType type);
// Parses the names written by toString ("goal_corner", ...); throws stereoloc::Error.
LandmarkType landmarkTypeFromString(const std::string& name);

enum class GoalColor { None, Blue, Yellow };
std::string toString(GoalColor color);
GoalColor goalColorFromString(const std::string& name);

struct Landmark {
  int id = -1;
  LandmarkType type = LandmarkType::Point;
  std::string name;                                        // human-readable, e.g. "blue_goal_y450"
  Eigen::Vector3d position = Eigen::Vector3d::Zero();      // mm, world frame
  bool unique = false;                                     // identifiable without a pose prior
  GoalColor color = GoalColor::None;                       // goal corners only
  Eigen::Vector2d xy() const { return position.head<2>(); }
};

// Dimensions of a FIRA MiroSot field (all mm).
struct FieldGeometry {
  double length = 1500.0;
  double width = 1300.0;
  double goal_width = 400.0;
  double goal_depth = 150.0;
  double wall_height = 50.0;
  double corner_triangle = 70.0;     // legs of the isosceles corner triangles
  double line_width = 10.0;          // white markings
  double centre_circle_radius = 250.0;
  double goal_area_depth = 150.0;
  double goal_area_width = 500.0;
  double penalty_area_depth = 350.0;
  double penalty_area_width = 800.0;
  double goal_corner_height = 25.0;  // z given to goal-corner landmarks (any point on the edge)
};

struct Bounds {
  double xmin = 0, ymin = 0, xmax = 0, ymax = 0;  // mm
  bool contains(const Eigen::Vector2d& p, double margin = 0.0) const {
    return p.x() >= xmin - margin && p.x() <= xmax + margin && p.y() >= ymin - margin && p.y() <= ymax + margin;
  }
};

// The dimensions of a MiroSot field that place its landmarks, by their FieldGeometry names: the
// walls' length and width, the goal mouths, the painted markings (goal depth, wall height and
// line width move no landmark). What a field built by hand gets wrong (the simulator's
// field_dimension_sigma_mm) and the batch smoother can estimate (`--calibrate field`).
struct FieldDimension {
  const char* name;
  double FieldGeometry::*ptr;
};
constexpr int kFieldDimensionCount = 9;
extern const FieldDimension kFieldDimensions[kFieldDimensionCount];
using FieldDimensionVector = Eigen::Matrix<double, kFieldDimensionCount, 1>;  // mm, in kFieldDimensions' order
using FieldDimensionMatrix = Eigen::Matrix<double, kFieldDimensionCount, kFieldDimensionCount>;  // mm^2, same order

class FieldMap;
// Whether `map` is FieldMap::miroSot of its own geometry (same ids, types and positions): only
// then do its landmarks follow its dimensions.
bool derivesFromGeometry(const FieldMap& map);

class FieldMap {
 public:
  FieldMap() = default;
  // Validates: ids unique and >= 0, positions finite and inside the bounds (or in a goal).
  FieldMap(std::string name, Bounds bounds, std::vector<Landmark> landmarks,
           std::optional<FieldGeometry> geometry = std::nullopt);

  // The thesis's field: MiroSot Small League, with landmarks derived from the geometry.
  static FieldMap miroSot(const FieldGeometry& geometry = FieldGeometry());

  // YAML through cv::FileStorage. Errors name the file and key, e.g.
  // "map.yaml: landmarks[2].x: not a finite number" or "map.yaml: landmarks[4].id: duplicate id 7".
  static FieldMap load(const std::string& path);
  void save(const std::string& path) const;

  const std::string& name() const { return name_; }
  // The same field with each of kFieldDimensions changed by `change` (mm), the landmarks keeping
  // their ids and names. Throws Error unless derivesFromGeometry().
  FieldMap withDimensionChange(const Eigen::Matrix<double, kFieldDimensionCount, 1>& change) const;
  // The same field stating how well its kFieldDimensions are known (their covariance, mm^2;
  // YAML key dimension_covariance_mm2): a field measured by a drive (`--field-out`), which the
  // next field calibration takes as its prior (fieldPriorCovariance, solvers/calibrated_models.h).
  // Throws Error unless derivesFromGeometry() and the covariance is finite, symmetric and
  // positive definite. withDimensionChange drops it: it describes the field as it was.
  FieldMap withDimensionCovariance(const FieldDimensionMatrix& covariance_mm2) const;
  const std::optional<FieldDimensionMatrix>& dimensionCovariance() const { return dimension_covariance_; }
  // d(x, y)/d(dimensions) of every landmark, by id (exact: a MiroSot field's landmarks are
  // linear in its dimensions). Throws Error unless derivesFromGeometry().
  std::unordered_map<int, Eigen::Matrix<double, 2, kFieldDimensionCount>> fieldJacobians() const;
  const Bounds& bounds() const { return bounds_; }
  const std::vector<Landmark>& landmarks() const { return landmarks_; }
  const std::optional<FieldGeometry>& geometry() const { return geometry_; }

  const Landmark* find(int id) const;       // nullptr when absent
  const Landmark& at(int id) const;         // throws stereoloc::Error when absent
  std::vector<const Landmark*> ofType(LandmarkType type) const;

 private:
  std::string name_;
  Bounds bounds_;
  std::vector<Landmark> landmarks_;
  std::optional<FieldGeometry> geometry_;
  std::optional<FieldDimensionMatrix> dimension_covariance_;
};

}  // namespace stereoloc
