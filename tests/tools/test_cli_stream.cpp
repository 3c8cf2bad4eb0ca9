// `stereoloc stream`: JSON Lines in, one estimate line per step out; malformed lines are
// reported with their line number and the stream goes on; --from replays a dataset.
#include <gtest/gtest.h>

#include <cstdio>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "cli_util.h"
#include "solvers/smoother_common.h"
#include "src/io/dataset.h"
#include "test_util.h"

namespace stereoloc {
namespace {

std::string stepJson(const Step& s) {
  std::ostringstream o;
  o.precision(17);
  o << "{\"step\":" << s.step << ",\"t\":" << s.t << ",\"d_left\":" << s.d_left << ",\"d_right\":" << s.d_right;
  if (s.compass) o << ",\"compass\":" << *s.compass << ",\"compass_sigma\":" << s.compass_sigma;
  o << ",\"observations\":[";
  for (size_t i = 0; i < s.observations.size(); ++i) {
    const Observation& ob = s.observations[i];
    o << (i ? "," : "") << "{\"landmark_id\":" << ob.landmark_id << ",\"range\":" << ob.range
      << ",\"bearing\":" << ob.bearing << ",\"sigma_range\":" << std::sqrt(ob.covariance(0, 0))
      << ",\"sigma_bearing\":" << std::sqrt(ob.covariance(1, 1)) << "}";
  }
  o << "]}";
  return o.str();
}

std::vector<std::string> lines(const std::string& text, const std::string& prefix) {
  std::vector<std::string> out;
  std::istringstream in(text);
  std::string l;
  while (std::getline(in, l))
    if (l.rfind(prefix, 0) == 0) out.push_back(l);
  return out;
}

double field(const std::string& line, const std::string& key) {
  const size_t p = line.find("\"" + key + "\":");
  if (p == std::string::npos) return std::nan("");
  return std::stod(line.substr(p + key.size() + 3));
}

// The map of the in-process problem, saved so that the CLI can load it.
SyntheticProblem problem(int steps) {
  SyntheticProblemOptions o;
  o.steps = steps;
  o.compass_sigma = 0.05;
  return makeRandomWalkProblem(o, 4);
}

TEST(CliStream, OneEstimatePerStepAndTracks) {
  const SyntheticProblem p = problem(60);
  test::TempDir dir("stream");
  p.map.save(dir.file("map.yaml"));
  {
    std::ofstream f(dir.file("in.jsonl"));
    for (const Step& s : p.steps) f << stepJson(s) << "\n";
  }
  const Pose2& t0 = p.truth[0];
  const test::CliRun r = test::runCli("stream --window 10 --map " + dir.file("map.yaml") + " --pose " +
                                          std::to_string(t0.x) + "," + std::to_string(t0.y) + "," +
                                          std::to_string(t0.theta),
                                      dir.file("in.jsonl"));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const std::vector<std::string> out = lines(r.output, "{\"step\":");
  ASSERT_EQ(out.size(), p.steps.size()) << r.output;
  for (size_t i = 0; i < out.size(); ++i) {
    EXPECT_EQ(field(out[i], "step"), static_cast<double>(i));
    EXPECT_NE(out[i].find("\"covariance\":["), std::string::npos);
  }
  const std::string& last = out.back();
  EXPECT_NE(last.find("\"status\":\"tracking\""), std::string::npos) << last;
  EXPECT_LT(std::hypot(field(last, "x") - p.truth.back().x, field(last, "y") - p.truth.back().y), 30.0) << last;
}

TEST(CliStream, MalformedLinesAreReportedAndTheStreamGoesOn) {
  const SyntheticProblem p = problem(6);
  test::TempDir dir("stream");
  p.map.save(dir.file("map.yaml"));
  {
    std::ofstream f(dir.file("in.jsonl"));
    f << stepJson(p.steps[0]) << "\n";
    f << "{\"step\":1,\"d_left\":1,\n";                                  // line 2: truncated
    f << "{\"step\":2,\"d_left\":\"a\",\"d_right\":1}\n";               // line 3: not a number
    f << "\n";                                                          // blank: skipped
    f << "{\"step\":3,\"d_left\":1,\"d_right\":1,\"observations\":[{\"landmark_id\":0,\"range\":-5,"
         "\"bearing\":0,\"sigma_range\":1,\"sigma_bearing\":0.1}]}\n";  // line 5: negative range
    f << stepJson(p.steps[4]) << "\n";
    f << stepJson(p.steps[2]) << "\n";                                  // line 7: step goes back
    f << stepJson(p.steps[5]) << "\n";
  }
  const test::CliRun r =
      test::runCli("stream --map " + dir.file("map.yaml") + " --pose 750,650,0.3", dir.file("in.jsonl"));
  EXPECT_EQ(r.exit_code, 1) << r.output;
  for (const char* where : {"stdin:2:", "stdin:3: step: \"d_left\"", "stdin:5: observations[0]", "stdin:7:"})
    EXPECT_NE(r.output.find(where), std::string::npos) << where << "\n" << r.output;
  const std::vector<std::string> out = lines(r.output, "{\"step\":");
  ASSERT_EQ(out.size(), 3u) << r.output;
  EXPECT_EQ(field(out[1], "step"), 4.0);
  EXPECT_EQ(field(out[2], "step"), 5.0);
}

TEST(CliStream, ReplaysADatasetAndPrintsTheSmoothedTrajectory) {
  const SyntheticProblem p = problem(40);
  test::TempDir dir("stream");
  Dataset d;
  d.name = "random_walk";
  d.map = p.map;
  d.odometry = p.odometry;
  d.compass_sigma = 0.05;
  d.steps = p.steps;
  for (const Pose2& t : p.truth) d.groundtruth.push_back(t);
  d.initial_pose = p.truth[0];
  saveDataset(d, dir.file("ds"), false);
  const test::CliRun r = test::runCli("stream --from " + dir.file("ds") + " --smoothed --window 5");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const std::vector<std::string> out = lines(r.output, "{\"step\":");
  ASSERT_EQ(out.size(), 2 * p.steps.size()) << r.output;
  EXPECT_NE(out[p.steps.size()].find("\"smoothed\":true"), std::string::npos);
  EXPECT_NE(out.back().find("\"smoothed\":true"), std::string::npos);
  EXPECT_EQ(out[0].find("\"smoothed\""), std::string::npos);
  const test::CliRun bad = test::runCli("stream --from " + dir.file("nothing"));
  EXPECT_EQ(bad.exit_code, 1) << bad.output;
  const test::CliRun usage = test::runCli("stream --window 0");
  EXPECT_EQ(usage.exit_code, 2) << usage.output;
}

}  // namespace
}  // namespace stereoloc
