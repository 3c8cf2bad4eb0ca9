// The accuracy study's building blocks: seeds, rows and their CSV form, option checks.
#include <gtest/gtest.h>

#include <fstream>

#include "src/pipeline/usage_error.h"
#include "src/study/study.h"
#include "src/study/study_rows.h"
#include "src/study/study_trial.h"
#include "test_util.h"

namespace stereoloc {
namespace {

TEST(Study, TrialSeedsDifferPerScenarioAndTrialAndRepeat) {
  EXPECT_EQ(trialSeed(1, "circle", 0), trialSeed(1, "circle", 0));
  EXPECT_NE(trialSeed(1, "circle", 0), trialSeed(1, "circle", 1));
  EXPECT_NE(trialSeed(1, "circle", 0), trialSeed(1, "line", 0));
  EXPECT_NE(trialSeed(1, "circle", 0), trialSeed(2, "circle", 0));
}

TEST(StudyRows, TrialAndStepRowsSurviveTheirCsvExactly) {
  test::TempDir dir;
  study::TrialRow t;
  t.scenario = "circle";
  t.method = "ekf:random";
  t.trial = 3;
  t.steps = 100;
  t.estimates = 99;
  t.sse_position = 1.0 / 3.0;
  for (double v : {12.5, 0.1, 1e-9}) t.distance.add(v);
  t.nees_count = 2;
  t.nees_sum = 6.000000000000001;
  t.nees_position_sum = 4.25;
  t.nees_heading_sum = 1.0000000000000002;
  study::StepRow s;
  s.scenario = "line";
  s.method = "batch";
  s.step = 7;
  s.dx = -0.1;
  s.stheta = 2e-17;
  {
    std::ofstream out(dir.file("trials.csv"));
    out << study::kTrialHeader << "\n" << study::toCsv(t) << "\n";
    std::ofstream steps(dir.file("steps.csv"));
    steps << study::kStepHeader << "\n" << study::toCsv(s) << "\n";
  }
  const std::vector<study::TrialRow> tr = study::readTrialRows(dir.file("trials.csv"));
  ASSERT_EQ(tr.size(), 1u);
  EXPECT_EQ(study::toCsv(tr[0]), study::toCsv(t));
  EXPECT_EQ(tr[0].distance.min, 1e-9);
  const std::vector<study::StepRow> sr = study::readStepRows(dir.file("steps.csv"));
  ASSERT_EQ(sr.size(), 1u);
  EXPECT_EQ(study::toCsv(sr[0]), study::toCsv(s));
  EXPECT_FALSE(sr[0].nees.has_value());
}

TEST(StudyRows, SummaryPoolsTrialsBySums) {
  StudyConfig c;
  c.scenarios = {"circle"};
  c.methods = {"ekf"};
  study::TrialRow a, b;
  a.scenario = b.scenario = "circle";
  a.method = b.method = "ekf";
  a.estimates = 1;
  a.sse_position = 9;
  b.estimates = 3;
  b.sse_position = 7;
  a.nees_count = 1;
  a.nees_sum = 5;
  a.nees_position_sum = 4;
  a.nees_heading_sum = 0.5;
  b.nees_count = 3;
  b.nees_sum = 7;
  b.nees_position_sum = 4;
  b.nees_heading_sum = 1.5;
  const std::vector<study::SummaryRow> s = study::summarise(c, {a, b});
  ASSERT_EQ(s.size(), 1u);
  EXPECT_EQ(s[0].trials, 2);
  EXPECT_DOUBLE_EQ(s[0].rmse(), 2.0);  // sqrt(16 / 4)
  EXPECT_DOUBLE_EQ(s[0].meanNees(), 3.0);  // 12 / 4 estimates
  EXPECT_DOUBLE_EQ(s[0].meanPositionNees(), 2.0);
  EXPECT_DOUBLE_EQ(s[0].meanHeadingNees(), 0.5);
}

TEST(StudyRows, TheFieldsDimensionsAreCalibrationParameters) {
  // A field calibration's nine dimensions follow the rig's parameters in calibration.csv, named
  // as saveAsRig names them, against the field error the world drew (0 where it drew none).
  CalibrationEstimate e;
  e.field = true;
  for (int k = 0; k < kFieldDimensionCount; ++k) {
    e.field_dimensions_mm[k] = 0.5 * k;
    e.field_covariance(k, k) = 1.0 + k;
  }
  const study::CalibrationValues v = study::calibrationValues(e, StereoRig());
  for (int k = 0; k < kFieldDimensionCount; ++k) {
    const int i = study::kFirstFieldCalibrationParameter + k;
    EXPECT_EQ(std::string(study::kCalibrationParameters[i]), std::string("field_") + kFieldDimensions[k].name + "_mm");
    EXPECT_TRUE(v.estimated[i]);
    EXPECT_EQ(v.value[i], 0.5 * k);
    EXPECT_EQ(v.variance[i], 1.0 + k);
  }
  EXPECT_FALSE(v.estimated[0]);  // no wheel block
  e.field = false;
  EXPECT_FALSE(study::calibrationValues(e, StereoRig()).estimated[study::kFirstFieldCalibrationParameter]);
  Dataset d;
  SimulationTrace trace;
  EXPECT_EQ(study::trueCalibration(d, trace)[study::kFirstFieldCalibrationParameter + 2], 0.0);
  trace.errors.field_dimension_mm.assign(kFieldDimensionCount, 0.0);
  trace.errors.field_dimension_mm[2] = -1.75;
  EXPECT_EQ(study::trueCalibration(d, trace)[study::kFirstFieldCalibrationParameter + 2], -1.75);
}

TEST(Study, BadOptionsAreUsageErrorsBeforeAnyFileIsWritten) {
  test::TempDir dir;
  StudyConfig c;
  c.out_dir = dir.file("s");
  c.log = nullptr;
  c.frontend = "pixels";
  c.trials = 0;
  EXPECT_THROW(runStudy(c), UsageError);
  c.trials = 1;
  c.scenarios = {"moon"};
  EXPECT_THROW(runStudy(c), UsageError);
  c.scenarios = {"circle"};
  c.methods = {"ekf:sideways"};
  EXPECT_THROW(runStudy(c), UsageError);
  EXPECT_FALSE(std::filesystem::exists(c.out_dir));
}

}  // namespace
}  // namespace stereoloc
