// `stereoloc fixstudy`: tables in the thesis's format with the thesis's numbers beside ours,
// deterministic per seed, files written, bad arguments rejected with exit code 2.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdio>
#include <fstream>
#include <sstream>

#include "cli_util.h"
#include "test_util.h"

namespace stereoloc {
namespace {

TEST(CliFixstudy, PrintsBothTablesWithThesisNumbersAndWritesFiles) {
  test::TempDir dir("fixstudy");
  const std::string tables = std::string(STEREOLOC_DATA_DIR) + "/thesis_tables.yaml";
  const test::CliRun r =
      test::runCli("fixstudy --category rect --method both --seed 3 --tables " + tables + " --out " + dir.path());
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("Table 6.4: two landmarks (fix2), category rect"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("Table 6.9: one landmark + compass (fix1), category rect"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("78.56"), std::string::npos) << "thesis Table 6.4 dx mean missing\n" << r.output;
  EXPECT_NE(r.output.find("91.51"), std::string::npos) << "thesis Table 6.9 dy mean at 10 deg missing\n" << r.output;
  EXPECT_NE(r.output.find("fixes: "), std::string::npos);
  EXPECT_NE(r.output.find("NEES: mean 3-dof"), std::string::npos);
  EXPECT_NE(r.output.find("covariance: sigma_points"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("linearisation holds when the nonlinearity <= 0.05"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("  linearisation holds "), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("  linearisation does not "), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("  separation 20-40 deg "), std::string::npos) << r.output;  // fix2 by geometry
  EXPECT_NE(r.output.find("  holds per fix "), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("3-dof variance"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("band from it ["), std::string::npos) << r.output;  // from the sample variance
  const std::string txt = test::readFile(dir.file("fixstudy.txt"));
  EXPECT_EQ(txt, r.output);
  const std::string csv = test::readFile(dir.file("fixes.csv"));
  EXPECT_EQ(csv.rfind("category,trial,run,method,compass_sigma_deg,step,status", 0), 0u);
  EXPECT_NE(csv.find("rect,0,0,fix2,,"), std::string::npos);
  EXPECT_NE(csv.find("rect,3,0,fix1,3.5,"), std::string::npos);

  // Same seed, same tables; another seed, other numbers.
  const test::CliRun again = test::runCli("fixstudy --category rect --method both --seed 3 --tables " + tables);
  EXPECT_EQ(again.output, r.output);
  const test::CliRun other = test::runCli("fixstudy --category rect --method fix2 --seed 4 --tables " + tables);
  ASSERT_EQ(other.exit_code, 0) << other.output;
  EXPECT_EQ(other.output.find("Table 6.9"), std::string::npos);
  EXPECT_NE(other.output.find("Table 6.4"), std::string::npos);

  // The thesis's first-order covariance on the same fixes: same error tables, other NEES, and the
  // same split (the rule is judged with sigma points whatever the covariance).
  const test::CliRun first =
      test::runCli("fixstudy --category rect --method fix2 --seed 3 --covariance first_order --tables " + tables);
  ASSERT_EQ(first.exit_code, 0) << first.output;
  EXPECT_NE(first.output.find("covariance: first_order"), std::string::npos);
  const auto table = [](const std::string& out) { return out.substr(out.find("dx (mm)"), out.find("NEES") - out.find("dx (mm)")); };
  EXPECT_EQ(table(first.output), table(r.output));
  const auto count = [](const std::string& out) {
    const size_t p = out.find("linearisation holds      n=");
    return out.substr(p, 35);
  };
  EXPECT_EQ(count(first.output), count(r.output));
  EXPECT_EQ(test::runCli("fixstudy --first-order --category rect --method fix2 --seed 3 --tables " + tables).output,
            first.output);
}

// The least-squares fix's study: both observation models on the same steps, with NEES.
TEST(CliFixstudy, MultiReportsBothObservationModels) {
  const std::string tables = std::string(STEREOLOC_DATA_DIR) + "/thesis_tables.yaml";
  const test::CliRun r = test::runCli("fixstudy --category rect --method multi --seed 3 --tables " + tables);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("Multi-landmark least squares (4.2.8), category rect"), std::string::npos) << r.output;
  const size_t rb = r.output.find("range-bearing: fixes: "), px = r.output.find("pixels: fixes: ");
  ASSERT_NE(rb, std::string::npos) << r.output;
  ASSERT_NE(px, std::string::npos) << r.output;
  // The same attempted steps for both models.
  EXPECT_EQ(r.output.substr(rb + 15, 20), r.output.substr(px + 8, 20));
  EXPECT_NE(r.output.find("NEES: mean 3-dof", px), std::string::npos);
  EXPECT_EQ(r.output.find("Table 6.4"), std::string::npos);
  EXPECT_EQ(r.output.find("Table 6.9"), std::string::npos);
  EXPECT_EQ(test::runCli("fixstudy --category rect --method multi --seed 3 --tables " + tables).output, r.output);
}

// Both worlds side by side on images: fixes and Table 6.3 per world, the ideal column equal to the
// ideal world run alone, and the ideal world alone printing no range table.
TEST(CliFixstudy, RealisticProfileAddsRangeTableBesideIdeal) {
  test::TempDir dir("fixstudy_profile");
  const std::string tables = std::string(STEREOLOC_DATA_DIR) + "/thesis_tables.yaml";
  const std::string common = "fixstudy --category rect --method fix2 --frontend images --steps 2 --seed 3 --tables " + tables;
  const test::CliRun both = test::runCli(common + " --profile ideal,realistic --out " + dir.path());
  ASSERT_EQ(both.exit_code, 0) << both.output;
  const std::string& out = both.output;
  EXPECT_NE(out.find("worlds: ideal, realistic"), std::string::npos) << out;
  EXPECT_NE(out.find("ours (images, ideal)"), std::string::npos) << out;
  EXPECT_NE(out.find("ours (images, realistic)"), std::string::npos) << out;
  EXPECT_NE(out.find("ours (images, realistic, self-cal.)"), std::string::npos) << out;
  EXPECT_EQ(out.find("ours (images, ideal, self-cal.)"), std::string::npos) << out;
  const size_t t63 = out.find("Table 6.3: goal-corner range error");
  ASSERT_NE(t63, std::string::npos) << out;
  EXPECT_NE(out.find("ours (images, ideal): ", t63), std::string::npos) << out;
  EXPECT_NE(out.find("ours (images, realistic): ", t63), std::string::npos) << out;
  EXPECT_NE(out.find("recall ", t63), std::string::npos) << out;
  // Thesis Table 6.3 beside ours: 5.18 % / 4.04 % normalised, 43.91 mm absolute.
  const size_t norm = out.find("normalised (%)", t63);
  ASSERT_NE(norm, std::string::npos) << out;
  const std::string norm_row = out.substr(norm, out.find('\n', norm) - norm);
  EXPECT_NE(norm_row.find("5.18     4.04"), std::string::npos) << norm_row;
  EXPECT_NE(out.find("43.91", t63), std::string::npos) << out;
  EXPECT_NE(out.find("signed norm (%)", t63), std::string::npos) << out;
  EXPECT_NE(out.find("trial bias (%)", t63), std::string::npos) << out;
  EXPECT_NE(out.find("|e - bias| (%)", t63), std::string::npos) << out;
  // Ranges measured in both worlds (8 pairs each): the row has two groups of four numbers.
  double ideal_mean = -1, real_mean = -1;
  ASSERT_EQ(std::sscanf(norm_row.c_str(), "normalised (%%) %lf %*f %*f %*f | %lf", &ideal_mean, &real_mean), 2) << norm_row;
  EXPECT_GT(ideal_mean, 0.0);
  EXPECT_GT(real_mean, 0.0);
  EXPECT_NE(ideal_mean, real_mean);
  const std::string csv = test::readFile(dir.file("fixes.csv"));
  EXPECT_NE(csv.find(",frontend,profile\n"), std::string::npos);
  EXPECT_NE(csv.find(",images,realistic\n"), std::string::npos);
  EXPECT_NE(csv.find(",images_self_calibrated,realistic\n"), std::string::npos);

  // The ideal world alone: the same ideal column, no world column names, no range table, and the
  // same output as without --profile.
  const test::CliRun ideal = test::runCli(common + " --profile ideal");
  ASSERT_EQ(ideal.exit_code, 0) << ideal.output;
  // (the timing line on stderr varies between runs)
  const auto tablesOf = [](const std::string& s) { return s.substr(std::min(s.size(), s.find("stereoloc fixstudy:"))); };
  EXPECT_EQ(tablesOf(ideal.output), tablesOf(test::runCli(common).output));
  EXPECT_EQ(ideal.output.find("Table 6.3"), std::string::npos) << ideal.output;
  EXPECT_EQ(ideal.output.find("worlds:"), std::string::npos) << ideal.output;
  const auto firstCells = [](const std::string& s, const char* row) {
    const size_t p = s.find(row);
    return p == std::string::npos ? std::string() : s.substr(p, 51);  // the label and the first group's 4 cells
  };
  EXPECT_EQ(firstCells(ideal.output, "dx (mm)"), firstCells(out, "dx (mm)")) << ideal.output << out;
  EXPECT_EQ(firstCells(ideal.output, "dy (mm)"), firstCells(out, "dy (mm)"));
  EXPECT_FALSE(firstCells(out, "dx (mm)").empty());
}

TEST(CliFixstudy, RejectsBadArguments) {
  EXPECT_EQ(test::runCli("fixstudy --category circles").exit_code, 2);
  EXPECT_EQ(test::runCli("fixstudy --method fix3").exit_code, 2);
  EXPECT_EQ(test::runCli("fixstudy --pixel-sigma -1").exit_code, 2);
  EXPECT_EQ(test::runCli("fixstudy --runs 0").exit_code, 2);
  EXPECT_EQ(test::runCli("fixstudy --covariance third_order").exit_code, 2);
  EXPECT_EQ(test::runCli("fixstudy --profile nowhere.yaml").exit_code, 2);
  EXPECT_EQ(test::runCli("fixstudy --profile realistic,realistic").exit_code, 2);
  EXPECT_EQ(test::runCli("fixstudy --profile ,").exit_code, 2);
  EXPECT_EQ(test::runCli("fixstudy --steps -1").exit_code, 2);
  EXPECT_EQ(test::runCli("fixstudy --calibrate wheels").exit_code, 2);
}

}  // namespace
}  // namespace stereoloc
