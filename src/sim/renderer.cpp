#include "src/sim/renderer.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <optional>
#include <opencv2/imgproc.hpp>
#include <random>
#include <thread>
#include <tuple>

#include "src/core/atomic_file.h"
#include "src/io/csv.h"
#include "src/io/dataset.h"
#include "src/io/image_file.h"
#include "src/core/error.h"
#include "src/sim/raw_render.h"
#include "src/sim/simulator.h"

namespace stereoloc {
namespace {

// Two colours (0..1 per channel) differ when a channel differs by more than a fifth of a grey
// level: surfaces are flat-shaded, so samples on one surface are identical.
constexpr float kColourTolerance = 0.2f / 255.0f;

// World <- C2 rotation for a robot pose and head pan (tilt included).
Eigen::Matrix3d visionToWorldRotation(const StereoRig& rig, const Pose2& robot, double pan) {
  const Eigen::Vector3d o = rig.visionToRobot(Eigen::Vector3d::Zero(), pan);
  Eigen::Matrix3d R_robot_vision;
  for (int k = 0; k < 3; ++k) R_robot_vision.col(k) = rig.visionToRobot(Eigen::Vector3d::Unit(k), pan) - o;
  const double c = std::cos(robot.theta), s = std::sin(robot.theta);
  Eigen::Matrix3d Rz;
  Rz << c, -s, 0, s, c, 0, 0, 0, 1;
  return Rz * R_robot_vision;
}

struct Box {
  int u0, u1, v0, v1;  // inclusive pixel range that may see the object
};

// Image-space bounding box of a convex object, given as the vertices and edges of a polytope
// holding it (world frame), seen from a camera: the projections of the vertices in front of the
// plane x = 1 mm (camera frame) and of the edges' crossings of that plane. Nothing behind the
// plane: invisible. An object crossing the plane but farther than `near_mm` from the camera
// (near_mm bounds the distance of a sample ray's points with x < 1 mm) is hit, if at all, in
// front of the plane, so the box holds it. The whole image when it comes nearer.
Box projectBox(const std::vector<Eigen::Vector3d>& pts, const std::vector<std::pair<int, int>>& edges,
               const Eigen::Vector3d& cam, const Eigen::Matrix3d& Rwv, double f, double ou, double ov, int W, int H,
               double near_mm) {
  constexpr double kPlane = 1.0;  // mm
  double umin = 1e300, umax = -1e300, vmin = 1e300, vmax = -1e300;
  bool any_front = false, any_behind = false;
  auto add = [&](const Eigen::Vector3d& q) {
    const double u = ou - f * q.y() / q.x(), v = ov - f * q.z() / q.x();
    umin = std::min(umin, u);
    umax = std::max(umax, u);
    vmin = std::min(vmin, v);
    vmax = std::max(vmax, v);
  };
  std::vector<Eigen::Vector3d> q(pts.size());
  Eigen::Vector3d lo = pts.front(), hi = pts.front();
  for (size_t k = 0; k < pts.size(); ++k) {
    q[k] = Rwv.transpose() * (pts[k] - cam);
    lo = lo.cwiseMin(pts[k]);
    hi = hi.cwiseMax(pts[k]);
    if (q[k].x() < kPlane) {
      any_behind = true;
      continue;
    }
    any_front = true;
    add(q[k]);
  }
  if (!any_front) return {1, 0, 1, 0};
  if (any_behind) {
    const double distance = (cam.cwiseMax(lo).cwiseMin(hi) - cam).norm();  // to the bounding box
    if (!(distance > near_mm)) return {-1, W, -1, H};
    for (const auto& [a, b] : edges) {
      const Eigen::Vector3d& qa = q[static_cast<size_t>(a)];
      const Eigen::Vector3d& qb = q[static_cast<size_t>(b)];
      if ((qa.x() < kPlane) != (qb.x() < kPlane)) add(qa + (kPlane - qa.x()) / (qb.x() - qa.x()) * (qb - qa));
    }
  }
  Box b;
  b.u0 = static_cast<int>(std::max(-1.0, std::floor(umin - 1.0)));
  b.u1 = static_cast<int>(std::min(static_cast<double>(W), std::ceil(umax + 1.0)));
  b.v0 = static_cast<int>(std::max(-1.0, std::floor(vmin - 1.0)));
  b.v1 = static_cast<int>(std::min(static_cast<double>(H), std::ceil(vmax + 1.0)));
  return b;
}

// An axis-aligned box seen from one camera (see render).
struct SlabBox {
  std::array<double, 6> rel;        // x0, x1, y0, y1, zmin, zmax minus the camera's x, x, y, y, z, z
  std::array<Colour, 6> colour;     // faces -y, +x, +y, -x, top, bottom
};

// A run [previous span's u_end, u_end) of pixels of one image row with the same object lists,
// as [begin, end) offsets into one item array.
struct Span {
  int u_end = 0;
  uint32_t all = 0, all_end = 0, inside = 0, inside_end = 0, high = 0, high_end = 0;
};

Colour surfaceColour(const RayHit& h, const SceneColours& c, bool shading) {
  Colour base;
  switch (h.cls) {
    case SurfaceClass::Background: base = c.background; break;
    case SurfaceClass::Floor: base = c.floor; break;
    case SurfaceClass::Marking: base = c.marking; break;
    case SurfaceClass::Wall: base = h.normal.z() > 0.5 ? c.wall_top : c.wall; break;
    case SurfaceClass::BlueGoal: base = c.blue_goal; break;
    case SurfaceClass::YellowGoal: base = c.yellow_goal; break;
    case SurfaceClass::Robot: base = h.normal.z() > 0.5 ? c.robot_top : c.robot; break;
    case SurfaceClass::Ball: base = c.ball; break;
  }
  if (shading && h.cls != SurfaceClass::Background && h.cls != SurfaceClass::Floor && h.cls != SurfaceClass::Marking) {
    // A fixed overhead light, slightly from +x +y: vertical faces a little darker than tops.
    static const Eigen::Vector3d light = Eigen::Vector3d(0.3, 0.2, 1.0).normalized();
    const double k = 0.75 + 0.25 * std::max(0.0, h.normal.dot(light));
    base *= static_cast<float>(k);
  }
  return base;
}

std::string jsonString(const std::string& s) {
  std::string out = "\"";
  for (char ch : s) {
    if (ch == '"' || ch == '\\') out += '\\';
    out += ch;
  }
  return out + "\"";
}

// The outline of the wall and goal tops where they meet the background (their outer top
// edges). Seen from the field with the camera above the walls (70 mm vs 50 mm), the top face is
// visible and this outline is the wall's silhouette against the background, the strongest edge
// of the wall; the scene's edges hold only the inner top edges (towards the floor). Every top
// polygon edge of the static scene is sampled every 5 mm; a sample is on the outline when the
// point 1 mm outside it is background floor and inside no other prism (so shared faces of the
// 300 mm wall pieces and of walls and goals drop out). Collinear touching runs are joined.
std::vector<SceneEdge> topOutlineEdges(const Scene& scene) {
  const auto& prisms = scene.prisms();
  auto insidePrism = [&](const Prism& p, const Eigen::Vector2d& q) {
    for (size_t i = 0; i < p.polygon.size(); ++i) {
      const Eigen::Vector2d& a = p.polygon[i];
      const Eigen::Vector2d& b = p.polygon[(i + 1) % p.polygon.size()];
      if ((b - a).x() * (q - a).y() - (b - a).y() * (q - a).x() < 0) return false;
    }
    return true;
  };
  std::vector<SceneEdge> runs;
  for (size_t pi = 0; pi < prisms.size(); ++pi) {
    const Prism& p = prisms[pi];
    const size_t n = p.polygon.size();
    for (size_t i = 0; i < n; ++i) {
      const Eigen::Vector2d a = p.polygon[i], b = p.polygon[(i + 1) % n];
      const double len = (b - a).norm();
      if (!(len > 0)) continue;
      const Eigen::Vector2d dir = (b - a) / len, out(dir.y(), -dir.x());  // counter-clockwise: outward
      const int samples = std::max(2, static_cast<int>(std::ceil(len / 5.0)));
      auto onOutline = [&](double s) {
        const Eigen::Vector2d q = a + s * (b - a) + out;
        if (scene.floorClass(q.x(), q.y()) != SurfaceClass::Background) return false;
        for (size_t pj = 0; pj < prisms.size(); ++pj)
          if (pj != pi && prisms[pj].zmax >= p.zmax && insidePrism(prisms[pj], q)) return false;
        return true;
      };
      double start = -1;
      for (int k = 0; k <= samples; ++k) {
        const double s = static_cast<double>(k) / samples;
        const bool on = onOutline(std::clamp(s, 0.01, 0.99));
        if (on && start < 0) start = s;
        if ((!on || k == samples) && start >= 0) {
          const double end = on ? s : static_cast<double>(k - 1) / samples;
          if (end > start) {
            const Eigen::Vector2d pa = a + start * (b - a), pb = a + end * (b - a);
            runs.push_back({"top_outline", "top_outline", {pa.x(), pa.y(), p.zmax}, {pb.x(), pb.y(), p.zmax}});
          }
          start = -1;
        }
      }
    }
  }
  // Join collinear runs that touch (the wall pieces).
  bool joined = true;
  while (joined) {
    joined = false;
    for (size_t i = 0; i < runs.size() && !joined; ++i)
      for (size_t j = i + 1; j < runs.size() && !joined; ++j) {
        SceneEdge& e = runs[i];
        const SceneEdge& f = runs[j];
        if (e.a.z() != f.a.z()) continue;
        const Eigen::Vector3d d = (e.b - e.a).normalized();
        auto off = [&](const Eigen::Vector3d& q) { return (q - e.a - d * d.dot(q - e.a)).norm(); };
        if (off(f.a) > 1e-6 || off(f.b) > 1e-6) continue;
        const double ta = 0, tb = d.dot(e.b - e.a), fa = d.dot(f.a - e.a), fb = d.dot(f.b - e.a);
        if (std::min(fa, fb) > tb + 1e-6 || std::max(fa, fb) < ta - 1e-6) continue;
        const double lo = std::min({ta, fa, fb}), hi = std::max({tb, fa, fb});
        const Eigen::Vector3d a0 = e.a;
        e.a = a0 + lo * d;
        e.b = a0 + hi * d;
        runs.erase(runs.begin() + static_cast<long>(j));
        joined = true;
      }
  }
  for (size_t i = 0; i < runs.size(); ++i) runs[i].name = "top_outline_" + std::to_string(i);
  return runs;
}

// The sample ray directions of a rig in C2 (StereoRenderer's per-column and per-row tables).
struct SampleRays {
  const std::vector<float>& base_y;
  const std::vector<float>& base_z;
  const std::vector<float>& fine_y;
  const std::vector<float>& fine_z;
};

// Image tiles whose every sample ray is known without tracing it. A tile's sample rays lie in
// the pyramid of the rays through its corners (grown by kTileMargin px, far more than the
// float rounding of the sample rays, ~1e-4 px). Where all four corner rays descend, a ray's
// floor point (and its point at the wall-top height) is a projective image of its pixel
// position that keeps convexity, so those points of every sample ray lie in the convex hull
// of the corners' points:
// - Column: the corner points lie inside the open field (1e-2 mm margin), so every ray is
//   in the column the per-ray test of ViewRender::shade would find; that test is skipped.
// - Floor: also no object not outside the field overlaps the tile and the floor under the
//   corners' bounding rectangle is plain: every sample is floor colour.
// - Sky: all four corner rays ascend and no object reaching above the camera overlaps the
//   tile: every sample is background.
// Other tiles trace every ray. The images are the same either way.
enum class TileMode : uint8_t { Traced, Column, Floor, Sky };
constexpr int kTile = 4;

// One camera's image of one view (StereoRenderer::renderView). The constructor builds the
// per-view state phase by phase, each phase reading what the earlier ones built; render() then
// runs pass 1 (base samples) and pass 2 (edge refinement) over the rows, and the illumination
// and blur.
class ViewRender {
 public:
  ViewRender(const Scene& scene, const StereoRig& rig, const RenderOptions& options, const SampleRays& rays,
             const Pose2& robot, double head_pan, int camera, const StereoRenderer::ColumnRanges* needed);
  cv::Mat render() const;

