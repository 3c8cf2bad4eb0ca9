#include "src/renderer.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <random>
#include <thread>

#include "src/atomic_file.h"
#include "src/csv.h"
#include "src/dataset.h"
#include "src/error.h"
#include "src/simulator.h"

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

// Image-space bounding box of a set of world points seen from a camera; the whole image when
// any point is near or behind the camera plane (the projection is unbounded there).
Box projectBox(const std::vector<Eigen::Vector3d>& pts, const Eigen::Vector3d& cam, const Eigen::Matrix3d& Rwv,
               double f, double ou, double ov, int W, int H) {
  double umin = 1e300, umax = -1e300, vmin = 1e300, vmax = -1e300;
  bool any_front = false, any_behind = false;
  for (const Eigen::Vector3d& p : pts) {
    const Eigen::Vector3d q = Rwv.transpose() * (p - cam);
    if (q.x() < 1.0) {
      any_behind = true;
      continue;
    }
    any_front = true;
    const double u = ou - f * q.y() / q.x(), v = ov - f * q.z() / q.x();
    umin = std::min(umin, u);
    umax = std::max(umax, u);
    vmin = std::min(vmin, v);
    vmax = std::max(vmax, v);
  }
  // Wholly behind the camera plane: invisible (a convex object behind x = 1 mm cannot reach the
  // image). Straddling it: its projection is unbounded, so the whole image.
  if (!any_front) return {1, 0, 1, 0};
  if (any_behind) return {-1, W, -1, H};
  Box b;
  b.u0 = static_cast<int>(std::max(-1.0, std::floor(umin - 1.0)));
  b.u1 = static_cast<int>(std::min(static_cast<double>(W), std::ceil(umax + 1.0)));
  b.v0 = static_cast<int>(std::max(-1.0, std::floor(vmin - 1.0)));
  b.v1 = static_cast<int>(std::min(static_cast<double>(H), std::ceil(vmax + 1.0)));
  return b;
}

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
  rays_.resize(static_cast<size_t>(W) * H * n * n);
  size_t k = 0;
  for (int v = 0; v < H; ++v)
    for (int u = 0; u < W; ++u)
      for (int j = 0; j < n; ++j)
        for (int i = 0; i < n; ++i) {
          // Regular n x n grid inside the pixel [u - 0.5, u + 0.5] x [v - 0.5, v + 0.5].
          const double su = u - 0.5 + baseSampleOffset(i), sv = v - 0.5 + baseSampleOffset(j);
          rays_[k++] = Eigen::Vector3f(1.0f, static_cast<float>(-(su - ou) / f), static_cast<float>(-(sv - ov) / f));
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
  const int W = rig_.params().image_width, H = rig_.params().image_height, n = options_.samples_per_axis;
  const int spp = n * n, fine = options_.edge_samples_per_axis;
  const bool nested = fine > 0 && fine % n == 0;
  const int fine_step = nested ? fine / n : 1;
  const double f = rig_.focal(), ou = rig_.principalU(), ov = rig_.principalV();
  const Eigen::Matrix3d Rwv = visionToWorldRotation(rig_, robot, head_pan);
  const Eigen::Matrix3f Rf = Rwv.cast<float>();
  StereoImages out;
  out.truth.robot = robot;
  out.truth.head_pan = head_pan;
  const size_t n_prisms = scene.prisms().size(), n_spheres = scene.spheres().size();

  for (int camera = 0; camera < 2; ++camera) {
    const Eigen::Vector3d cam = cameraCentreWorld(rig_, robot, head_pan, camera);
    // Per-object image bounding boxes (culling).
    std::vector<Box> boxes;
    for (const Prism& p : scene.prisms()) {
      std::vector<Eigen::Vector3d> pts;
      for (const Eigen::Vector2d& q : p.polygon) {
        pts.emplace_back(q.x(), q.y(), p.zmin);
        pts.emplace_back(q.x(), q.y(), p.zmax);
      }
      boxes.push_back(projectBox(pts, cam, Rwv, f, ou, ov, W, H));
    }
    for (const Sphere& s : scene.spheres()) {
      std::vector<Eigen::Vector3d> pts;
      for (int k = 0; k < 8; ++k)
        pts.push_back(s.centre + s.radius * Eigen::Vector3d(k & 1 ? 1 : -1, k & 2 ? 1 : -1, k & 4 ? 1 : -1));
      boxes.push_back(projectBox(pts, cam, Rwv, f, ou, ov, W, H));
    }
    // Ray-independent culling facts per object: `low` objects lie entirely below the camera, so
    // a ray that does not descend misses them; `outside` objects (walls, goals) lie outside the
    // open field, so a descending ray whose path from the wall-top height down to the floor
    // stays above the field cannot hit them (the field is convex).
    const FieldGeometry& g = scene.geometry();
    std::vector<uint8_t> low(boxes.size(), 0), outside(boxes.size(), 0);
    double outside_top = 0.0;
    for (size_t b = 0; b < n_prisms; ++b) {
      const Prism& p = scene.prisms()[b];
      low[b] = p.zmax < cam.z();
      double x0 = 1e300, x1 = -1e300, y0 = 1e300, y1 = -1e300;
      for (const Eigen::Vector2d& q : p.polygon) {
        x0 = std::min(x0, q.x());
        x1 = std::max(x1, q.x());
        y0 = std::min(y0, q.y());
        y1 = std::max(y1, q.y());
      }
      outside[b] = x1 <= 0.0 || x0 >= g.length || y1 <= 0.0 || y0 >= g.width;
      if (outside[b]) outside_top = std::max(outside_top, p.zmax);
    }
    const bool cam_above_outside = cam.z() > outside_top;
    // Colour seen along the sample ray d (world frame) from this camera.
    auto shade = [&](const Eigen::Vector3d& d, std::vector<size_t>& candidates, std::vector<size_t>& inside,
                     std::vector<size_t>& high) -> Colour {
      RayHit best;
      best.t = std::numeric_limits<double>::infinity();
      bool hit_object = false;
      RayHit h;
      const bool descending = d.z() < 0;
      bool in_column = false;
      if (descending && cam_above_outside) {
        const double tf = -cam.z() / d.z(), tt = (outside_top - cam.z()) / d.z();
        const double fx = cam.x() + tf * d.x(), fy = cam.y() + tf * d.y();
        const double tx = cam.x() + tt * d.x(), ty = cam.y() + tt * d.y();
        in_column = fx > 0 && fx < g.length && fy > 0 && fy < g.width && tx > 0 && tx < g.length && ty > 0 &&
                    ty < g.width;
      }
      const std::vector<size_t>& list = !descending ? high : in_column ? inside : candidates;
      for (size_t b : list) {
        const bool got = b < n_prisms ? scene.intersectPrism(b, cam, d, 0.0, best.t, &h)
                                      : scene.intersectSphere(b - n_prisms, cam, d, 0.0, best.t, &h);
        if (got) {
          best = h;
          hit_object = true;
        }
      }
      if (descending) {
        const double tf = -cam.z() / d.z();
        if (tf < best.t) {
          best.t = tf;
          best.cls = scene.floorClass(cam.x() + tf * d.x(), cam.y() + tf * d.y());
          best.normal = Eigen::Vector3d(0, 0, 1);
          hit_object = true;
        }
      }
      if (!hit_object) best.cls = SurfaceClass::Background;
      return surfaceColour(best, options_.colours, options_.shading);
    };
    // The object candidates of pixel (u, v), split by what a sample ray can possibly hit (see above).
    auto pixelCandidates = [&](int u, const std::vector<size_t>& row_objects, std::vector<size_t>& candidates,
                               std::vector<size_t>& inside, std::vector<size_t>& high) {
      candidates.clear();
      inside.clear();
      high.clear();
      for (size_t b : row_objects)
        if (u >= boxes[b].u0 && u <= boxes[b].u1) {
          candidates.push_back(b);
          if (!outside[b]) inside.push_back(b);
          if (!low[b]) high.push_back(b);
        }
    };
    auto rowObjects = [&](int v) {
      std::vector<size_t> row_objects;
      for (size_t b = 0; b < boxes.size(); ++b)
        if (v >= boxes[b].v0 && v <= boxes[b].v1) row_objects.push_back(b);
      return row_objects;
    };
    // Pass 1: the base n x n samples of every pixel, their mean, and whether they disagree.
    std::vector<Colour> mean(static_cast<size_t>(W) * H);
    std::vector<uint8_t> mixed(static_cast<size_t>(W) * H, 0);
    auto baseRows = [&](int first_row, int step) {
      std::vector<size_t> candidates, inside, high;
      for (int v = first_row; v < H; v += step) {
        const std::vector<size_t> row_objects = rowObjects(v);
        for (int u = 0; u < W; ++u) {
          pixelCandidates(u, row_objects, candidates, inside, high);
          Colour sum = Colour::Zero(), first = Colour::Zero();
          bool differ = false;
          const Eigen::Vector3f* ray = &rays_[(static_cast<size_t>(v) * W + u) * spp];
          for (int k = 0; k < spp; ++k) {
            const Colour c = shade((Rf * ray[k]).cast<double>(), candidates, inside, high);
            if (k == 0) first = c;
            else differ = differ || (c - first).cwiseAbs().maxCoeff() > kColourTolerance;
            sum += c;
          }
          const size_t i = static_cast<size_t>(v) * W + u;
          mean[i] = sum / static_cast<float>(spp);
          mixed[i] = differ ? 1 : 0;
        }
      }
    };
    // Pass 2: a pixel whose samples disagree, or whose mean differs from a 4-neighbour's (a stripe
    // thinner than the base grid spacing may fall between this pixel's samples but not the
    // neighbour's), is re-sampled on the finer edge grid; the others keep the base mean.
    cv::Mat img(H, W, CV_8UC3);
    auto renderRows = [&](int first_row, int step) {
      std::vector<size_t> candidates, inside, high;
      for (int v = first_row; v < H; v += step) {
        const std::vector<size_t> row_objects = fine > 0 ? rowObjects(v) : std::vector<size_t>();
        cv::Vec3b* row = img.ptr<cv::Vec3b>(v);
        for (int u = 0; u < W; ++u) {
          const size_t i = static_cast<size_t>(v) * W + u;
          Colour c = mean[i];
          bool refine = fine > 0 && mixed[i];
          // An edge between two sample rows (columns) of neighbouring pixels leaves both uniform
          // but different: compare with the 4-neighbours.
          constexpr int kNeighbour[4][2] = {{-1, 0}, {1, 0}, {0, -1}, {0, 1}};
          for (int k = 0; k < 4 && fine > 0 && !refine; ++k) {
            const int uu = u + kNeighbour[k][0], vv = v + kNeighbour[k][1];
            if (uu < 0 || uu >= W || vv < 0 || vv >= H) continue;
            refine = (mean[static_cast<size_t>(vv) * W + uu] - c).cwiseAbs().maxCoeff() > kColourTolerance;
          }
          if (refine) {
            pixelCandidates(u, row_objects, candidates, inside, high);
            // The base samples are points of the fine grid when it nests them: reuse them.
            Colour sum = nested ? Colour(c * static_cast<float>(spp)) : Colour::Zero();
            for (int j = 0; j < fine; ++j)
              for (int k = 0; k < fine; ++k) {
                if (nested && j % fine_step == fine_step / 2 && k % fine_step == fine_step / 2) continue;
                const double su = u - 0.5 + (k + 0.5) / fine, sv = v - 0.5 + (j + 0.5) / fine;
                const Eigen::Vector3f ray(1.0f, static_cast<float>(-(su - ou) / f), static_cast<float>(-(sv - ov) / f));
                sum += shade((Rf * ray).cast<double>(), candidates, inside, high);
              }
            c = sum / static_cast<float>(fine * fine);
          }
          c *= 255.0f;
          // BGR
          row[u] = cv::Vec3b(cv::saturate_cast<uchar>(c.z()), cv::saturate_cast<uchar>(c.y()),
                             cv::saturate_cast<uchar>(c.x()));
        }
      }
    };
    const int threads = std::min(options_.threads, H);
    auto runRows = [threads](const std::function<void(int, int)>& rows) {
      if (threads <= 1) return rows(0, 1);
      std::vector<std::thread> pool;
      for (int t = 1; t < threads; ++t) pool.emplace_back(rows, t, threads);
      rows(0, threads);
      for (std::thread& th : pool) th.join();
    };
    runRows(baseRows);
    runRows(renderRows);
    (camera == 0 ? out.left : out.right) = img;
    (void)n_spheres;
  }

  // Post-processing: illumination, blur, sensor noise (single-threaded, seeded: deterministic).
  std::mt19937_64 rng(noise_seed);
  std::normal_distribution<double> N(0.0, 1.0);
  for (cv::Mat* m : {&out.left, &out.right}) {
    if (options_.contrast != 1.0 || options_.brightness != 0.0)
      m->convertTo(*m, -1, options_.contrast, options_.brightness + 128.0 * (1.0 - options_.contrast));
    if (options_.blur_sigma > 0) cv::GaussianBlur(*m, *m, cv::Size(0, 0), options_.blur_sigma);
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
  const StereoRenderer renderer(d.map, d.rig, options);
  const int W = d.rig.params().image_width, H = d.rig.params().image_height;
  for (size_t s = 0; s < d.steps.size(); ++s) {
    const Step& st = d.steps[s];
    const StereoImages im = renderer.render(trace.scenario.poses[s], st.head_pan, trace.obstacles[s], seed + s);
    for (int camera = 0; camera < 2; ++camera) {
      const std::string path = (std::filesystem::path(dir) / imageFileName(camera == 0 ? "left" : "right", st.step)).string();
      std::vector<uchar> png;
      if (!cv::imencode(".png", camera == 0 ? im.left : im.right, png)) throw Error(path + ": PNG encoding failed");
      writeFileAtomically(path, std::string(png.begin(), png.end()));
    }
    writeFileAtomically((std::filesystem::path(dir) / imageFileName("truth", st.step)).string(),
                        truthToJson(im.truth, st.step, W, H));
  }
}

}  // namespace stereoloc
