// A run on a rig of its user's choosing (src/pipeline/rig_handover.h): the rig replaces the
// dataset's, its handed-over wheel estimate goes onto the odometry, and the dataset's pixel
// observations are kept only where the new rig has the same rectified cameras. Likewise a map,
// which must hold every landmark the dataset sees.
#include "src/pipeline/rig_handover.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <fstream>
#include <string>

#include "src/core/error.h"
#include "src/sim/simulator.h"
#include "test_util.h"

namespace stereoloc {
namespace {

Dataset line() {
  SimulationConfig cfg;
  cfg.scenario.steps = 30;
  return simulate("line", 0, cfg, 3);
}

// The rig at `path` with the wheel keys a --calibration-out file carries.
void saveWithWheels(const StereoRig& rig, const std::string& path) {
  rig.save(path);
  std::ofstream(path, std::ios::app) << "wheel_scale_left: 1.02\nwheel_scale_left_sigma: 0.003\n"
                                        "wheel_scale_right: 0.97\nwheel_scale_right_sigma: 0.004\n"
                                        "wheel_base_mm: 78.5\nwheel_base_sigma_mm: 1.5\n";
}

TEST(RigHandover, SameRectifiedCamerasKeepThePixelsWithTheNewMounting) {
  const Dataset original = line();
  size_t pixel_observations = 0;
  for (const Step& s : original.steps) pixel_observations += s.observations.size();
  ASSERT_GT(pixel_observations, 10u);
  StereoRigParams p = original.rig.params();
  p.tilt_rad += 0.01;  // the mounting changes, the cameras do not
  p.camera_height_mm += 2.0;
  const StereoRig tilted(p);
  test::TempDir dir;
  saveWithWheels(tilted, dir.file("rig.yaml"));

  Dataset d = original;
  const CalibrationHandover h = useRig(d, dir.file("rig.yaml"), false);
  ASSERT_TRUE(h.wheels);
  EXPECT_DOUBLE_EQ(d.rig.params().tilt_rad, p.tilt_rad);
  EXPECT_DOUBLE_EQ(d.odometry.wheel_base_mm, 78.5);
  for (size_t k = 0; k < d.steps.size(); ++k) {
    EXPECT_DOUBLE_EQ(d.steps[k].d_left, 1.02 * original.steps[k].d_left);
    EXPECT_DOUBLE_EQ(d.steps[k].d_right, 0.97 * original.steps[k].d_right);
    for (size_t i = 0; i < d.steps[k].observations.size(); ++i) {
      const Observation& was = original.steps[k].observations[i];
      const Observation& is = d.steps[k].observations[i];
      ASSERT_TRUE(is.pixels);
      const Observation expected =
          observationFromPixels(tilted, was.landmark_id, was.type, *was.pixels, was.head_pan, was.pixel_covariance);
      EXPECT_DOUBLE_EQ(is.range, expected.range);
      EXPECT_DOUBLE_EQ(is.bearing, expected.bearing);
      EXPECT_NE(is.range, was.range);  // triangulated again: the tilt moves the floor point
      EXPECT_EQ(is.pixel_covariance, was.pixel_covariance);
    }
  }
}

TEST(RigHandover, OtherRectifiedCamerasNeedTheImagesMeasuredAgain) {
  const Dataset original = line();
  StereoRigParams p = original.rig.params();
  p.focal_px = original.rig.focal() * 1.01;
  test::TempDir dir;
  StereoRig(p).save(dir.file("other.yaml"));
  Dataset d = original;
  try {
    useRig(d, dir.file("other.yaml"), false);
    ADD_FAILURE() << "pixels of one rig were taken as pixels of another";
  } catch (const Error& e) {
    const std::string m = e.what();
    EXPECT_NE(m.find(dir.file("other.yaml")), std::string::npos) << m;
    EXPECT_NE(m.find("focal length"), std::string::npos) << m;
    EXPECT_NE(m.find("no images"), std::string::npos) << m;  // a simulation without images
  }
  d.has_images = true;
  try {
    useRig(d, dir.file("other.yaml"), false);
    ADD_FAILURE() << "pixels of one rig were taken as pixels of another";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("--frontend images"), std::string::npos) << e.what();
  }
  d.has_images = false;
  EXPECT_EQ(d.rig.focal(), original.rig.focal());  // unchanged after the refusal
  // The caller measures the images again: the rig is taken, the old pixels left to be replaced.
  const CalibrationHandover h = useRig(d, dir.file("other.yaml"), true);
  EXPECT_TRUE(h.empty());
  EXPECT_DOUBLE_EQ(d.rig.focal(), p.focal_px);
  EXPECT_DOUBLE_EQ(d.steps[5].d_left, original.steps[5].d_left);
}

// A field measured 3 mm longer is taken; a map without a landmark the dataset sees, or with
// it of another type, is refused with the file, the landmark and a step that sees it.
TEST(MapHandover, TakesAMapWithTheSeenLandmarksAndRefusesOneWithout) {
  const Dataset original = line();
  Eigen::Matrix<double, kFieldDimensionCount, 1> change = Eigen::Matrix<double, kFieldDimensionCount, 1>::Zero();
  change[0] = 3.0;
  const FieldMap longer = original.map.withDimensionChange(change);
  test::TempDir dir;
  longer.save(dir.file("longer.yaml"));
  Dataset d = original;
  useMap(d, dir.file("longer.yaml"), false);
  ASSERT_EQ(d.map.landmarks().size(), longer.landmarks().size());
  double moved = 0.0;
  for (size_t i = 0; i < longer.landmarks().size(); ++i) {
    EXPECT_EQ(d.map.landmarks()[i].position, longer.landmarks()[i].position);
    moved = std::max(moved, (d.map.landmarks()[i].position - original.map.landmarks()[i].position).norm());
  }
  EXPECT_NEAR(moved, 3.0, 1e-9);  // the far end of the field moves by the change

  // The landmark the dataset sees first, left out, then of another type.
  const Observation* first = nullptr;
  for (const Step& s : original.steps)
    for (const Observation& o : s.observations)
      if (!first && o.landmark_id >= 0) first = &o;
  ASSERT_NE(first, nullptr);
  std::vector<Landmark> without, retyped;
  for (const Landmark& l : original.map.landmarks()) {
    if (l.id != first->landmark_id) without.push_back(l);
    retyped.push_back(l);
    if (l.id == first->landmark_id)
      retyped.back().type = l.type == LandmarkType::Junction ? LandmarkType::MarkingCorner : LandmarkType::Junction;
  }
  FieldMap("without", original.map.bounds(), without).save(dir.file("without.yaml"));
  FieldMap("retyped", original.map.bounds(), retyped).save(dir.file("retyped.yaml"));
  const std::string id = "landmark " + std::to_string(first->landmark_id) + ": ";
  for (const char* name : {"without.yaml", "retyped.yaml"}) {
    Dataset refused = original;
    try {
      useMap(refused, dir.file(name), false);
      ADD_FAILURE() << name << " was taken";
    } catch (const Error& e) {
      const std::string m = e.what();
      EXPECT_EQ(m.rfind(dir.file(name) + ": " + id, 0), 0u) << m;
      EXPECT_NE(m.find("at step"), std::string::npos) << m;
    }
    EXPECT_EQ(refused.map.landmarks().size(), original.map.landmarks().size());  // unchanged after the refusal
    // The caller measures the images again on the new map: the stored observations go.
    Dataset remeasured = original;
    useMap(remeasured, dir.file(name), true);
    EXPECT_EQ(remeasured.map.name(), std::string(name).substr(0, std::string(name).find('.')));
  }
}

}  // namespace
}  // namespace stereoloc