 private:
  void columnRanges();
  void imageBoxes();
  void cullingFacts();
  void slabBoxes();
  void uniformColours();
  void rowSpans();
  void classifyTiles();
  void settleTiles();
  TileMode tileMode(int u, int v) const {
    return tiles_[static_cast<size_t>(v / kTile) * tiles_x_ + u / kTile];
  }
  Colour shade(const Eigen::Vector3d& d, const Span& span, bool column) const;
  void baseRows(int first_row, int step, std::vector<Colour>& mean, std::vector<uint8_t>& mixed) const;
  void renderRows(int first_row, int step, const std::vector<Colour>& mean, const std::vector<uint8_t>& mixed,
                  cv::Mat& img) const;
  void runRows(const std::function<void(int, int)>& rows) const;
  void illuminateAndBlur(cv::Mat& img) const;

  const Scene& scene_;
  const RenderOptions& options_;
  const SampleRays rays_;
  const StereoRenderer::ColumnRanges* needed_;
  const FieldGeometry& g_;
  const int W_, H_, n_, spp_, fine_;
  const bool nested_;
  const int fine_step_;
  const double f_, ou_, ov_;
  const Eigen::Matrix3d Rwv_;
  const Eigen::Matrix3f Rf_;
  const size_t n_prisms_;
  const Eigen::Vector3d cam_;
  // Phase 1: columns [first, last) of each row that pass 2 writes and that pass 1 samples.
  std::vector<std::pair<int, int>> write_cols_, base_cols_;
  // Phases 2-3: per object, its image box and whether it is low / outside the field.
  std::vector<Box> boxes_;
  std::vector<uint8_t> low_, outside_;
  double outside_top_ = 0.0;
  bool cam_above_outside_ = false;
  // Phase 4: slab_of_[b] indexes slabs_, -1 for objects that are not axis-aligned boxes.
  std::vector<int> slab_of_;
  std::vector<SlabBox> slabs_;
  // Colours of the untraced surfaces and the pixel values of uniform pixels.
  Colour background_, floor_, marking_, floor_mean_, sky_mean_;
  cv::Vec3b floor_bgr_, sky_bgr_;
  std::vector<uint8_t> on_base_;
  // Phase 5: the spans of every row (row v: [row_first_span_[v], row_first_span_[v + 1])) and
  // the object lists they index.
  std::vector<Span> spans_;
  std::vector<uint32_t> row_first_span_, items_;
  // Phases 6-7: per tile (row-major, tiles_x_ per row) its mode and whether it is settled.
  int tiles_x_ = 0, tiles_y_ = 0;
  std::vector<TileMode> tiles_;
  std::vector<uint8_t> settled_;
};

cv::Vec3b toBgr(Colour c) {
  c *= 255.0f;
  return cv::Vec3b(cv::saturate_cast<uchar>(c.z()), cv::saturate_cast<uchar>(c.y()), cv::saturate_cast<uchar>(c.x()));
}

ViewRender::ViewRender(const Scene& scene, const StereoRig& rig, const RenderOptions& options, const SampleRays& rays,
                       const Pose2& robot, double head_pan, int camera, const StereoRenderer::ColumnRanges* needed)
    : scene_(scene),
      options_(options),
      rays_(rays),
      needed_(needed),
      g_(scene.geometry()),
      W_(rig.params().image_width),
      H_(rig.params().image_height),
      n_(options.samples_per_axis),
      spp_(n_ * n_),
      fine_(options.edge_samples_per_axis),
      nested_(fine_ > 0 && fine_ % n_ == 0),
      fine_step_(nested_ ? fine_ / n_ : 1),
      f_(rig.focal()),
      ou_(rig.principalU()),
      ov_(rig.principalV()),
      Rwv_(visionToWorldRotation(rig, robot, head_pan)),
      Rf_(Rwv_.cast<float>()),
      n_prisms_(scene.prisms().size()),
      cam_(cameraCentreWorld(rig, robot, head_pan, camera)) {
  columnRanges();
  imageBoxes();
  cullingFacts();
  slabBoxes();
  uniformColours();
  rowSpans();
  classifyTiles();
  settleTiles();
}

// Columns [first, last) of each row that pass 2 writes (`needed`, else all), and those pass 1
// samples: pass 2 reads the base mean of a pixel and of its 4-neighbours.
void ViewRender::columnRanges() {
  const int W = W_, H = H_;
  write_cols_.assign(static_cast<size_t>(H), {0, W});
  base_cols_ = write_cols_;
  if (!needed_) return;
  auto clampRange = [W](std::pair<int, int> r) {
    r.first = std::clamp(r.first, 0, W);
    r.second = std::clamp(r.second, 0, W);
    return r.first < r.second ? r : std::pair<int, int>(0, 0);
  };
  for (int v = 0; v < H; ++v) write_cols_[static_cast<size_t>(v)] = clampRange((*needed_)[static_cast<size_t>(v)]);
  for (int v = 0; v < H; ++v) {
    std::pair<int, int> b(W, 0);
    auto join = [&](std::pair<int, int> r) {
      if (r.first >= r.second) return;
      b.first = std::min(b.first, r.first);
      b.second = std::max(b.second, r.second);
    };
    const std::pair<int, int> own = write_cols_[static_cast<size_t>(v)];
    if (own.first < own.second) join({own.first - 1, own.second + 1});
    if (v > 0) join(write_cols_[static_cast<size_t>(v) - 1]);
    if (v + 1 < H) join(write_cols_[static_cast<size_t>(v) + 1]);
    base_cols_[static_cast<size_t>(v)] = clampRange(b);
  }
}

// Per-object image bounding boxes (culling). A sample ray at x < 1 mm (camera frame) is
// within x * near_factor of the camera (its image point lies in the image, grown 1 px).
void ViewRender::imageBoxes() {
  const int W = W_, H = H_;
  const double f = f_, ou = ou_, ov = ov_;
  const double near_factor = std::hypot(1.0, (std::max(ou, W - 1 - ou) + 1.5) / f, (std::max(ov, H - 1 - ov) + 1.5) / f);
  const double near_mm = 2.0 * near_factor;
  for (const Prism& p : scene_.prisms()) {
    std::vector<Eigen::Vector3d> pts;
    std::vector<std::pair<int, int>> edges;
    const int m = static_cast<int>(p.polygon.size());
    for (int k = 0; k < m; ++k) {
      const Eigen::Vector2d& c = p.polygon[static_cast<size_t>(k)];
      pts.emplace_back(c.x(), c.y(), p.zmin);
      pts.emplace_back(c.x(), c.y(), p.zmax);
      const int next = (k + 1) % m;
      edges.insert(edges.end(), {{2 * k, 2 * k + 1}, {2 * k, 2 * next}, {2 * k + 1, 2 * next + 1}});
    }
    boxes_.push_back(projectBox(pts, edges, cam_, Rwv_, f, ou, ov, W, H, near_mm));
  }
  for (const Sphere& s : scene_.spheres()) {
    // Its bounding cube: corners k (bit i: + or - along axis i), edges between corners one bit apart.
    std::vector<Eigen::Vector3d> pts;
    std::vector<std::pair<int, int>> edges;
    for (int k = 0; k < 8; ++k) {
      pts.push_back(s.centre + s.radius * Eigen::Vector3d(k & 1 ? 1 : -1, k & 2 ? 1 : -1, k & 4 ? 1 : -1));
      for (int bit = 1; bit < 8; bit <<= 1)
        if (!(k & bit)) edges.emplace_back(k, k | bit);
    }
    boxes_.push_back(projectBox(pts, edges, cam_, Rwv_, f, ou, ov, W, H, near_mm));
  }
}

// Ray-independent culling facts per object: `low` objects lie entirely below the camera, so
// a ray that does not descend misses them; `outside` objects (walls, goals) lie outside the
// open field, so a descending ray whose path from the wall-top height down to the floor
// stays above the field cannot hit them (the field is convex).
void ViewRender::cullingFacts() {
  low_.assign(boxes_.size(), 0);
  outside_.assign(boxes_.size(), 0);
  for (size_t b = 0; b < n_prisms_; ++b) {
    const Prism& p = scene_.prisms()[b];
    low_[b] = p.zmax < cam_.z();
    double x0 = 1e300, x1 = -1e300, y0 = 1e300, y1 = -1e300;
    for (const Eigen::Vector2d& q : p.polygon) {
      x0 = std::min(x0, q.x());
      x1 = std::max(x1, q.x());
      y0 = std::min(y0, q.y());
      y1 = std::max(y1, q.y());
    }
    outside_[b] = x1 <= 0.0 || x0 >= g_.length || y1 <= 0.0 || y0 >= g_.width;
    if (outside_[b]) outside_top_ = std::max(outside_top_, p.zmax);
  }
  cam_above_outside_ = cam_.z() > outside_top_;
}

// Axis-aligned boxes (walls, goals: most tested objects) get Scene::intersectPrism's slab test
// inline, with the ray-independent differences (bound - camera) and the face colours computed
// once here and 1 / d once per ray instead of per box. Same operations on the same values: the
// same hits. slab_of_[b] indexes `slabs_`, -1 for other objects.
void ViewRender::slabBoxes() {
  slab_of_.assign(boxes_.size(), -1);
  for (size_t b = 0; b < n_prisms_; ++b) {
    const Eigen::Vector4d& r = scene_.boxRect(b);
    if (std::isnan(r[0])) continue;
    const Prism& p = scene_.prisms()[b];
    SlabBox s;
    s.rel = {r[0] - cam_.x(), r[2] - cam_.x(), r[1] - cam_.y(), r[3] - cam_.y(), p.zmin - cam_.z(), p.zmax - cam_.z()};
    static const Eigen::Vector3d normals[6] = {{0, -1, 0}, {1, 0, 0}, {0, 1, 0}, {-1, 0, 0}, {0, 0, 1}, {0, 0, -1}};
    for (int face = 0; face < 6; ++face) {
      RayHit h;
      h.cls = face < 4 ? p.side[face] : face == 4 ? p.top : p.bottom;
      h.normal = normals[face];
      s.colour[face] = surfaceColour(h, options_.colours, options_.shading);
    }
    slab_of_[b] = static_cast<int>(slabs_.size());
    slabs_.push_back(s);
  }
}

// The colours of the surfaces shade() does not take from a hit, and the values of pixels whose
// samples are all floor or all background.
void ViewRender::uniformColours() {
  auto classColour = [&](SurfaceClass cls) {
    RayHit h;
    h.cls = cls;
    h.normal = Eigen::Vector3d(0, 0, 1);
    return surfaceColour(h, options_.colours, options_.shading);
  };
  background_ = classColour(SurfaceClass::Background);
  floor_ = classColour(SurfaceClass::Floor);
  marking_ = classColour(SurfaceClass::Marking);
  // The mean of a pixel whose base samples all have colour c, summed as for traced samples.
  auto uniformMean = [&](const Colour& c) {
    Colour sum = Colour::Zero();
    for (int k = 0; k < spp_; ++k) sum += c;
    return Colour(sum / static_cast<float>(spp_));
  };
  floor_mean_ = uniformMean(floor_);
  sky_mean_ = uniformMean(background_);
  floor_bgr_ = toBgr(floor_mean_);
  sky_bgr_ = toBgr(sky_mean_);
  // Which points of the edge grid are base samples (their colour is in the pixel's mean).
  on_base_.assign(static_cast<size_t>(std::max(fine_, 0)), 0);
  for (int j = 0; j < fine_; ++j) on_base_[static_cast<size_t>(j)] = nested_ && j % fine_step_ == fine_step_ / 2;
}

// The objects a sample ray of pixel (u, v) may hit: those whose image box holds the pixel, in
// object order (the order decides equal-distance hits), and of them the ones not outside the
// field and the ones not below the camera (see cullingFacts). The lists change only where some
// box starts or ends, so each row is cut into spans that share them (instead of filtering every
// object for every pixel and pass).
void ViewRender::rowSpans() {
  const int W = W_, H = H_;
  row_first_span_.assign(static_cast<size_t>(H) + 1, 0);
  for (int v = 0; v < H; ++v) {
    std::vector<size_t> row_objects;
    std::vector<int> cuts = {0, W};
    for (size_t b = 0; b < boxes_.size(); ++b)
      if (v >= boxes_[b].v0 && v <= boxes_[b].v1) {
        row_objects.push_back(b);
        cuts.push_back(std::clamp(boxes_[b].u0, 0, W));
        cuts.push_back(std::clamp(boxes_[b].u1 + 1, 0, W));
      }
    std::sort(cuts.begin(), cuts.end());
    cuts.erase(std::unique(cuts.begin(), cuts.end()), cuts.end());
    for (size_t c = 0; c + 1 < cuts.size(); ++c) {
      const int u = cuts[c];
      Span s;
      s.u_end = cuts[c + 1];
      auto add = [&](auto keep) {
        const uint32_t first = static_cast<uint32_t>(items_.size());
        for (size_t b : row_objects)
          if (u >= boxes_[b].u0 && u <= boxes_[b].u1 && keep(b)) items_.push_back(static_cast<uint32_t>(b));
        return std::pair<uint32_t, uint32_t>(first, static_cast<uint32_t>(items_.size()));
      };
      std::tie(s.all, s.all_end) = add([](size_t) { return true; });
      std::tie(s.inside, s.inside_end) = add([&](size_t b) { return !outside_[b]; });
      std::tie(s.high, s.high_end) = add([&](size_t b) { return !low_[b]; });
      spans_.push_back(s);
    }
    row_first_span_[static_cast<size_t>(v) + 1] = static_cast<uint32_t>(spans_.size());
  }
}

// The mode of every tile (see TileMode).
void ViewRender::classifyTiles() {
  const int W = W_, H = H_;
  const double f = f_, ou = ou_, ov = ov_;
  constexpr double kTileMargin = 0.05, kFieldMargin = 1e-2, kDirection = 1e-9;
  tiles_x_ = (W + kTile - 1) / kTile;
  tiles_y_ = (H + kTile - 1) / kTile;
  const int tiles_x = tiles_x_, tiles_y = tiles_y_;
  tiles_.assign(static_cast<size_t>(tiles_x) * tiles_y, TileMode::Traced);
  // Per tile: does the image box of an object above the camera (bit 0) / not outside the field
  // (bit 1) overlap it. Marked box by box (testing every object for every tile was 2.4 M
  // instructions per pair, serial).
  std::vector<uint8_t> overlap(tiles_.size(), 0);
  for (size_t b = 0; b < boxes_.size(); ++b) {
    const Box& box = boxes_[b];
    const uint8_t bits = static_cast<uint8_t>((low_[b] ? 0 : 1) | (outside_[b] ? 0 : 2));
    if (bits == 0 || box.u0 > std::min(box.u1, W - 1) || box.v0 > std::min(box.v1, H - 1) || box.u1 < 0 || box.v1 < 0)
      continue;  // off the image
    const int tx0 = std::max(0, box.u0) / kTile, tx1 = std::min(W - 1, box.u1) / kTile;
    const int ty0 = std::max(0, box.v0) / kTile, ty1 = std::min(H - 1, box.v1) / kTile;
    for (int ty = ty0; ty <= ty1; ++ty)
      for (int tx = tx0; tx <= tx1; ++tx) overlap[static_cast<size_t>(ty) * tiles_x + tx] |= bits;
  }
  if (options_.reference_tracing) return;
  for (int ty = 0; ty < tiles_y; ++ty)
    for (int tx = 0; tx < tiles_x; ++tx) {
      const int u0 = tx * kTile, u1 = std::min(W, u0 + kTile) - 1, v0 = ty * kTile, v1 = std::min(H, v0 + kTile) - 1;
      bool all_down = true, all_up = true, in_field = cam_above_outside_;
      double x_lo = 1e300, x_hi = -1e300, y_lo = 1e300, y_hi = -1e300;
      for (int corner = 0; corner < 4; ++corner) {
        const double su = (corner & 1) ? u1 + 0.5 + kTileMargin : u0 - 0.5 - kTileMargin;
        const double sv = (corner & 2) ? v1 + 0.5 + kTileMargin : v0 - 0.5 - kTileMargin;
        const Eigen::Vector3d d = Rwv_ * Eigen::Vector3d(1.0, -(su - ou) / f, -(sv - ov) / f);
        all_down = all_down && d.z() < -kDirection;
        all_up = all_up && d.z() > kDirection;
        if (!all_down) continue;
        for (double z : {0.0, outside_top_}) {
          const double t = (z - cam_.z()) / d.z(), x = cam_.x() + t * d.x(), y = cam_.y() + t * d.y();
          in_field = in_field && x > kFieldMargin && x < g_.length - kFieldMargin && y > kFieldMargin &&
                     y < g_.width - kFieldMargin;
          if (z == 0.0) {
            x_lo = std::min(x_lo, x);
            x_hi = std::max(x_hi, x);
            y_lo = std::min(y_lo, y);
            y_hi = std::max(y_hi, y);
          }
        }
      }
      const size_t t = static_cast<size_t>(ty) * tiles_x + tx;
      TileMode& mode = tiles_[t];
      if (all_up && !(overlap[t] & 1)) {
        mode = TileMode::Sky;
      } else if (all_down && in_field) {
        mode = !(overlap[t] & 2) && scene_.floorIsPlain(x_lo - kFieldMargin, y_lo - kFieldMargin, x_hi + kFieldMargin,
                                                             y_hi + kFieldMargin)
                   ? TileMode::Floor
                   : TileMode::Column;
      }
    }
}

// A Floor or Sky tile whose 4-neighbour tiles have its mode too is settled: each of its pixels
// and their 4-neighbours have the same uniform mean, so none is refined (pass 2 writes the
// uniform value without the neighbour tests).
void ViewRender::settleTiles() {
  const int tiles_x = tiles_x_, tiles_y = tiles_y_;
  settled_.assign(tiles_.size(), 0);
  for (int ty = 0; ty < tiles_y; ++ty)
    for (int tx = 0; tx < tiles_x; ++tx) {
      const TileMode mode = tiles_[static_cast<size_t>(ty) * tiles_x + tx];
      auto same = [&](int x, int y) {
        return x < 0 || y < 0 || x >= tiles_x || y >= tiles_y || tiles_[static_cast<size_t>(y) * tiles_x + x] == mode;
      };
      settled_[static_cast<size_t>(ty) * tiles_x + tx] = (mode == TileMode::Floor || mode == TileMode::Sky) &&
                                                         same(tx - 1, ty) && same(tx + 1, ty) && same(tx, ty - 1) &&
                                                         same(tx, ty + 1);
    }
}

// Colour seen along the sample ray d (world frame) from this camera; `column`: the ray is
// known to be in the column above the open field (a Column tile).
inline Colour ViewRender::shade(const Eigen::Vector3d& d, const Span& span, bool column) const {
  const Eigen::Vector3d& cam = cam_;
  if (options_.reference_tracing)
    return surfaceColour(scene_.trace(cam, d, 0.0, std::numeric_limits<double>::infinity()), options_.colours,
                         options_.shading);
  const bool descending = d.z() < 0;
  bool in_column = column;
  if (descending && cam_above_outside_ && !column) {
    const double tf = -cam.z() / d.z(), tt = (outside_top_ - cam.z()) / d.z();
    const double fx = cam.x() + tf * d.x(), fy = cam.y() + tf * d.y();
    const double tx = cam.x() + tt * d.x(), ty = cam.y() + tt * d.y();
    in_column = fx > 0 && fx < g_.length && fy > 0 && fy < g_.width && tx > 0 && tx < g_.length && ty > 0 &&
                ty < g_.width;
  }
  const uint32_t* first = items_.data() + (!descending ? span.high : in_column ? span.inside : span.all);
  const uint32_t* last = items_.data() + (!descending ? span.high_end : in_column ? span.inside_end : span.all_end);
  double best_t = std::numeric_limits<double>::infinity();
  Colour colour = background_;
  if (first != last) {
    const Eigen::Vector3d inv(d.x() != 0.0 ? 1.0 / d.x() : 0.0, d.y() != 0.0 ? 1.0 / d.y() : 0.0,
                              d.z() != 0.0 ? 1.0 / d.z() : 0.0);
    RayHit h;
    for (const uint32_t* it = first; it != last; ++it) {
      const size_t b = *it;
      if (slab_of_[b] >= 0) {
        // Scene::intersectPrism's slab test, term for term.
        const SlabBox& s = slabs_[static_cast<size_t>(slab_of_[b])];
        double t0 = 0.0, t1 = best_t;
        int face = -3;
        auto slab = [&](double lo, double hi, double d_k, double inv_k, int face_lo, int face_hi) {
          if (d_k == 0.0) return lo <= 0.0 && hi >= 0.0;  // o_k >= lo && o_k <= hi
          return clipSlab(lo * inv_k, hi * inv_k, face_lo, face_hi, t0, t1, face);
        };
        if (slab(s.rel[0], s.rel[1], d.x(), inv.x(), 3, 1) && slab(s.rel[2], s.rel[3], d.y(), inv.y(), 0, 2) &&
            slab(s.rel[4], s.rel[5], d.z(), inv.z(), -2, -1) && face != -3 && t0 > 0.0) {
          best_t = t0;
          colour = s.colour[face >= 0 ? face : face == -1 ? 4 : 5];
        }
      } else if (b < n_prisms_ ? scene_.intersectPrism(b, cam, d, 0.0, best_t, &h)
                               : scene_.intersectSphere(b - n_prisms_, cam, d, 0.0, best_t, &h)) {
        best_t = h.t;
        colour = surfaceColour(h, options_.colours, options_.shading);
      }
    }
  }
  if (descending) {
    const double tf = -cam.z() / d.z();
    if (tf < best_t) {
      const SurfaceClass cls = scene_.floorClass(cam.x() + tf * d.x(), cam.y() + tf * d.y());
      colour = cls == SurfaceClass::Floor ? floor_ : cls == SurfaceClass::Marking ? marking_ : background_;
    }
  }
  return colour;
}

// Pass 1 over rows first_row, first_row + step, ...: the base n x n samples of every pixel,
// their mean, and whether they disagree.
void ViewRender::baseRows(int first_row, int step, std::vector<Colour>& mean, std::vector<uint8_t>& mixed) const {
  const int W = W_, H = H_, n = n_, spp = spp_;
  for (int v = first_row; v < H; v += step) {
    const Span* span = spans_.data() + row_first_span_[static_cast<size_t>(v)];
    const auto [u_first, u_last] = base_cols_[static_cast<size_t>(v)];
    for (int u = u_first; u < u_last; ++u) {
      while (u >= span->u_end) ++span;
      const size_t i = static_cast<size_t>(v) * W + u;
      const TileMode mode = tileMode(u, v);
      if (mode == TileMode::Floor || mode == TileMode::Sky) {
        mean[i] = mode == TileMode::Floor ? floor_mean_ : sky_mean_;
        mixed[i] = 0;
        continue;
      }
      Colour sum = Colour::Zero(), first = Colour::Zero();
      bool differ = false;
      for (int k = 0; k < spp; ++k) {
        const Eigen::Vector3f ray(1.0f, rays_.base_y[static_cast<size_t>(u) * n + k % n],
                                  rays_.base_z[static_cast<size_t>(v) * n + k / n]);
        const Colour c = shade((Rf_ * ray).cast<double>(), *span, mode == TileMode::Column);
        if (k == 0) first = c;
        else differ = differ || (c - first).cwiseAbs().maxCoeff() > kColourTolerance;
        sum += c;
      }
      mean[i] = sum / static_cast<float>(spp);
      mixed[i] = differ ? 1 : 0;
    }
  }
}

// Pass 2 over rows first_row, first_row + step, ...: a pixel whose samples disagree, or whose
// mean differs from a 4-neighbour's (a stripe thinner than the base grid spacing may fall
// between this pixel's samples but not the neighbour's), is re-sampled on the finer edge grid;
// the others keep the base mean.
void ViewRender::renderRows(int first_row, int step, const std::vector<Colour>& mean,
                            const std::vector<uint8_t>& mixed, cv::Mat& img) const {
  const int W = W_, H = H_, spp = spp_, fine = fine_;
  for (int v = first_row; v < H; v += step) {
    const Span* span = spans_.data() + row_first_span_[static_cast<size_t>(v)];
    cv::Vec3b* row = img.ptr<cv::Vec3b>(v);
    const auto [u_first, u_last] = write_cols_[static_cast<size_t>(v)];
    for (int u = u_first; u < u_last; ++u) {
      while (u >= span->u_end) ++span;
      const size_t tile = static_cast<size_t>(v / kTile) * tiles_x_ + u / kTile;
      if (settled_[tile]) {
        row[u] = tiles_[tile] == TileMode::Floor ? floor_bgr_ : sky_bgr_;
        continue;
      }
      const size_t i = static_cast<size_t>(v) * W + u;
      Colour c = mean[i];
      // An edge between two sample rows (columns) of neighbouring pixels leaves both uniform
      // but different: compare with the 4-neighbours.
      auto differs = [&](size_t j) { return (mean[j] - c).cwiseAbs().maxCoeff() > kColourTolerance; };
      const bool refine = fine > 0 && (mixed[i] || (u > 0 && differs(i - 1)) || (u + 1 < W && differs(i + 1)) ||
                                       (v > 0 && differs(i - W)) || (v + 1 < H && differs(i + W)));
      if (refine) {
        const TileMode mode = tiles_[tile];
        // The base samples are points of the fine grid when it nests them: reuse them.
        Colour sum = nested_ ? Colour(c * static_cast<float>(spp)) : Colour::Zero();
        for (int j = 0; j < fine; ++j)
          for (int k = 0; k < fine; ++k) {
            if (on_base_[static_cast<size_t>(j)] && on_base_[static_cast<size_t>(k)]) continue;
            if (mode == TileMode::Floor || mode == TileMode::Sky) {
              sum += mode == TileMode::Floor ? floor_ : background_;
              continue;
            }
            const Eigen::Vector3f ray(1.0f, rays_.fine_y[static_cast<size_t>(u) * fine + k],
                                      rays_.fine_z[static_cast<size_t>(v) * fine + j]);
            sum += shade((Rf_ * ray).cast<double>(), *span, mode == TileMode::Column);
          }
        c = sum / static_cast<float>(fine * fine);
      }
      row[u] = toBgr(c);
    }
  }
}

// Runs rows(first_row, step) on options_.threads threads (this one included), rows interleaved.
void ViewRender::runRows(const std::function<void(int, int)>& rows) const {
  const int threads = std::min(options_.threads, H_);
  if (threads <= 1) return rows(0, 1);
  std::vector<std::thread> pool;
  for (int t = 1; t < threads; ++t) pool.emplace_back(rows, t, threads);
  rows(0, threads);
  for (std::thread& th : pool) th.join();
}

// Illumination and blur (deterministic); sensor noise is render()'s.
void ViewRender::illuminateAndBlur(cv::Mat& img) const {
  if (options_.contrast != 1.0 || options_.brightness != 0.0)
    img.convertTo(img, -1, options_.contrast, options_.brightness + 128.0 * (1.0 - options_.contrast));
  if (options_.blur_sigma > 0) cv::GaussianBlur(img, img, cv::Size(0, 0), options_.blur_sigma);
}

cv::Mat ViewRender::render() const {
  // Pass 1's output. Kept between the renders of a thread (no 1.4 MB allocation and page faults
  // per image); every entry pass 2 reads is written by pass 1 of this render.
  struct PixelScratch {
    std::vector<Colour> mean;
    std::vector<uint8_t> mixed;
  };
  static thread_local PixelScratch scratch;
  scratch.mean.resize(static_cast<size_t>(W_) * H_);
  scratch.mixed.resize(static_cast<size_t>(W_) * H_);
  std::vector<Colour>& mean = scratch.mean;  // the workers of runRows use this thread's scratch
  std::vector<uint8_t>& mixed = scratch.mixed;
  cv::Mat img = needed_ ? cv::Mat(H_, W_, CV_8UC3, cv::Scalar::all(0)) : cv::Mat(H_, W_, CV_8UC3);
  runRows([&](int first_row, int step) { baseRows(first_row, step, mean, mixed); });
  runRows([&](int first_row, int step) { renderRows(first_row, step, mean, mixed, img); });
  illuminateAndBlur(img);
  return img;
}

}  // namespace

void RenderOptions::validate() const {
  if (samples_per_axis < 2 || samples_per_axis > 8) throw Error("render: samples_per_axis must be in 2..8");
  if (edge_samples_per_axis != 0 && (edge_samples_per_axis <= samples_per_axis || edge_samples_per_axis > 16))
    throw Error("render: edge_samples_per_axis must be 0 (off) or in samples_per_axis+1..16");
  auto finite_nonneg = [](double v, const char* name) {
    if (!(std::isfinite(v) && v >= 0)) throw Error(std::string("render: ") + name + " must be a finite number >= 0");
  };
  finite_nonneg(noise_sigma, "noise_sigma");
  finite_nonneg(blur_sigma, "blur_sigma");
  finite_nonneg(contrast, "contrast");
  if (!std::isfinite(brightness)) throw Error("render: brightness must be finite");
  if (threads < 1 || threads > 64) throw Error("render: threads must be in 1..64");
}

StereoRenderer::StereoRenderer(const FieldMap& map, const StereoRig& rig, const RenderOptions& options)
    : map_(map), rig_(rig), options_(options), static_scene_(Scene::fromMap(map)) {
  options_.validate();
  outline_edges_ = topOutlineEdges(static_scene_);
  const int W = rig.params().image_width, H = rig.params().image_height, n = options_.samples_per_axis;
  const double f = rig.focal(), ou = rig.principalU(), ov = rig.principalV();
  const int fine = options_.edge_samples_per_axis;
  // Regular n x n grid inside the pixel [u - 0.5, u + 0.5] x [v - 0.5, v + 0.5], and the edge grid.
  base_y_.resize(static_cast<size_t>(W) * n);
  base_z_.resize(static_cast<size_t>(H) * n);
  fine_y_.resize(static_cast<size_t>(W) * fine);
  fine_z_.resize(static_cast<size_t>(H) * fine);
  for (int u = 0; u < W; ++u) {
    for (int i = 0; i < n; ++i) {
      const double su = u - 0.5 + baseSampleOffset(i);
      base_y_[static_cast<size_t>(u) * n + i] = static_cast<float>(-(su - ou) / f);
    }
    for (int k = 0; k < fine; ++k) {
      const double su = u - 0.5 + (k + 0.5) / fine;
      fine_y_[static_cast<size_t>(u) * fine + k] = static_cast<float>(-(su - ou) / f);
    }
  }
  for (int v = 0; v < H; ++v) {
    for (int j = 0; j < n; ++j) {
      const double sv = v - 0.5 + baseSampleOffset(j);
      base_z_[static_cast<size_t>(v) * n + j] = static_cast<float>(-(sv - ov) / f);
    }
    for (int j = 0; j < fine; ++j) {
      const double sv = v - 0.5 + (j + 0.5) / fine;
      fine_z_[static_cast<size_t>(v) * fine + j] = static_cast<float>(-(sv - ov) / f);
    }
  }
}

double StereoRenderer::baseSampleOffset(int i) const {
  const int n = options_.samples_per_axis, fine = options_.edge_samples_per_axis;
  if (fine > 0 && fine % n == 0) {
    const int step = fine / n;
    return (i * step + step / 2 + 0.5) / fine;
  }
  return (i + 0.5) / n;
}

StereoImages StereoRenderer::render(const Pose2& robot, double head_pan, const std::vector<Obstacle>& obstacles) const {
  return render(robot, head_pan, obstacles, options_.seed);
}

StereoImages StereoRenderer::render(const Pose2& robot, double head_pan, const std::vector<Obstacle>& obstacles,
                                    uint64_t noise_seed) const {
  const Scene dynamic_scene = obstacles.empty() ? Scene() : Scene::fromMap(map_, obstacles);
  const Scene& scene = obstacles.empty() ? static_scene_ : dynamic_scene;
  StereoImages out;
  out.truth.robot = robot;
  out.truth.head_pan = head_pan;
  out.left = renderView(scene, robot, head_pan, 0, nullptr);
  out.right = renderView(scene, robot, head_pan, 1, nullptr);

  // Sensor noise (single-threaded, seeded: deterministic).
  std::mt19937_64 rng(noise_seed);
  std::normal_distribution<double> N(0.0, 1.0);
  for (cv::Mat* m : {&out.left, &out.right}) {
    if (options_.noise_sigma > 0) {
      for (int v = 0; v < m->rows; ++v) {
        uchar* p = m->ptr<uchar>(v);
        for (int k = 0; k < m->cols * 3; ++k) p[k] = cv::saturate_cast<uchar>(p[k] + options_.noise_sigma * N(rng));
      }
    }
  }
  if (options_.compute_truth) out.truth = computeTruth(scene, robot, head_pan);
  return out;
}

cv::Mat StereoRenderer::renderCamera(const Pose2& robot, double head_pan, const std::vector<Obstacle>& obstacles,
                                     int camera, const ColumnRanges* needed) const {
  if (camera != 0 && camera != 1) throw Error("renderCamera: camera must be 0 (left) or 1 (right)");
  if (needed && needed->size() != static_cast<size_t>(rig_.params().image_height))
    throw Error("renderCamera: one column range per image row expected");
  const Scene dynamic_scene = obstacles.empty() ? Scene() : Scene::fromMap(map_, obstacles);
  // A blurred pixel depends on its neighbourhood: the whole image then.
  return renderView(obstacles.empty() ? static_scene_ : dynamic_scene, robot, head_pan, camera,
                    options_.blur_sigma > 0 ? nullptr : needed);
}

cv::Mat StereoRenderer::renderView(const Scene& scene, const Pose2& robot, double head_pan, int camera,
                                   const ColumnRanges* needed) const {
  return ViewRender(scene, rig_, options_, SampleRays{base_y_, base_z_, fine_y_, fine_z_}, robot, head_pan, camera,
                    needed)
      .render();
}

StereoTruth StereoRenderer::computeTruth(const Scene& scene, const Pose2& robot, double head_pan) const {
  StereoTruth truth;
  truth.robot = robot;
  truth.head_pan = head_pan;
  const int W = rig_.params().image_width, H = rig_.params().image_height;
  const double f = rig_.focal(), ou = rig_.principalU(), ov = rig_.principalV();
  const Eigen::Matrix3d Rwv = visionToWorldRotation(rig_, robot, head_pan);
  const double umin = -0.5, umax = W - 0.5, vmin = -0.5, vmax = H - 0.5;
  constexpr double kTolerance = 0.5;  // mm: the last bit of a sight line touches the feature's own surface
  for (int camera = 0; camera < 2; ++camera) {
    ImageTruth& it = camera == 0 ? truth.left : truth.right;
    const Eigen::Vector3d cam = cameraCentreWorld(rig_, robot, head_pan, camera);
    auto toCam = [&](const Eigen::Vector3d& p) { return Eigen::Vector3d(Rwv.transpose() * (p - cam)); };
    auto pixel = [&](const Eigen::Vector3d& q) { return Eigen::Vector2d(ou - f * q.y() / q.x(), ov - f * q.z() / q.x()); };
    for (const Landmark& l : map_.landmarks()) {
      const Eigen::Vector3d q = toCam(l.position);
      if (q.x() < 1.0) continue;
      const Eigen::Vector2d px = pixel(q);
      if (px.x() < umin || px.x() >= umax || px.y() < vmin || px.y() >= vmax) continue;
      if (scene.occluded(cam, l.position, kTolerance)) continue;
      it.landmarks.push_back({l.id, toString(l.type), px});
    }
    for (size_t ei = 0; ei < scene.edges().size() + outline_edges_.size(); ++ei) {
      const SceneEdge& e = ei < scene.edges().size() ? scene.edges()[ei] : outline_edges_[ei - scene.edges().size()];
      // Clip the segment to the viewing frustum: x >= 1 mm and the four image borders, each a
      // half-space a.q >= 0 that is linear in the segment parameter s.
      const Eigen::Vector3d A = toCam(e.a), B = toCam(e.b);
      double s0 = 0.0, s1 = 1.0;
      const Eigen::Vector3d planes[] = {{1, 0, 0}, {ou - umin, -f, 0}, {umax - ou, f, 0}, {ov - vmin, 0, -f}, {vmax - ov, 0, f}};
      const double offsets[] = {-1.0, 0, 0, 0, 0};
      bool empty = false;
      for (int k = 0; k < 5 && !empty; ++k) {
        const double ga = planes[k].dot(A) + offsets[k], gb = planes[k].dot(B) + offsets[k];
        // g(s) = ga + s (gb - ga) >= 0
        if (ga < 0 && gb < 0) {
          empty = true;
        } else if (ga < 0) {
          s0 = std::max(s0, ga / (ga - gb));
        } else if (gb < 0) {
          s1 = std::min(s1, ga / (ga - gb));
        }
        if (s0 >= s1) empty = true;
      }
      if (empty) continue;
      auto world = [&](double s) { return Eigen::Vector3d(e.a + s * (e.b - e.a)); };
      auto visible = [&](double s) { return !scene.occluded(cam, world(s), kTolerance); };
      const double px_len = (pixel(A + s0 * (B - A)) - pixel(A + s1 * (B - A))).norm();
      const int samples = std::clamp(static_cast<int>(std::ceil(px_len)), 2, 400);
      // Runs of visible samples; run ends refined by bisection.
      auto refine = [&](double vis, double hid) {
        for (int it2 = 0; it2 < 30; ++it2) {
          const double mid = 0.5 * (vis + hid);
          (visible(mid) ? vis : hid) = mid;
        }
        return vis;
      };
      double prev_s = s0;
      bool prev_vis = visible(s0);
      double run_start = s0;
      for (int k = 1; k <= samples; ++k) {
        const double s = s0 + (s1 - s0) * k / samples;
        const bool vis = visible(s);
        if (vis && !prev_vis) run_start = refine(s, prev_s);
        if ((!vis && prev_vis) || (vis && k == samples)) {
          const double run_end = vis ? s : refine(prev_s, s);
          const Eigen::Vector2d pa = pixel(toCam(world(run_start))), pb = pixel(toCam(world(run_end)));
          if ((pa - pb).norm() > 0.5) it.segments.push_back({e.kind, e.name, pa, pb});
        }
        prev_vis = vis;
        prev_s = s;
      }
    }
  }
  return truth;
}

StereoTruth StereoRenderer::truth(const Pose2& robot, double head_pan, const std::vector<Obstacle>& obstacles) const {
  if (obstacles.empty()) return computeTruth(static_scene_, robot, head_pan);
  return computeTruth(Scene::fromMap(map_, obstacles), robot, head_pan);
}

StereoImages renderStereoPair(const FieldMap& map, const StereoRig& rig, const Pose2& robot, double head_pan,
                              const std::vector<Obstacle>& obstacles, const RenderOptions& options) {
  return StereoRenderer(map, rig, options).render(robot, head_pan, obstacles);
}

std::string truthToJson(const StereoTruth& t, long step, int width, int height) {
  const auto num = [](double v) { return formatDouble(v); };
  std::string s = "{\n  \"step\": " + std::to_string(step) + ",\n  \"units\": \"px; robot mm, rad\",\n";
  s += "  \"image_width\": " + std::to_string(width) + ",\n  \"image_height\": " + std::to_string(height) + ",\n";
  s += "  \"robot\": {\"x\": " + num(t.robot.x) + ", \"y\": " + num(t.robot.y) + ", \"theta\": " + num(t.robot.theta) + "},\n";
  s += "  \"head_pan\": " + num(t.head_pan) + ",\n";
  for (int camera = 0; camera < 2; ++camera) {
    const ImageTruth& it = camera == 0 ? t.left : t.right;
    s += std::string("  \"") + (camera == 0 ? "left" : "right") + "\": {\n    \"landmarks\": [";
    for (size_t i = 0; i < it.landmarks.size(); ++i) {
      const ImageLandmark& l = it.landmarks[i];
      s += std::string(i ? "," : "") + "\n      {\"id\": " + std::to_string(l.id) + ", \"type\": " + jsonString(l.type) +
           ", \"u\": " + num(l.pixel.x()) + ", \"v\": " + num(l.pixel.y()) + "}";
    }
    s += std::string(it.landmarks.empty() ? "" : "\n    ") + "],\n    \"segments\": [";
    for (size_t i = 0; i < it.segments.size(); ++i) {
      const ImageSegment& g = it.segments[i];
      s += std::string(i ? "," : "") + "\n      {\"kind\": " + jsonString(g.kind) + ", \"name\": " + jsonString(g.name) +
           ", \"u0\": " + num(g.a.x()) + ", \"v0\": " + num(g.a.y()) + ", \"u1\": " + num(g.b.x()) + ", \"v1\": " + num(g.b.y()) + "}";
    }
    s += std::string(it.segments.empty() ? "" : "\n    ") + "]\n  }" + (camera == 0 ? "," : "") + "\n";
  }
  return s + "}\n";
}

void writeDatasetImages(const Dataset& d, const SimulationTrace& trace, const RenderOptions& options, uint64_t seed,
                        const std::string& dir) {
  if (trace.scenario.poses.size() != d.steps.size() || trace.obstacles.size() != d.steps.size())
    throw Error("writeDatasetImages: the simulation trace does not match the dataset");
  std::filesystem::create_directories(std::filesystem::path(dir) / "images");
  const bool ideal = trace.profile.isIdeal();
  const StereoRenderer renderer(d.map, ideal ? d.rig : StereoRig(trace.nominal_rig), options);
  std::optional<RawPairRenderer> raw;
  if (!ideal) raw.emplace(d.map, trace.nominal_rig, trace.profile, trace.errors, options, trace.scenario.dt);
  const int W = d.rig.params().image_width, H = d.rig.params().image_height;
  for (size_t s = 0; s < d.steps.size(); ++s) {
    const Step& st = d.steps[s];
    const StereoImages im = ideal ? renderer.render(trace.scenario.poses[s], st.head_pan, trace.obstacles[s], seed + s)
                                  : raw->render(trace.scenario, s, trace.obstacles[s], seed + s);
    for (int camera = 0; camera < 2; ++camera) {
      const std::string path = (std::filesystem::path(dir) / imageFileName(camera == 0 ? "left" : "right", st.step)).string();
      writePngFile(path, camera == 0 ? im.left : im.right);
    }
    writeFileAtomically((std::filesystem::path(dir) / imageFileName("truth", st.step)).string(),
                        truthToJson(im.truth, st.step, W, H));
  }
}

}  // namespace stereoloc
