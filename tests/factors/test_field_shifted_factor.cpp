// FieldShiftedFactor: the wrapped sighting factor evaluated with the landmark where the changed
// field puts it, for a factor on the pose alone and one with a calibration block; Jacobians
// against central differences; bad wrapping.
#include "factors/field_shifted_factor.h"

#include <gtest/gtest.h>

#include <memory>
#include <vector>

#include "factors/calibration_prior_factor.h"
#include "factors/factor_check.h"
#include "factors/range_bearing_factor.h"
#include "factors/stereo_pixel_calibration_factor.h"
#include "factors/stereo_pixel_factor.h"
#include "src/core/error.h"
#include "src/core/measurement_model.h"
#include "src/core/stereo_rig.h"

namespace stereoloc {
namespace {

using FieldVector = Eigen::Matrix<double, kFieldDimensionCount, 1>;

FieldVector someChange() {
  FieldVector f;
  f << 6.0, -4.0, 3.0, 1.5, -2.5, 2.0, -3.0, 4.5, -1.0;
  return f;
}

double residualOf(const ceres::CostFunction& cost, const std::vector<const double*>& blocks, Eigen::VectorXd* r) {
  r->resize(cost.num_residuals());
  EXPECT_TRUE(cost.Evaluate(blocks.data(), r->data(), nullptr));
  return r->norm();
}

TEST(FieldShiftedFactor, SeesTheLandmarkWhereTheChangedFieldPutsIt) {
  const FieldMap map = FieldMap::miroSot();
  const FieldVector f = someChange();
  const FieldMap changed = map.withDimensionChange(f);
  const StereoRig rig;
  const double pose[3] = {900.0, 500.0, 0.4};
  int checked = 0;
  for (const Landmark& l : map.landmarks()) {
    const Eigen::Vector2d local = transformToLocal(Pose2(pose[0], pose[1], pose[2]), changed.at(l.id).xy());
    const auto px = rig.project(Eigen::Vector3d(local.x(), local.y(), l.position.z()), 0.0);
    if (!px || local.x() < 200) continue;
    StereoPixels z = *px;
    z.u_left += 0.3;
    z.v_right -= 0.2;
    const FieldShiftedFactor::LandmarkJacobian J = map.fieldJacobians().at(l.id);
    // A factor on the pose alone.
    const FieldShiftedFactor shifted(StereoPixelFactor::Create(rig, l.position, z, 0.0, 0.5, PixelResiduals::All), J);
    std::unique_ptr<ceres::CostFunction> moved(
        StereoPixelFactor::Create(rig, changed.at(l.id).position, z, 0.0, 0.5, PixelResiduals::All));
    Eigen::VectorXd a, b;
    residualOf(shifted, {pose, f.data()}, &a);
    residualOf(*moved, {pose}, &b);
    EXPECT_LT((a - b).norm(), 1e-9 * (1 + b.norm())) << l.name;
    const FactorCheck c = checkFactorJacobians(shifted, {pose, f.data()});
    EXPECT_TRUE(c.ok) << l.name << ": " << c.message;

    // A factor with the stereo calibration block, the field after it.
    const double g[6] = {0.002, 1.01, 0.3, -0.2, 0.001, -0.002};
    const FieldShiftedFactor calibrated(
        StereoPixelCalibrationFactor::Create(rig, l.position, z, 0.0, 0.5, PixelResiduals::All), J);
    std::unique_ptr<ceres::CostFunction> moved_calibrated(
        StereoPixelCalibrationFactor::Create(rig, changed.at(l.id).position, z, 0.0, 0.5, PixelResiduals::All));
    residualOf(calibrated, {pose, g, f.data()}, &a);
    residualOf(*moved_calibrated, {pose, g}, &b);
    EXPECT_LT((a - b).norm(), 1e-9 * (1 + b.norm())) << l.name;
    const FactorCheck cc = checkFactorJacobians(calibrated, {pose, g, f.data()});
    EXPECT_TRUE(cc.ok) << l.name << ": " << cc.message;
    ++checked;
  }
  EXPECT_GE(checked, 3);
}

TEST(FieldShiftedFactor, RangeBearingAndBadWrapping) {
  const FieldMap map = FieldMap::miroSot();
  const Landmark& l = map.landmarks().front();
  const FieldVector f = someChange();
  const double pose[3] = {400.0, 300.0, -2.9};
  const Eigen::Vector2d z = predictRangeBearing(Pose2(pose[0], pose[1], pose[2]), l.xy()) + Eigen::Vector2d(3.0, 0.01);
  const Eigen::Matrix2d R = Eigen::Vector2d(25.0, 1e-4).asDiagonal();
  const FieldShiftedFactor shifted(RangeBearingFactor::Create(l.xy(), z, R), map.fieldJacobians().at(l.id));
  std::unique_ptr<ceres::CostFunction> moved(RangeBearingFactor::Create(map.withDimensionChange(f).at(l.id).xy(), z, R));
  Eigen::VectorXd a, b;
  residualOf(shifted, {pose, f.data()}, &a);
  residualOf(*moved, {pose}, &b);
  EXPECT_LT((a - b).norm(), 1e-9 * (1 + b.norm()));
  const FactorCheck c = checkFactorJacobians(shifted, {pose, f.data()});
  EXPECT_TRUE(c.ok) << c.message;
  // The inner factor's first block must be the pose.
  EXPECT_THROW(FieldShiftedFactor(CalibrationPriorFactor<6>::Create(Eigen::Matrix<double, 6, 1>::Zero(),
                                                                    Eigen::Matrix<double, 6, 6>::Identity()),
                                  map.fieldJacobians().at(l.id)),
               Error);
  // Only a map its geometry derives has a field Jacobian.
  std::vector<Landmark> own = map.landmarks();
  own[0].position.x() += 1.0;
  const FieldMap edited("edited", map.bounds(), own, *map.geometry());
  EXPECT_THROW(edited.fieldJacobians(), Error);
  EXPECT_EQ(map.fieldJacobians().size(), map.landmarks().size());
}

}  // namespace
}  // namespace stereoloc
