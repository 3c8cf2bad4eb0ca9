#include "src/core/field_map.h"

#include <cmath>
#include <opencv2/core.hpp>
#include <set>

#include "src/core/error.h"
#include "src/core/gaussian.h"
#include "src/core/yaml_util.h"

namespace stereoloc {

std::string toString(LandmarkType type) {
  switch (type) {
    case LandmarkType::GoalCorner: return "goal_corner";
    case LandmarkType::MarkingCorner: return "corner";
    case LandmarkType::Junction: return "junction";
    case LandmarkType::Intersection: return "intersection";
    case LandmarkType::WallCorner: return "wall_corner";
    case LandmarkType::Point: return "point";
  }
  return "point";
}

LandmarkType landmarkTypeFromString(const std::string& name) {
  for (LandmarkType t : {LandmarkType::GoalCorner, LandmarkType::MarkingCorner, LandmarkType::Junction,
                         LandmarkType::Intersection, LandmarkType::WallCorner, LandmarkType::Point})
    if (toString(t) == name) return t;
  throw Error("unknown landmark type '" + name +
              "' (expected goal_corner, corner, junction, intersection, wall_corner or point)");
}

std::string toString(GoalColor color) {
  switch (color) {
    case GoalColor::Blue: return "blue";
    case GoalColor::Yellow: return "yellow";
    case GoalColor::None: return "none";
  }
  return "none";
}

GoalColor goalColorFromString(const std::string& name) {
  if (name == "blue") return GoalColor::Blue;
  if (name == "yellow") return GoalColor::Yellow;
  if (name == "none") return GoalColor::None;
  throw Error("unknown goal colour '" + name + "' (expected blue, yellow or none)");
}

FieldMap::FieldMap(std::string name, Bounds bounds, std::vector<Landmark> landmarks,
                   std::optional<FieldGeometry> geometry)
    : name_(std::move(name)), bounds_(bounds), landmarks_(std::move(landmarks)), geometry_(geometry) {
  if (!(std::isfinite(bounds_.xmin) && std::isfinite(bounds_.xmax) && std::isfinite(bounds_.ymin) &&
        std::isfinite(bounds_.ymax) && bounds_.xmax > bounds_.xmin && bounds_.ymax > bounds_.ymin))
    throw Error("map bounds: must be finite with xmax > xmin and ymax > ymin");
  std::set<int> ids;
  for (size_t i = 0; i < landmarks_.size(); ++i) {
    const Landmark& l = landmarks_[i];
    const std::string where = "landmarks[" + std::to_string(i) + "]";
    if (l.id < 0) throw Error(where + ".id: must be >= 0");
    if (!ids.insert(l.id).second) throw Error(where + ".id: duplicate id " + std::to_string(l.id));
    if (!l.position.allFinite()) throw Error(where + ": position is not finite");
    if (!bounds_.contains(l.xy(), 1e-6)) throw Error(where + ": landmark " + std::to_string(l.id) + " lies outside the map bounds");
    if (l.type == LandmarkType::GoalCorner && l.color == GoalColor::None)
      throw Error(where + ".color: a goal corner needs a colour");
  }
}

const FieldDimension kFieldDimensions[kFieldDimensionCount] = {
    {"length", &FieldGeometry::length},
    {"width", &FieldGeometry::width},
    {"goal_width", &FieldGeometry::goal_width},
    {"corner_triangle", &FieldGeometry::corner_triangle},
    {"centre_circle_radius", &FieldGeometry::centre_circle_radius},
    {"goal_area_depth", &FieldGeometry::goal_area_depth},
    {"goal_area_width", &FieldGeometry::goal_area_width},
    {"penalty_area_depth", &FieldGeometry::penalty_area_depth},
    {"penalty_area_width", &FieldGeometry::penalty_area_width},
};

bool derivesFromGeometry(const FieldMap& map) {
  if (!map.geometry()) return false;
  const FieldMap derived = FieldMap::miroSot(*map.geometry());
  if (derived.landmarks().size() != map.landmarks().size()) return false;
  for (size_t i = 0; i < map.landmarks().size(); ++i) {
    const Landmark &a = map.landmarks()[i], &b = derived.landmarks()[i];
    if (a.id != b.id || a.type != b.type || (a.position - b.position).norm() > 1e-6) return false;
  }
  return true;
}

namespace {
// Only a field whose geometry places its landmarks has dimensions to change or to know.
void requireDimensions(const FieldMap& map) {
  if (!derivesFromGeometry(map))
    throw Error("map '" + map.name() + "': " +
                (map.geometry() ? "has landmarks of its own, not those its field geometry derives"
                                : "has no field geometry"));
}
}  // namespace

FieldMap FieldMap::withDimensionChange(const Eigen::Matrix<double, kFieldDimensionCount, 1>& change) const {
  requireDimensions(*this);
  if (!change.allFinite()) throw Error("map '" + name_ + "': a field dimension change is not finite");
  FieldGeometry g = *geometry_;
  for (int k = 0; k < kFieldDimensionCount; ++k) g.*kFieldDimensions[k].ptr += change[k];
  std::vector<Landmark> landmarks = miroSot(g).landmarks();
  for (size_t i = 0; i < landmarks.size(); ++i) landmarks[i].name = landmarks_[i].name;
  return FieldMap(name_, Bounds{-g.goal_depth, 0.0, g.length + g.goal_depth, g.width}, std::move(landmarks), g);
}

FieldMap FieldMap::withDimensionCovariance(const FieldDimensionMatrix& covariance_mm2) const {
  requireDimensions(*this);
  try {
    sqrtInformationUpper<kFieldDimensionCount>(covariance_mm2, "dimension_covariance_mm2");
  } catch (const Error& e) {
    throw Error("map '" + name_ + "': " + e.what());
  }
  FieldMap out = *this;
  out.dimension_covariance_ = 0.5 * (covariance_mm2 + covariance_mm2.transpose());
  return out;
}

std::unordered_map<int, Eigen::Matrix<double, 2, kFieldDimensionCount>> FieldMap::fieldJacobians() const {
  std::unordered_map<int, Eigen::Matrix<double, 2, kFieldDimensionCount>> J;
  for (int k = 0; k < kFieldDimensionCount; ++k) {  // exact: the positions are linear in the dimensions
    const FieldMap moved = withDimensionChange(Eigen::Matrix<double, kFieldDimensionCount, 1>::Unit(k));
    for (size_t i = 0; i < landmarks_.size(); ++i)
      J[landmarks_[i].id].col(k) = moved.landmarks()[i].xy() - landmarks_[i].xy();
  }
  return J;
}

FieldMap FieldMap::miroSot(const FieldGeometry& g) {
  std::vector<Landmark> lms;
  auto add = [&](LandmarkType type, const std::string& name, double x, double y, double z, bool unique,
                 GoalColor color = GoalColor::None) {
    Landmark l;
    l.id = static_cast<int>(lms.size());
    l.type = type;
    l.name = name;
    l.position = Eigen::Vector3d(x, y, z);
    l.unique = unique;
    l.color = color;
    lms.push_back(l);
  };
  const double cy = 0.5 * g.width, L = g.length;
  auto tag = [](double v) { return std::to_string(static_cast<long>(std::lround(v))); };
  // Goal corners: globally unique by colour and side (thesis 3.6).
  for (double y : {cy - 0.5 * g.goal_width, cy + 0.5 * g.goal_width}) {
    add(LandmarkType::GoalCorner, "blue_goal_y" + tag(y), 0.0, y, g.goal_corner_height, true, GoalColor::Blue);
    add(LandmarkType::GoalCorner, "yellow_goal_y" + tag(y), L, y, g.goal_corner_height, true, GoalColor::Yellow);
  }
  // Goal-area and penalty-area corners (L) and their T-junctions with the goal-line walls.
  struct Area {
    const char* name;
    double depth, width;
  };
  for (const Area& a : {Area{"goal_area", g.goal_area_depth, g.goal_area_width},
                        Area{"penalty_area", g.penalty_area_depth, g.penalty_area_width}}) {
    for (double y : {cy - 0.5 * a.width, cy + 0.5 * a.width}) {
      add(LandmarkType::MarkingCorner, std::string("blue_") + a.name + "_corner_y" + tag(y), a.depth, y, 0.0, false);
      add(LandmarkType::MarkingCorner, std::string("yellow_") + a.name + "_corner_y" + tag(y), L - a.depth, y, 0.0, false);
      add(LandmarkType::Junction, std::string("blue_") + a.name + "_junction_y" + tag(y), 0.0, y, 0.0, false);
      add(LandmarkType::Junction, std::string("yellow_") + a.name + "_junction_y" + tag(y), L, y, 0.0, false);
    }
  }
  // Halfway line: T-junctions with the side walls and crossings with the centre circle.
  add(LandmarkType::Junction, "halfway_junction_y0", 0.5 * L, 0.0, 0.0, false);
  add(LandmarkType::Junction, "halfway_junction_y" + tag(g.width), 0.5 * L, g.width, 0.0, false);
  add(LandmarkType::Intersection, "halfway_circle_y" + tag(cy - g.centre_circle_radius), 0.5 * L,
      cy - g.centre_circle_radius, 0.0, false);
  add(LandmarkType::Intersection, "halfway_circle_y" + tag(cy + g.centre_circle_radius), 0.5 * L,
      cy + g.centre_circle_radius, 0.0, false);
  // Corner triangles meet the walls at distance corner_triangle from each field corner.
  const double t = g.corner_triangle;
  for (auto [x, y] : {std::pair{t, 0.0}, std::pair{0.0, t}, std::pair{L - t, 0.0}, std::pair{L, t},
                      std::pair{0.0, g.width - t}, std::pair{t, g.width}, std::pair{L, g.width - t},
                      std::pair{L - t, g.width}})
    add(LandmarkType::WallCorner, "wall_corner_x" + tag(x) + "_y" + tag(y), x, y, 0.0, false);
  Bounds b{-g.goal_depth, 0.0, L + g.goal_depth, g.width};
  return FieldMap("FIRA MiroSot Small League", b, std::move(lms), g);
}

const Landmark* FieldMap::find(int id) const {
  for (const Landmark& l : landmarks_)
    if (l.id == id) return &l;
  return nullptr;
}

const Landmark& FieldMap::at(int id) const {
  const Landmark* l = find(id);
  if (!l) throw Error("map '" + name_ + "': unknown landmark id " + std::to_string(id));
  return *l;
}

std::vector<const Landmark*> FieldMap::ofType(LandmarkType type) const {
  std::vector<const Landmark*> out;
  for (const Landmark& l : landmarks_)
    if (l.type == type) out.push_back(&l);
  return out;
}

FieldMap FieldMap::load(const std::string& path) {
  YamlReader in(path);
  const std::string name = in.getString("name");
  const YamlNode b = in.child("bounds");
  Bounds bounds{b.getDouble("xmin"), b.getDouble("ymin"), b.getDouble("xmax"), b.getDouble("ymax")};
  std::optional<FieldGeometry> geometry;
  if (in.has("geometry")) {
    const YamlNode g = in.child("geometry");
    const std::string kind = g.getString("kind");
    if (kind != "mirosot") g.fail("kind", "unknown geometry kind '" + kind + "' (expected mirosot)");
    FieldGeometry fg;
    double* fields[] = {&fg.length, &fg.width, &fg.goal_width, &fg.goal_depth, &fg.wall_height,
                        &fg.corner_triangle, &fg.line_width, &fg.centre_circle_radius, &fg.goal_area_depth,
                        &fg.goal_area_width, &fg.penalty_area_depth, &fg.penalty_area_width, &fg.goal_corner_height};
    const char* keys[] = {"length", "width", "goal_width", "goal_depth", "wall_height", "corner_triangle",
                          "line_width", "centre_circle_radius", "goal_area_depth", "goal_area_width",
                          "penalty_area_depth", "penalty_area_width", "goal_corner_height"};
    for (size_t i = 0; i < sizeof(keys) / sizeof(keys[0]); ++i) {
      *fields[i] = g.getDouble(keys[i]);
      // Ten metres bound the MiroSot fields (the large league's is 4 m) and what a renderer can grid.
      if (!(*fields[i] > 0 && *fields[i] <= 10000.0)) g.fail(keys[i], "must be within (0, 10000] mm");
    }
    geometry = fg;
  }
  const YamlNode list = in.child("landmarks");
  if (!list.node().isSeq()) list.fail("", "must be a sequence");
  std::vector<Landmark> lms;
  for (size_t i = 0; i < list.size(); ++i) {
    const YamlNode n = list.at(i);
    Landmark l;
    l.id = n.getInt("id");
    try {
      l.type = landmarkTypeFromString(n.getString("type"));
      l.color = goalColorFromString(n.getString("color", "none"));
    } catch (const Error& e) {
      n.fail("type", e.what());
    }
    l.name = n.getString("name", "");
    l.position = Eigen::Vector3d(n.getDouble("x"), n.getDouble("y"), n.getDouble("z", 0.0));
    l.unique = n.getBool("unique", false);
    lms.push_back(l);
  }
  std::optional<FieldDimensionMatrix> covariance;
  if (in.has("dimension_covariance_mm2")) {
    const YamlNode n = in.child("dimension_covariance_mm2");
    if (!geometry) n.fail("", "needs the field's geometry");
    cv::Mat m;
    try {
      n.node() >> m;
    } catch (const cv::Exception&) {
      m.release();
    }
    if (m.rows != kFieldDimensionCount || m.cols != kFieldDimensionCount || m.type() != CV_64F)
      n.fail("", "must be a 9 x 9 matrix of reals (the dimensions in kFieldDimensions' order)");
    FieldDimensionMatrix c;
    for (int i = 0; i < kFieldDimensionCount; ++i)
      for (int j = 0; j < kFieldDimensionCount; ++j) c(i, j) = m.at<double>(i, j);
    covariance = c;
  }
  try {
    FieldMap map(name, bounds, std::move(lms), geometry);
    return covariance ? map.withDimensionCovariance(*covariance) : map;
  } catch (const Error& e) {
    throw Error(path + ": " + e.what());
  }
}

void FieldMap::save(const std::string& path) const {
  YamlWriter out;
  out.comment("stereoloc field map. Units: mm. Frame: origin at the bottom-left field corner, x along the length.");
  cv::FileStorage& fs = out.fs();
  fs << "name" << name_;
  fs << "bounds" << "{" << "xmin" << bounds_.xmin << "ymin" << bounds_.ymin << "xmax" << bounds_.xmax << "ymax"
     << bounds_.ymax << "}";
  if (geometry_) {
    const FieldGeometry& g = *geometry_;
    fs << "geometry" << "{" << "kind" << "mirosot" << "length" << g.length << "width" << g.width << "goal_width"
       << g.goal_width << "goal_depth" << g.goal_depth << "wall_height" << g.wall_height << "corner_triangle"
       << g.corner_triangle << "line_width" << g.line_width << "centre_circle_radius" << g.centre_circle_radius
       << "goal_area_depth" << g.goal_area_depth << "goal_area_width" << g.goal_area_width << "penalty_area_depth"
       << g.penalty_area_depth << "penalty_area_width" << g.penalty_area_width << "goal_corner_height"
       << g.goal_corner_height << "}";
  }
  if (dimension_covariance_) {
    cv::Mat m(kFieldDimensionCount, kFieldDimensionCount, CV_64F);
    for (int i = 0; i < kFieldDimensionCount; ++i)
      for (int j = 0; j < kFieldDimensionCount; ++j) m.at<double>(i, j) = (*dimension_covariance_)(i, j);
    fs << "dimension_covariance_mm2" << m;
  }
  fs << "landmarks" << "[";
  for (const Landmark& l : landmarks_) {
    fs << "{:" << "id" << l.id << "type" << toString(l.type) << "name" << l.name << "x" << l.position.x() << "y"
       << l.position.y() << "z" << l.position.z() << "unique" << (l.unique ? 1 : 0) << "color" << toString(l.color)
       << "}";
  }
  fs << "]";
  out.writeAtomically(path);
}

}  // namespace stereoloc
