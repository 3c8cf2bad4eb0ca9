// `localize` and `refine` with a noise model whose wheels drift (UnmodelledNoise::
// wheel_scale_drift): the batch, which holds one wheel calibration for the run, says so in one
// line; the window and the EKF, which follow the drift, do not. A field measured by the field
// block is written as the next drive's map, which `--map` runs on.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <fstream>

#include <Eigen/Core>
#include <opencv2/core.hpp>
#include <string>

#include "cli_util.h"
#include "src/core/field_map.h"
#include "src/io/dataset.h"
#include "test_util.h"

namespace stereoloc {
namespace {

TEST(CliLocalize, TheBatchSaysItHoldsDriftingWheelsConstant) {
  test::TempDir dir("cli_localize_drift");
  const std::string ds = dir.file("ds");
  const test::CliRun sim = test::runCli("simulate --scenario random-walk --steps 300 --seed 3 --out " + ds);
  ASSERT_EQ(sim.exit_code, 0) << sim.output;
  const std::string drifting = dir.file("drift.yaml");
  std::ofstream(drifting) << "%YAML:1.0\n---\nwheel_scale_drift: 0.01\nwheel_base_drift: 0.02\n";
  const std::string note = "the batch estimates one wheel calibration for the whole run";
  for (const std::string& command : {"localize " + ds + " --method batch", "refine " + ds}) {
    const std::string run = command + " --calibrate odometry --out " + dir.file("est.csv");
    const test::CliRun with = test::runCli(run + " --noise-model " + drifting);
    ASSERT_EQ(with.exit_code, 0) << with.output;
    EXPECT_NE(with.output.find(note), std::string::npos) << with.output;
    const test::CliRun without = test::runCli(run);
    ASSERT_EQ(without.exit_code, 0) << without.output;
    EXPECT_EQ(without.output.find(note), std::string::npos) << without.output;
  }
  for (const std::string method : {"window", "ekf"}) {
    const test::CliRun r = test::runCli("localize " + ds + " --method " + method + " --calibrate odometry --noise-model " +
                                        drifting + " --out " + dir.file("est.csv"));
    ASSERT_EQ(r.exit_code, 0) << r.output;
    EXPECT_EQ(r.output.find(note), std::string::npos) << r.output;
    EXPECT_NE(r.output.find("calibration: wheel scales"), std::string::npos) << r.output;
  }
}

// A short drive on a field whose dimensions are off (data/profile_hand_built_field.yaml), into `ds`.
void simulateHandBuiltField(const std::string& ds) {
  const test::CliRun sim = test::runCli("simulate --scenario circle --steps 60 --seed 2 --profile " +
                                        std::string(STEREOLOC_DATA_DIR) + "/profile_hand_built_field.yaml --out " + ds);
  ASSERT_EQ(sim.exit_code, 0) << sim.output;
}

TEST(CliLocalize, TheMeasuredFieldIsTheNextDrivesMap) {
  test::TempDir dir("cli_localize_field");
  const std::string ds = dir.file("ds");
  ASSERT_NO_FATAL_FAILURE(simulateHandBuiltField(ds));
  for (const std::string method : {"batch", "window", "ekf", "refine"}) {
    const std::string map = dir.file(method + "_map.yaml"), rig = dir.file(method + "_rig.yaml");
    const std::string command = method == "refine" ? "refine " + ds : "localize " + ds + " --method " + method;
    const test::CliRun r = test::runCli(command + " --calibrate odometry,stereo,field --calibration-out " + rig +
                                        " --field-out " + map + " --out " + dir.file("est.csv"));
    ASSERT_EQ(r.exit_code, 0) << r.output;
    EXPECT_NE(r.output.find("calibration: field dimensions' change length "), std::string::npos) << r.output;
    // The map carries the estimate the rig file states.
    cv::FileStorage fs(rig, cv::FileStorage::READ);
    Eigen::Matrix<double, kFieldDimensionCount, 1> change;
    for (int k = 0; k < kFieldDimensionCount; ++k)
      change[k] = static_cast<double>(fs[std::string("field_") + kFieldDimensions[k].name + "_mm"]);
    EXPECT_GT(change.cwiseAbs().maxCoeff(), 0.0) << method;
    const FieldMap measured = FieldMap::load(map), expected = loadDataset(ds).map.withDimensionChange(change);
    ASSERT_EQ(measured.landmarks().size(), expected.landmarks().size());
    for (size_t i = 0; i < expected.landmarks().size(); ++i)
      EXPECT_LT((measured.landmarks()[i].position - expected.landmarks()[i].position).norm(), 1e-9) << method;
    EXPECT_TRUE(derivesFromGeometry(measured));  // a field the next drive can measure again
    // ... with the estimate's covariance as its prior.
    ASSERT_TRUE(measured.dimensionCovariance().has_value()) << method;
    for (int k = 0; k < kFieldDimensionCount; ++k)
      EXPECT_NEAR(std::sqrt((*measured.dimensionCovariance())(k, k)),
                  static_cast<double>(fs[std::string("field_") + kFieldDimensions[k].name + "_sigma_mm"]), 1e-9)
          << method;
  }
  const test::CliRun without = test::runCli("localize " + ds + " --method batch --calibrate odometry,stereo --field-out " +
                                            dir.file("m.yaml") + " --out " + dir.file("est.csv"));
  EXPECT_EQ(without.exit_code, 2) << without.output;
  EXPECT_NE(without.output.find("--field-out"), std::string::npos) << without.output;
}

// `--map`: the same drive on the map of the field as built (its dimensions from the dataset's
// truth) is closer to the truth than on the map as drawn, with and without the field block; a
// map without the landmarks the dataset sees is refused, naming the file.
TEST(CliLocalize, RunsOnTheMapItIsGiven) {
  test::TempDir dir("cli_localize_map");
  const std::string ds = dir.file("ds");
  ASSERT_NO_FATAL_FAILURE(simulateHandBuiltField(ds));
  cv::FileStorage errors(ds + "/errors.yaml", cv::FileStorage::READ);
  Eigen::Matrix<double, kFieldDimensionCount, 1> built;
  for (int k = 0; k < kFieldDimensionCount; ++k)
    built[k] = static_cast<double>(errors[std::string("field_") + kFieldDimensions[k].name + "_mm"]);
  ASSERT_GT(built.cwiseAbs().maxCoeff(), 1.0);
  const std::string as_built = dir.file("as_built.yaml");
  loadDataset(ds).map.withDimensionChange(built).save(as_built);
  for (const std::string calibrate : {"odometry,stereo", "odometry,stereo,field"}) {
    const std::string run =
        "localize " + ds + " --method batch --calibrate " + calibrate + " --out " + dir.file("e.csv");
    const test::CliRun drawn = test::runCli(run), measured = test::runCli(run + " --map " + as_built);
    ASSERT_EQ(drawn.exit_code, 0) << drawn.output;
    ASSERT_EQ(measured.exit_code, 0) << measured.output;
    std::printf("%s: position RMSE %.2f mm on the map as drawn, %.2f mm on the field as built\n", calibrate.c_str(),
                test::printedPositionRmse(drawn.output), test::printedPositionRmse(measured.output));
    EXPECT_LT(test::printedPositionRmse(measured.output), test::printedPositionRmse(drawn.output)) << calibrate;
  }
  const std::string empty = dir.file("empty.yaml");
  FieldMap("empty", FieldMap::miroSot().bounds(), {}).save(empty);
  const test::CliRun refused =
      test::runCli("localize " + ds + " --method batch --map " + empty + " --out " + dir.file("e.csv"));
  EXPECT_EQ(refused.exit_code, 1) << refused.output;
  EXPECT_NE(refused.output.find(empty + ": landmark "), std::string::npos) << refused.output;
}

}  // namespace
}  // namespace stereoloc
