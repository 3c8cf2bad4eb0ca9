#include <gtest/gtest.h>

#include <Eigen/LU>
#include <fstream>
#include <map>
#include <random>
#include <sstream>

#include "src/core/atomic_file.h"
#include "src/core/stereo_rig.h"
#include "src/core/types.h"
#include "test_util.h"

namespace stereoloc {
namespace {

StereoRig tiltedRig() {
  StereoRigParams p;
  p.tilt_rad = deg2rad(12);
  p.offset_x_mm = 15;
  p.principal_u = 161.3;
  p.principal_v = 118.2;
  return StereoRig(p);
}

}  // namespace

TEST(StereoRig, DefaultsAreTheThesisHead) {
  const StereoRig rig;
  EXPECT_NEAR(rig.focal(), 160.0 / std::tan(deg2rad(30)), 1e-9);
  EXPECT_NEAR(rig.focal(), 277.128, 1e-3);
  EXPECT_DOUBLE_EQ(rig.principalU(), 159.5);
  EXPECT_DOUBLE_EQ(rig.principalV(), 119.5);
  EXPECT_DOUBLE_EQ(rig.params().baseline_mm, 30);
  EXPECT_DOUBLE_EQ(rig.params().camera_height_mm, 70);
}

TEST(StereoRig, ProjectTriangulateRoundTripOverRandomPointsInView) {
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<double> U(-1, 1);
  for (const StereoRig& rig : {StereoRig(), tiltedRig()}) {
    int in_view = 0;
    for (int i = 0; i < 20000 && in_view < 2000; ++i) {
      const Eigen::Vector3d p(150 + 1800 * (0.5 + 0.5 * U(rng)), 1000 * U(rng), 150 * U(rng));
      const double pan = 0.8 * U(rng);
      const auto px = rig.project(p, pan);
      if (!px || !rig.inImages(*px) || px->disparity() < 1.0) continue;
      ++in_view;
      EXPECT_LT((rig.triangulate(*px, pan) - p).norm(), 1e-9) << p.transpose();
    }
    EXPECT_GE(in_view, 1000);
  }
}

TEST(StereoRig, MatchesThesis34WithoutTiltOrPan) {
  // (3.4): x = f b / (u_l - u_r), y = -b/2 (u_l + u_r - 2 o_u)/(u_l - u_r), z = -b (v - o_v)/(u_l - u_r).
  const StereoRig rig;
  const double f = rig.focal(), b = 30, ou = rig.principalU(), ov = rig.principalV();
  const StereoPixels px{180.0, 100.0, 170.0, 100.0};
  const Eigen::Vector3d pv = rig.triangulateVision(px);
  EXPECT_NEAR(pv.x(), f * b / 10.0, 1e-9);
  EXPECT_NEAR(pv.y(), -0.5 * b * (350.0 - 2 * ou) / 10.0, 1e-9);
  EXPECT_NEAR(pv.z(), -b * (100.0 - ov) / 10.0, 1e-9);
  // In C0 the camera height is added.
  EXPECT_NEAR(rig.triangulate(px, 0.0).z(), pv.z() + 70.0, 1e-9);
}

TEST(StereoRig, PanRotatesBearing) {
  const StereoRig rig;
  const auto px = rig.pixelsFromRangeBearing(RangeBearing{800, 0.1}, 0.0, 0.0);
  ASSERT_TRUE(px);
  const double pan = 0.4;
  const auto px_pan = rig.pixelsFromRangeBearing(RangeBearing{800, 0.1 + pan}, 0.0, pan);
  ASSERT_TRUE(px_pan);
  EXPECT_NEAR(px->u_left, px_pan->u_left, 1e-9);
  EXPECT_NEAR(px->u_right, px_pan->u_right, 1e-9);
  const RangeBearing rb = rig.rangeBearing(*px_pan, pan);
  EXPECT_NEAR(rb.range, 800, 1e-9);
  EXPECT_NEAR(rb.bearing, 0.1 + pan, 1e-12);
}

TEST(StereoRig, RangeBearingJacobianMatchesCentralDifferences) {
  std::mt19937_64 rng(8);
  std::uniform_real_distribution<double> U(-1, 1);
  for (const StereoRig& rig : {StereoRig(), tiltedRig()}) {
    int checked = 0;
    for (int i = 0; i < 5000 && checked < 300; ++i) {
      const double pan = (i % 4 == 0) ? kPi - 1e-8 : 0.5 * U(rng);  // bearings near +-pi too
      const auto px = rig.pixelsFromRangeBearing(RangeBearing{300 + 1500 * (0.5 + 0.5 * U(rng)), pan + 0.4 * U(rng)},
                                                 40 * U(rng), pan);
      if (!px || !rig.inImages(*px)) continue;
      ++checked;
      StereoRig::Matrix24d J;
      rig.rangeBearing(*px, pan, &J);
      auto f = [&](const Eigen::Vector4d& v) {
        const RangeBearing rb = rig.rangeBearing(StereoPixels{v(0), v(1), v(2), v(3)}, pan);
        return Eigen::Vector2d(rb.range, rb.bearing);
      };
      auto wrapMinus = [](const Eigen::Vector2d& a, const Eigen::Vector2d& b) {
        return Eigen::Vector2d(a.x() - b.x(), angleDiff(a.y(), b.y()));
      };
      const Eigen::Vector4d x(px->u_left, px->v_left, px->u_right, px->v_right);
      EXPECT_TRUE(test::jacobianMatches(J, numericJacobian<2, 4>(f, x, wrapMinus)));
      StereoRig::Matrix34d Jp;
      rig.triangulate(*px, pan, &Jp);
      auto g = [&](const Eigen::Vector4d& v) { return rig.triangulate(StereoPixels{v(0), v(1), v(2), v(3)}, pan); };
      EXPECT_TRUE(test::jacobianMatches(Jp, numericJacobian<3, 4>(g, x)));
    }
    EXPECT_GE(checked, 300);
  }
}

TEST(StereoRig, CovarianceMatchesThesisClosedFormR11) {
  // (5.32) element R11 for beta = gamma = 0 and the v columns not contributing:
  // R11 = b^2 s^2 / (r^2 d^4) (2 f^2 x^2 + y^2 ((u_l-o_u)^2 + (u_r-o_u)^2) - 2 f x y (u_l + u_r - 2 o_u)).
  const StereoRig rig;
  const double f = rig.focal(), b = 30, ou = rig.principalU(), s = 0.7;
  const StereoPixels px{200.0, 119.5, 188.0, 119.5};
  const Eigen::Vector3d p = rig.triangulate(px, 0.0);
  const double x = p.x(), y = p.y(), r2 = x * x + y * y, d = 12.0;
  const double a = px.u_left - ou, c = px.u_right - ou;
  const double R11 = b * b * s * s / (r2 * std::pow(d, 4)) * (2 * f * f * x * x + y * y * (a * a + c * c) - 2 * f * x * y * (a + c));
  const Eigen::Matrix2d R = rig.rangeBearingCovariance(px, 0.0, s);
  EXPECT_NEAR(R(0, 0), R11, 1e-9 * R11);
  EXPECT_NEAR(R(0, 1), R(1, 0), 0);
  EXPECT_GT(R.determinant(), 0);
}

TEST(StereoRig, CovarianceAgreesWithMonteCarlo) {
  const StereoRig rig;
  const auto px = rig.pixelsFromRangeBearing(RangeBearing{900, 0.3}, 0.0, 0.0);
  ASSERT_TRUE(px);
  const double sigma = 0.3;
  std::mt19937_64 rng(9);
  std::normal_distribution<double> N(0, sigma);
  Eigen::Matrix2d acc = Eigen::Matrix2d::Zero();
  const int n = 100000;
  for (int i = 0; i < n; ++i) {
    StereoPixels q = *px;
    q.u_left += N(rng);
    q.u_right += N(rng);
    q.v_left += N(rng);
    q.v_right += N(rng);
    const RangeBearing rb = rig.rangeBearing(q, 0.0);
    const Eigen::Vector2d e(rb.range - 900, rb.bearing - 0.3);
    acc += e * e.transpose();
  }
  const Eigen::Matrix2d R = rig.rangeBearingCovariance(*px, 0.0, sigma);
  // First-order propagation: range variance within a few percent at this disparity.
  EXPECT_NEAR(acc(0, 0) / n, R(0, 0), 0.05 * R(0, 0));
  EXPECT_NEAR(acc(1, 1) / n, R(1, 1), 0.05 * R(1, 1));
}

TEST(StereoRig, DegenerateAndBadInput) {
  const StereoRig rig;
  EXPECT_THROW(rig.triangulate(StereoPixels{100, 100, 100, 100}, 0.0), GeometryError);  // zero disparity
  EXPECT_THROW(rig.triangulate(StereoPixels{100, 100, 105, 100}, 0.0), GeometryError);  // negative
  EXPECT_THROW(rig.triangulate(StereoPixels{std::nan(""), 100, 90, 100}, 0.0), GeometryError);
  EXPECT_FALSE(rig.project(Eigen::Vector3d(-100, 0, 0), 0.0).has_value());  // behind
  StereoRigParams p;
  p.baseline_mm = 0;
  EXPECT_THROW(StereoRig{p}, Error);
  p = StereoRigParams();
  p.hfov_rad = 4;
  EXPECT_THROW(StereoRig{p}, Error);
}

TEST(StereoRig, YamlRoundTripAndErrors) {
  test::TempDir dir;
  const StereoRig rig = tiltedRig();
  rig.save(dir.file("rig.yaml"));
  const StereoRig back = StereoRig::load(dir.file("rig.yaml"));
  EXPECT_DOUBLE_EQ(back.focal(), rig.focal());
  EXPECT_DOUBLE_EQ(back.principalU(), rig.principalU());
  EXPECT_DOUBLE_EQ(back.params().tilt_rad, rig.params().tilt_rad);
  EXPECT_DOUBLE_EQ(back.params().offset_x_mm, rig.params().offset_x_mm);
  // The shipped default file loads and equals the built-in default.
  const StereoRig shipped = StereoRig::load(std::string(STEREOLOC_DATA_DIR) + "/rig_default.yaml");
  EXPECT_DOUBLE_EQ(shipped.focal(), StereoRig().focal());
  // Bad value: the error names the file and the key.
  writeFileAtomically(dir.file("bad.yaml"), "%YAML:1.0\n---\nimage_width: 320\nimage_height: 240\nfocal_px: 277\n"
                                            "baseline_mm: -3\ncamera_height_mm: 70\ntilt_rad: 0\n");
  try {
    StereoRig::load(dir.file("bad.yaml"));
    FAIL() << "expected an error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("bad.yaml"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("baseline_mm"), std::string::npos) << e.what();
  }
  writeFileAtomically(dir.file("nan.yaml"), "%YAML:1.0\n---\nfocal_px: .nan\n");
  EXPECT_THROW(StereoRig::load(dir.file("nan.yaml")), Error);
  EXPECT_THROW(StereoRig::load(dir.file("missing.yaml")), Error);
}

// A rig file states the cameras' geometry and the head's mounting: a key lost from it (a file
// cut short, an edit) is an error naming the key, not the thesis's default; a value the struct
// reads as "use the default" (focal_px <= 0, a negative principal point) is an error in a file.
TEST(StereoRig, FileMustStateGeometryAndMounting) {
  test::TempDir dir;
  tiltedRig().save(dir.file("rig.yaml"));
  std::ostringstream text;
  text << std::ifstream(dir.file("rig.yaml")).rdbuf();
  const std::string good = text.str();
  // The error of the file with each key of `edits` replaced by its value ("": line removed).
  auto edited = [&](const std::map<std::string, std::string>& edits) {
    std::string out;
    std::istringstream in(good);
    for (std::string line; std::getline(in, line);) {
      const auto it = edits.find(line.substr(0, line.find(':')));
      if (it == edits.end()) out += line + "\n";
      else if (!it->second.empty()) out += it->first + ": " + it->second + "\n";
    }
    writeFileAtomically(dir.file("edited.yaml"), out);
    return test::errorOf([&] { StereoRig::load(dir.file("edited.yaml")); });
  };
  auto withLine = [&](const std::string& key, const std::string& value) { return edited({{key, value}}); };
  const std::string where = dir.file("edited.yaml") + ": ";
  for (const char* key : {"image_width", "image_height", "baseline_mm", "camera_height_mm", "tilt_rad"})
    EXPECT_NE(withLine(key, "").find(where + key + ": missing"), std::string::npos) << key;
  // Either focal_px or hfov_rad gives the focal length.
  EXPECT_EQ(withLine("focal_px", ""), "");
  EXPECT_EQ(withLine("hfov_rad", ""), "");
  EXPECT_NE(edited({{"focal_px", ""}, {"hfov_rad", ""}}).find(where + "focal_px: missing (neither focal_px nor hfov_rad)"),
            std::string::npos);
  EXPECT_NE(withLine("focal_px", "-1").find(where + "focal_px: must be within [1, 1e6] px"), std::string::npos);
  EXPECT_NE(withLine("focal_px", "0.5").find(where + "focal_px: must be within [1, 1e6] px"), std::string::npos);
  EXPECT_NE(withLine("hfov_rad", "-1").find(where + "hfov_rad: must be in (0, pi)"), std::string::npos);
  EXPECT_NE(withLine("principal_u", "-1").find(where + "principal_u: must lie in the image"), std::string::npos);
  EXPECT_NE(withLine("principal_v", "240").find(where + "principal_v: must lie in the image"), std::string::npos);
  // The optional keys take their documented defaults.
  EXPECT_EQ(withLine("max_range_mm", ""), "");
  EXPECT_DOUBLE_EQ(StereoRig::load(dir.file("edited.yaml")).params().max_range_mm, StereoRigParams().max_range_mm);
}

// A mounting file for a head whose cameras come from a checkerboard calibration: the mounting
// and noise fields alone, the mounting required.
TEST(StereoRig, MountingAloneLoadsWithoutCameraKeys) {
  test::TempDir dir;
  writeFileAtomically(dir.file("m.yaml"), "%YAML:1.0\n---\ncamera_height_mm: 72.5\ntilt_rad: 0.2\npixel_sigma: 0.3\n");
  const StereoRigParams m = StereoRig::loadMounting(dir.file("m.yaml"));
  EXPECT_DOUBLE_EQ(m.camera_height_mm, 72.5);
  EXPECT_DOUBLE_EQ(m.tilt_rad, 0.2);
  EXPECT_DOUBLE_EQ(m.pixel_sigma, 0.3);
  EXPECT_DOUBLE_EQ(m.offset_x_mm, 0.0);
  EXPECT_NE(test::errorOf([&] { StereoRig::load(dir.file("m.yaml")); }).find("image_width: missing"), std::string::npos);
  writeFileAtomically(dir.file("no_tilt.yaml"), "%YAML:1.0\n---\ncamera_height_mm: 72.5\n");
  EXPECT_NE(test::errorOf([&] { StereoRig::loadMounting(dir.file("no_tilt.yaml")); })
                .find(dir.file("no_tilt.yaml") + ": tilt_rad: missing"),
            std::string::npos);
  writeFileAtomically(dir.file("bad.yaml"), "%YAML:1.0\n---\ncamera_height_mm: 72.5\ntilt_rad: 2\n");
  EXPECT_NE(test::errorOf([&] { StereoRig::loadMounting(dir.file("bad.yaml")); })
                .find(dir.file("bad.yaml") + ": stereo rig: tilt_rad"),
            std::string::npos);
  // A whole rig serves as a mounting too.
  tiltedRig().save(dir.file("rig.yaml"));
  EXPECT_DOUBLE_EQ(StereoRig::loadMounting(dir.file("rig.yaml")).tilt_rad, tiltedRig().params().tilt_rad);
}

TEST(Observation, FromPixelsCarriesRangeBearingAndCovariance) {
  const StereoRig rig;
  const auto px = rig.pixelsFromRangeBearing(RangeBearing{700, -0.2}, 25.0, 0.0);
  ASSERT_TRUE(px);
  const Observation o = observationFromPixels(rig, 3, LandmarkType::GoalCorner, *px, 0.0, 0.5);
  EXPECT_NEAR(o.range, 700, 1e-9);
  EXPECT_NEAR(o.bearing, -0.2, 1e-12);
  EXPECT_EQ(o.landmark_id, 3);
  EXPECT_TRUE(o.pixels.has_value());
  EXPECT_GT(o.covariance(0, 0), 0);
  EXPECT_THROW(observationFromRangeBearing(1, LandmarkType::Point, -5, 0, 1, 1), Error);
}

}  // namespace stereoloc
