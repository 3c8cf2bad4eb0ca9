#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <random>
#include <set>

#include <opencv2/imgproc.hpp>

#include "src/sim/renderer.h"
#include "src/sim/simulator.h"

namespace stereoloc {
namespace {

RenderOptions plain() {
  RenderOptions o;
  o.shading = true;
  return o;
}

// Sub-pixel position of the white-wall edge (min of B, G, R: high on the white wall, low on the
// coloured goal face, the dark goal floor or the background) along row v near u, from the
// anti-aliased pixel values (each pixel is the box average over [u - 0.5, u + 0.5], so the
// half-way crossing between the two plateaus is the edge position).
std::optional<double> colourEdge(const cv::Mat& img, double u, double v, int half_window = 5) {
  const int row = static_cast<int>(std::lround(v));
  const int c = static_cast<int>(std::lround(u));
  std::vector<double> b;
  const int lo = std::max(0, c - half_window), hi = std::min(img.cols - 1, c + half_window);
  for (int x = lo; x <= hi; ++x) {
    const cv::Vec3b p = img.at<cv::Vec3b>(row, x);
    b.push_back(static_cast<double>(std::min({p[0], p[1], p[2]})));
  }
  const double bmin = *std::min_element(b.begin(), b.end()), bmax = *std::max_element(b.begin(), b.end());
  if (bmax - bmin < 100) return std::nullopt;
  const double mid = 0.5 * (bmin + bmax);
  std::optional<double> best;
  for (size_t i = 0; i + 1 < b.size(); ++i) {
    if ((b[i] - mid) * (b[i + 1] - mid) <= 0 && b[i] != b[i + 1]) {
      const double x = lo + i + (mid - b[i]) / (b[i + 1] - b[i]);
      if (!best || std::fabs(x - u) < std::fabs(*best - u)) best = x;
    }
  }
  return best;
}

TEST(Renderer, GoalCornerLandsOnTheColourTransitionWithinOnePixel) {
  const FieldMap map = FieldMap::miroSot();
  const StereoRig rig;
  const StereoRenderer renderer(map, rig, plain());
  const std::vector<std::pair<Pose2, double>> poses = {
      {Pose2(400, 650, kPi), 0.0},      {Pose2(600, 520, 2.9), 0.0},  {Pose2(350, 800, -2.9), 0.0},
      {Pose2(1100, 650, 0.0), 0.0},     {Pose2(900, 400, 0.2), 0.1},  {Pose2(700, 650, 0.5), kPi - 0.4},
      {Pose2(1200, 900, -0.35), -0.05}, {Pose2(250, 420, 2.5), 0.3}};
  int checked = 0;
  double worst = 0;
  for (const auto& [pose, pan] : poses) {
    const StereoImages im = renderer.render(pose, pan, {});
    for (int camera = 0; camera < 2; ++camera) {
      const ImageTruth& t = camera == 0 ? im.truth.left : im.truth.right;
      for (const ImageLandmark& l : t.landmarks) {
        if (l.type != "goal_corner") continue;
        // The truth is StereoRig::project of the landmark.
        const Eigen::Vector2d local = transformToLocal(pose, map.at(l.id).xy());
        const auto px = rig.project(Eigen::Vector3d(local.x(), local.y(), map.at(l.id).position.z()), pan);
        ASSERT_TRUE(px);
        EXPECT_NEAR(l.pixel.x(), camera == 0 ? px->u_left : px->u_right, 1e-9);
        EXPECT_NEAR(l.pixel.y(), camera == 0 ? px->v_left : px->v_right, 1e-9);
        if (l.pixel.x() < 6 || l.pixel.x() > rig.params().image_width - 7) continue;
        const auto edge = colourEdge(camera == 0 ? im.left : im.right, l.pixel.x(), l.pixel.y());
        ASSERT_TRUE(edge) << "no colour transition near landmark " << l.id;
        EXPECT_LT(std::fabs(*edge - l.pixel.x()), 1.0) << "landmark " << l.id << " camera " << camera;
        worst = std::max(worst, std::fabs(*edge - l.pixel.x()));
        ++checked;
      }
    }
  }
  EXPECT_GE(checked, 10);
  EXPECT_LT(worst, 0.5);
  std::printf("goal corners checked: %d, worst edge offset %.3f px\n", checked, worst);
}

TEST(Renderer, TruthLandmarksAgreeWithTheSimulatedSensor) {
  const FieldMap map = FieldMap::miroSot();
  const StereoRig rig;
  const StereoRenderer renderer(map, rig, plain());
  const Scene scene = Scene::fromMap(map);
  for (const Pose2& pose : {Pose2(400, 650, kPi), Pose2(750, 650, 0.3), Pose2(1200, 300, 2.2), Pose2(300, 1000, -0.6)}) {
    const StereoTruth t = renderer.truth(pose, 0.0, {});
    std::set<int> left, right, both, sensor;
    for (const auto& l : t.left.landmarks) left.insert(l.id);
    for (const auto& l : t.right.landmarks) right.insert(l.id);
    for (int id : left)
      if (right.count(id)) both.insert(id);
    for (const auto& v : visibleLandmarks(map, rig, scene, pose, 0.0, LandmarkSet::All)) sensor.insert(v.id);
    EXPECT_EQ(both, sensor) << pose.x << " " << pose.y;
    EXPECT_FALSE(both.empty());
  }
}

TEST(Renderer, MarkingSegmentsAreOnBrightPixels) {
  const FieldMap map = FieldMap::miroSot();
  const StereoRenderer renderer(map, StereoRig(), plain());
  const StereoImages im = renderer.render(Pose2(900, 600, 2.8), 0.0, {});
  int checked = 0, brightest = 0;
  for (const ImageSegment& s : im.truth.left.segments) {
    if (s.kind != "marking" || (s.a - s.b).norm() < 20) continue;
    for (double f : {0.25, 0.5, 0.75}) {
      const Eigen::Vector2d p = s.a + f * (s.b - s.a);
      const int u = static_cast<int>(std::lround(p.x())), v = static_cast<int>(std::lround(p.y()));
      int best = 0;
      for (int dv = -1; dv <= 1; ++dv)
        for (int du = -1; du <= 1; ++du) {
          const int uu = std::clamp(u + du, 0, im.left.cols - 1), vv = std::clamp(v + dv, 0, im.left.rows - 1);
          best = std::max(best, static_cast<int>(im.left.at<cv::Vec3b>(vv, uu)[1]));
        }
      // Clearly above the floor (20): the far markings of this view are only a quarter of a
      // pixel wide in the image, and a pixel integrates over its area (~70 there).
      EXPECT_GT(best, 50) << s.name << " at " << p.transpose();
      brightest = std::max(brightest, best);
      ++checked;
    }
  }
  EXPECT_GE(checked, 6);
  EXPECT_GT(brightest, 200);  // a near marking covers whole pixels
  // Wall, goal and triangle edges are reported too.
  std::set<std::string> kinds;
  for (const ImageSegment& s : im.truth.left.segments) kinds.insert(s.kind);
  EXPECT_TRUE(kinds.count("goal_post"));
  EXPECT_TRUE(kinds.count("wall_top"));
  EXPECT_TRUE(kinds.count("marking"));
}

// The walls' outer top edge (their silhouette against the background, seen from above the
// wall height) was missing from the truth although it is the strongest edge of a wall: each
// top_outline segment must separate the bright wall top (below it) from the darker background
// (above it), and lie above (smaller v) the inner top edge of the same wall.
TEST(Renderer, TopOutlineIsTheWallSilhouette) {
  const FieldMap map = FieldMap::miroSot();
  const StereoRenderer renderer(map, StereoRig(), plain());
  // 150 mm from the y = 0 wall, looking at it: the inner and outer top edges (25 mm apart on a
  // wall 20 mm below the camera) are ~6 px apart.
  const StereoImages im = renderer.render(Pose2(700, 150, -kPi / 2), 0.0, {});
  int outlines = 0;
  for (const ImageSegment& s : im.truth.left.segments) {
    if (s.kind != "top_outline" || (s.a - s.b).norm() < 40) continue;
    ++outlines;
    for (double f : {0.3, 0.5, 0.7}) {
      const Eigen::Vector2d p = s.a + f * (s.b - s.a);
      const int u = static_cast<int>(std::lround(p.x())), v = static_cast<int>(std::lround(p.y()));
      const int above = im.left.at<cv::Vec3b>(v - 2, u)[1], below = im.left.at<cv::Vec3b>(v + 2, u)[1];
      EXPECT_GT(below - above, 40) << "at " << p.transpose();
    }
    bool has_inner = false;
    for (const ImageSegment& w : im.truth.left.segments)
      if (w.kind == "wall_top" && w.name == "wall_y0") {
        has_inner = true;
        EXPECT_LT(0.5 * (s.a.y() + s.b.y()) + 1.0, 0.5 * (w.a.y() + w.b.y()));
      }
    EXPECT_TRUE(has_inner);
  }
  EXPECT_GE(outlines, 1);
}

TEST(Renderer, ObstaclesHideLandmarksInTheImagesAndTheTruth) {
  const FieldMap map = FieldMap::miroSot();
  const StereoRenderer renderer(map, StereoRig(), plain());
  Obstacle o;
  o.position = Eigen::Vector2d(200, 550);
  const StereoImages im = renderer.render(Pose2(400, 650, kPi), 0.0, {o});
  for (const auto& l : im.truth.left.landmarks) EXPECT_NE(l.id, 0);
  bool robot_pixels = false;
  for (int v = 0; v < im.left.rows && !robot_pixels; ++v)
    for (int u = 0; u < im.left.cols; ++u) {
      const cv::Vec3b p = im.left.at<cv::Vec3b>(v, u);
      if (std::abs(p[0] - 51 * 0.22 / 0.2) < 20 && p[1] > 35 && p[1] < 60) robot_pixels = true;
    }
  EXPECT_TRUE(robot_pixels);
}

TEST(Renderer, DeterministicWhateverTheThreadCount) {
  const FieldMap map = FieldMap::miroSot();
  RenderOptions a = plain(), b = plain();
  a.threads = 1;
  b.threads = 2;
  a.noise_sigma = b.noise_sigma = 4.0;
  a.seed = b.seed = 17;
  Obstacle ball;
  ball.kind = Obstacle::Kind::Ball;
  ball.size = 42.7;
  ball.position = Eigen::Vector2d(500, 600);
  const StereoImages x = StereoRenderer(map, StereoRig(), a).render(Pose2(900, 600, 2.8), 0.1, {ball});
  const StereoImages y = StereoRenderer(map, StereoRig(), b).render(Pose2(900, 600, 2.8), 0.1, {ball});
  EXPECT_EQ(cv::norm(x.left, y.left, cv::NORM_INF), 0.0);
  EXPECT_EQ(cv::norm(x.right, y.right, cv::NORM_INF), 0.0);
  const StereoImages z = StereoRenderer(map, StereoRig(), b).render(Pose2(900, 600, 2.8), 0.1, {ball}, 18);
  EXPECT_GT(cv::norm(x.left, z.left, cv::NORM_INF), 0.0);
  EXPECT_EQ(x.left.type(), CV_8UC3);
  EXPECT_EQ(x.left.cols, 320);
  EXPECT_EQ(x.left.rows, 240);
}

TEST(Renderer, IlluminationBlurAndNoiseOptions) {
  const FieldMap map = FieldMap::miroSot();
  const Pose2 pose(900, 600, 2.8);
  const StereoImages base = renderStereoPair(map, StereoRig(), pose, 0.0, {}, plain());
  RenderOptions dark = plain();
  dark.brightness = -40;
  dark.contrast = 0.6;
  const StereoImages d = renderStereoPair(map, StereoRig(), pose, 0.0, {}, dark);
  EXPECT_LT(cv::mean(d.left)[1], cv::mean(base.left)[1] - 20);
  RenderOptions blur = plain();
  blur.blur_sigma = 1.5;
  const StereoImages bl = renderStereoPair(map, StereoRig(), pose, 0.0, {}, blur);
  cv::Mat gx0, gx1;
  cv::Sobel(base.left, gx0, CV_32F, 1, 0);
  cv::Sobel(bl.left, gx1, CV_32F, 1, 0);
  EXPECT_LT(cv::norm(gx1, cv::NORM_L1), 0.8 * cv::norm(gx0, cv::NORM_L1));
  RenderOptions bad = plain();
  bad.samples_per_axis = 1;
  EXPECT_THROW(bad.validate(), Error);
  bad = plain();
  bad.noise_sigma = -1;
  EXPECT_THROW(StereoRenderer(map, StereoRig(), bad), Error);
}

TEST(Renderer, AntiAliasedEdgesHaveIntermediateValues) {
  const StereoImages im = renderStereoPair(FieldMap::miroSot(), StereoRig(), Pose2(900, 600, 2.8), 0.0, {}, plain());
  std::set<int> greens;
  for (int v = 0; v < im.left.rows; ++v)
    for (int u = 0; u < im.left.cols; ++u) greens.insert(im.left.at<cv::Vec3b>(v, u)[1]);
  EXPECT_GT(greens.size(), 20u);  // a 1-sample renderer of flat colours would give a handful
}

// A camera pixel integrates over its area: the adaptive renderer (2 x 2 samples, 4 x 4 on edge
// pixels) must be much closer to a dense 8 x 8 rendering than plain 2 x 2 sampling is, and equal
// to the 2 x 2 rendering away from edges.
TEST(Renderer, EdgePixelsAreResampledOnTheFinerGrid) {
  const FieldMap map = FieldMap::miroSot();
  const Pose2 pose(900, 600, 2.8);  // the blue goal across the centre circle: far, thin, nearly horizontal edges
  RenderOptions plain2 = plain(), adaptive = plain(), dense = plain();
  plain2.edge_samples_per_axis = 0;
  dense.samples_per_axis = 8;
  dense.edge_samples_per_axis = 0;
  const cv::Mat a = renderStereoPair(map, StereoRig(), pose, 0.0, {}, adaptive).left;
  const cv::Mat p = renderStereoPair(map, StereoRig(), pose, 0.0, {}, plain2).left;
  const cv::Mat d = renderStereoPair(map, StereoRig(), pose, 0.0, {}, dense).left;
  const double err_adaptive = cv::norm(a, d, cv::NORM_L1), err_plain = cv::norm(p, d, cv::NORM_L1);
  EXPECT_LT(err_adaptive, 0.5 * err_plain) << "adaptive " << err_adaptive << ", plain 2x2 " << err_plain;
  int differing = 0;
  for (int v = 0; v < a.rows; ++v)
    for (int u = 0; u < a.cols; ++u) differing += a.at<cv::Vec3b>(v, u) != p.at<cv::Vec3b>(v, u);
  EXPECT_GT(differing, 200);
  EXPECT_LT(differing, a.rows * a.cols / 10);  // only pixels on or next to an edge are re-sampled
  RenderOptions bad = plain();
  bad.edge_samples_per_axis = bad.samples_per_axis;
  EXPECT_THROW(bad.validate(), Error);
  bad.edge_samples_per_axis = 17;
  EXPECT_THROW(bad.validate(), Error);
  bad.edge_samples_per_axis = 0;
  EXPECT_NO_THROW(bad.validate());
}

// The renderer settles image tiles of plain floor and sky from their corner rays, and repeats
// the slab test of the wall and goal boxes with hoisted terms: the images must be the ones of
// tracing every sample with Scene's own tests, byte for byte, also with obstacles, head pan, a
// non-nested edge grid and no refinement.
TEST(Renderer, ShortcutsGiveTheReferenceImages) {
  const FieldMap map = FieldMap::miroSot();
  Obstacle robot, ball;
  robot.position = Eigen::Vector2d(600, 560);
  robot.heading = 0.4;
  ball.kind = Obstacle::Kind::Ball;
  ball.size = 42.7;
  ball.position = Eigen::Vector2d(700, 640);
  // Objects crossing the camera plane: bench_render's five robots (one 60 mm beside the camera),
  // and a robot and a ball at the side of the camera, half in front of it.
  std::vector<Obstacle> bench, beside(2);
  for (int k = 0; k < 5; ++k) {
    Obstacle o;
    o.position = Eigen::Vector2d(300 + 150 * k, 500 + 40 * k);
    bench.push_back(o);
  }
  beside[0].position = Eigen::Vector2d(520, 560);
  beside[0].heading = 0.3;
  beside[1].kind = Obstacle::Kind::Ball;
  beside[1].size = 42.7;
  beside[1].position = Eigen::Vector2d(505, 735);
  struct Case {
    Pose2 pose;
    double pan;
    std::vector<Obstacle> obstacles;
    int samples, edge_samples;
  };
  const std::vector<Case> cases = {
      {Pose2(900, 600, 2.8), 0.0, {}, 2, 4},          {Pose2(900, 600, 2.8), 0.0, {robot, ball}, 2, 4},
      {Pose2(400, 650, kPi), 0.3, {}, 2, 4},          {Pose2(700, 150, -kPi / 2), 0.0, {}, 2, 4},
      {Pose2(120, 110, -2.4), 0.0, {}, 2, 4},          {Pose2(1300, 1000, 0.7), -0.5, {ball}, 3, 4},
      {Pose2(750, 650, 1.2), 0.0, {robot}, 2, 0},      {Pose2(1100, 300, -0.3), 0.2, {robot, ball}, 2, 5},
      {Pose2(900, 600, 2.8), 0.0, bench, 2, 4},        {Pose2(500, 650, 0.0), 0.0, beside, 2, 4},
      {Pose2(500, 650, 0.1), 0.0, beside, 2, 4},       {Pose2(40, 300, kPi / 2), 0.0, {}, 2, 4}};
  for (const Case& c : cases) {
    RenderOptions fast = plain(), reference = plain();
    fast.samples_per_axis = reference.samples_per_axis = c.samples;
    fast.edge_samples_per_axis = reference.edge_samples_per_axis = c.edge_samples;
    fast.compute_truth = reference.compute_truth = false;
    reference.reference_tracing = true;
    const StereoImages a = StereoRenderer(map, StereoRig(), fast).render(c.pose, c.pan, c.obstacles);
    const StereoImages b = StereoRenderer(map, StereoRig(), reference).render(c.pose, c.pan, c.obstacles);
    EXPECT_EQ(cv::norm(a.left, b.left, cv::NORM_INF), 0.0) << c.pose.x << " " << c.pose.y << " " << c.pose.theta;
    EXPECT_EQ(cv::norm(a.right, b.right, cv::NORM_INF), 0.0) << c.pose.x << " " << c.pose.y << " " << c.pose.theta;
  }
}

// floorIsPlain lets the renderer colour a tile of floor samples without classifying them: when it
// says yes, every point of the rectangle and within 1 mm of it must be plain floor.
TEST(Renderer, FloorIsPlainOnlyWhereEveryPointIsFloor) {
  const Scene scene = Scene::fromMap(FieldMap::miroSot());
  std::mt19937_64 rng(9);
  std::uniform_real_distribution<double> x(-250.0, 1750.0), y(-100.0, 1400.0), size(0.0, 120.0);
  int plain = 0, not_plain = 0;
  for (int k = 0; k < 20000; ++k) {
    const double x0 = x(rng), y0 = y(rng), x1 = x0 + size(rng), y1 = y0 + size(rng);
    if (!scene.floorIsPlain(x0, y0, x1, y1)) {
      ++not_plain;
      continue;
    }
    ++plain;
    for (double px = x0 - 0.99; px <= x1 + 0.99; px += (x1 - x0 + 1.98) / 12)
      for (double py = y0 - 0.99; py <= y1 + 0.99; py += (y1 - y0 + 1.98) / 12)
        ASSERT_EQ(scene.floorClassLinearScan(px, py), SurfaceClass::Floor) << "at (" << px << ", " << py << ") mm";
  }
  EXPECT_GT(plain, 2000);
  EXPECT_GT(not_plain, 2000);
  const FieldGeometry& g = scene.geometry();
  EXPECT_TRUE(scene.floorIsPlain(300, 300, 320, 320));
  EXPECT_FALSE(scene.floorIsPlain(0.5 * g.length - 30, 300, 0.5 * g.length + 30, 320));  // the halfway line
  EXPECT_FALSE(scene.floorIsPlain(-100, 100, -50, 150));                                 // beside a goal
  EXPECT_FALSE(scene.floorIsPlain(300, 320, 320, 300));                                  // empty rectangle
  EXPECT_FALSE(Scene().floorIsPlain(300, 300, 320, 320));
}

// floorClass looks the markings up in a cell grid; it must agree with testing every marking,
// everywhere, including points on and next to marking borders.
TEST(Renderer, FloorClassCellGridAgreesWithTheLinearScan) {
  const Scene scene = Scene::fromMap(FieldMap::miroSot());
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> x(-250.0, 1750.0), y(-100.0, 1400.0);
  int markings = 0;
  for (int k = 0; k < 200000; ++k) {
    const double px = x(rng), py = y(rng);
    const SurfaceClass c = scene.floorClass(px, py);
    ASSERT_EQ(c, scene.floorClassLinearScan(px, py)) << "at (" << px << ", " << py << ") mm";
    markings += c == SurfaceClass::Marking;
  }
  EXPECT_GT(markings, 1000);
  // Points on the grid lines (every 20 mm) and on the marking borders of the centre line.
  const FieldGeometry& g = scene.geometry();
  for (double px = -g.goal_depth; px <= g.length + g.goal_depth; px += 0.5 * g.line_width)
    for (double py = 0; py <= g.width; py += 20.0) ASSERT_EQ(scene.floorClass(px, py), scene.floorClassLinearScan(px, py));
}

TEST(Renderer, TruthJson) {
  const StereoImages im = renderStereoPair(FieldMap::miroSot(), StereoRig(), Pose2(400, 650, kPi), 0.0, {}, plain());
  const std::string js = truthToJson(im.truth, 12, 320, 240);
  EXPECT_NE(js.find("\"step\": 12"), std::string::npos);
  EXPECT_NE(js.find("\"left\": {"), std::string::npos);
  EXPECT_NE(js.find("\"right\": {"), std::string::npos);
  EXPECT_NE(js.find("{\"id\": 0, \"type\": \"goal_corner\""), std::string::npos) << js;
  EXPECT_NE(js.find("\"kind\": \"goal_post\""), std::string::npos);
  EXPECT_EQ(std::count(js.begin(), js.end(), '{'), std::count(js.begin(), js.end(), '}'));
  EXPECT_EQ(std::count(js.begin(), js.end(), '['), std::count(js.begin(), js.end(), ']'));
}

TEST(Renderer, RequiresFieldGeometry) {
  Landmark l;
  l.id = 0;
  l.position = Eigen::Vector3d(1, 1, 0);
  const FieldMap bare("bare", Bounds{0, 0, 10, 10}, {l});
  EXPECT_THROW(StereoRenderer(bare, StereoRig()), Error);
}

}  // namespace
}  // namespace stereoloc
