// `stereoloc stream`: JSON Lines in, one estimate line per step out; malformed lines are
// reported with their line number and the stream goes on; --from replays a dataset; images in
// the stream give the estimates of `localize --frontend images`; late images are inserted.
#include <gtest/gtest.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <opencv2/core.hpp>
#include <sstream>
#include <string>
#include <vector>

#include "cli_util.h"
#include "solvers/smoother_common.h"
#include "src/core/yaml_util.h"
#include "src/io/dataset.h"
#include "src/io/image_file.h"
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

TEST(CliStream, SelfCalibratesAndWritesTheCalibration) {
  // A realistic line (wrong wheel radii, baseline, tilt, ...) replayed with the window's and the
  // particle filter's self-calibration: the rig YAML with the estimate and its standard
  // deviations is written.
  test::TempDir dir("stream_calib");
  const test::CliRun sim =
      test::runCli("simulate --scenario line --steps 40 --seed 7 --profile realistic --out " + dir.file("ds"));
  ASSERT_EQ(sim.exit_code, 0) << sim.output;
  const test::CliRun r = test::runCli("stream --from " + dir.file("ds") +
                                      " --calibrate odometry,stereo --calibration-out " + dir.file("calib.yaml"));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_EQ(lines(r.output, "{\"step\":").size(), 40u) << r.output;
  const StereoRig rig = StereoRig::load(dir.file("calib.yaml"));  // usable as --rig
  EXPECT_GT(rig.params().baseline_mm, 0.0);
  std::ifstream in(dir.file("calib.yaml"));
  const std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  for (const char* key : {"wheel_base_mm", "wheel_base_sigma_mm", "baseline_scale", "baseline_scale_sigma"})
    EXPECT_NE(text.find(key), std::string::npos) << key;
  const test::CliRun pf = test::runCli("stream --from " + dir.file("ds") + " --method pf --particles 500" +
                                       " --calibrate odometry,stereo --calibration-out " + dir.file("pf.yaml"));
  ASSERT_EQ(pf.exit_code, 0) << pf.output;
  EXPECT_EQ(lines(pf.output, "{\"step\":").size(), 40u) << pf.output;
  EXPECT_NE(pf.output.find("calibration: wheel scales"), std::string::npos) << pf.output;
  EXPECT_GT(StereoRig::load(dir.file("pf.yaml")).params().baseline_mm, 0.0);
  const test::CliRun usage = test::runCli("stream --from " + dir.file("ds") + " --calibration-out " + dir.file("x.yaml"));
  EXPECT_EQ(usage.exit_code, 2) << usage.output;
  const test::CliRun rb = test::runCli("stream --from " + dir.file("ds") +
                                       " --calibrate stereo --observation-model range_bearing");
  EXPECT_EQ(rb.exit_code, 2) << rb.output;
}

// A simulated run with images (`line`: it sees a goal's corners from the first step) and the
// JSON Lines a robot would send for it: odometry, compass and the image files of each step, the
// images of step k on the line of step k + delay.
class StreamImages : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = new test::TempDir("stream_images");
    const test::CliRun r = test::runCli("simulate --scenario line --steps 25 --seed 5 --images --out " + ds());
    ASSERT_EQ(r.exit_code, 0) << r.output;
  }
  static void TearDownTestSuite() {
    delete dir_;
    dir_ = nullptr;
  }
  static std::string ds() { return dir_->file("d"); }
  static std::string image(const std::string& kind, long step) { return ds() + "/" + imageFileName(kind, step); }
  static std::string line(const Step& s, long obs_step, const std::string& left, const std::string& right) {
    std::ostringstream o;
    o.precision(17);
    o << "{\"step\":" << s.step << ",\"t\":" << s.t << ",\"d_left\":" << s.d_left << ",\"d_right\":" << s.d_right;
    if (s.compass) o << ",\"compass\":" << *s.compass << ",\"compass_sigma\":" << s.compass_sigma;
    o << ",\"head_pan\":" << s.head_pan;
    if (!left.empty()) {
      if (obs_step != s.step) o << ",\"obs_step\":" << obs_step;
      o << ",\"left\":\"" << left << "\",\"right\":\"" << right << "\"";
    }
    return o.str() + "}";
  }
  static std::string writeLines(const std::string& name, int delay) {
    const Dataset d = loadDataset(ds());
    std::ofstream f(dir_->file(name));
    for (size_t k = 0; k < d.steps.size(); ++k) {
      const long obs = static_cast<long>(k) - delay;
      f << line(d.steps[k], obs, obs >= 0 ? image("left", obs) : "", obs >= 0 ? image("right", obs) : "") << "\n";
    }
    return dir_->file(name);
  }
  static test::TempDir* dir_;
};
test::TempDir* StreamImages::dir_ = nullptr;

// step -> (x, y, theta, 9 covariance values) of a stream's estimate lines, the smoothed ones
// (printed after the input ends) or the real-time ones.
std::map<long, std::vector<double>> estimateLines(const std::string& output, bool smoothed) {
  std::map<long, std::vector<double>> out;
  for (const std::string& l : lines(output, "{\"step\":")) {
    if ((l.find("\"smoothed\":true") != std::string::npos) != smoothed || l.find("\"x\"") == std::string::npos)
      continue;
    std::vector<double> v = {field(l, "x"), field(l, "y"), field(l, "theta")};
    std::istringstream cov(l.substr(l.find("\"covariance\":[") + 14));
    for (int i = 0; i < 9; ++i) {
      double c = 0;
      char sep = 0;
      cov >> c >> sep;
      v.push_back(c);
    }
    out[static_cast<long>(field(l, "step"))] = v;
  }
  return out;
}

// The same of an estimate CSV written by `localize`.
std::map<long, std::vector<double>> estimateCsv(const std::string& csv) {
  std::map<long, std::vector<double>> out;
  for (const auto& [step, v] : test::readRows(csv)) {
    EXPECT_EQ(v.size(), 11u) << step;  // step,t,x,y,theta, xx,xy,xtheta,yy,ytheta,thetatheta
    if (v.size() == 11u) out[step] = {v[2], v[3], v[4], v[5], v[6], v[7], v[6], v[8], v[9], v[7], v[9], v[10]};
  }
  return out;
}

// The largest difference of two estimate maps with the same steps, relative to max(1, |value|).
double worstRelativeDifference(const std::map<long, std::vector<double>>& got,
                               const std::map<long, std::vector<double>>& expected) {
  EXPECT_EQ(got.size(), expected.size());
  double worst = 0;
  for (const auto& [step, v] : expected) {
    if (got.count(step) == 0) {
      ADD_FAILURE() << "no estimate of step " << step;
      return std::numeric_limits<double>::infinity();
    }
    for (size_t i = 0; i < v.size(); ++i)
      worst = std::max(worst, std::fabs(got.at(step)[i] - v[i]) / std::max(1.0, std::fabs(v[i])));
  }
  return worst;
}

TEST_F(StreamImages, ImagesInTheStreamGiveTheEstimatesOfLocalize) {
  const std::string csv = dir_->file("localize.csv");
  const test::CliRun loc =
      test::runCli("localize " + ds() + " --method window --init global --frontend images --out " + csv);
  ASSERT_EQ(loc.exit_code, 0) << loc.output;
  const std::map<long, std::vector<double>> expected = estimateCsv(csv);
  ASSERT_GT(expected.size(), 20u);
  const test::CliRun on_stdin =
      test::runCli("stream --setup " + ds() + " --init global --smoothed", writeLines("in_order.jsonl", 0));
  const test::CliRun replay = test::runCli("stream --from " + ds() + " --frontend images --init global --smoothed");
  for (const test::CliRun* r : {&on_stdin, &replay}) {
    ASSERT_EQ(r->exit_code, 0) << r->output;
    EXPECT_LT(worstRelativeDifference(estimateLines(r->output, true), expected), 1e-9) << r->output;
  }
  // Every real-time line carries its compute time.
  for (const std::string& l : lines(on_stdin.output, "{\"step\":"))
    if (l.find("smoothed") == std::string::npos) {
      EXPECT_GT(field(l, "compute_ms"), 0.0) << l;
    }
}

TEST_F(StreamImages, LateImagesAreInsertedAtTheirStep) {
  // The images of step k come with the odometry of step k + 3. The run differs from the in-order
  // one where the gate and the association judge against a different belief (the window's
  // marginal instead of the prediction): here one re-initialisation happens 3 steps later.
  const test::CliRun in_order =
      test::runCli("stream --setup " + ds() + " --init global --window 40 --smoothed", writeLines("in_order.jsonl", 0));
  const test::CliRun late =
      test::runCli("stream --setup " + ds() + " --init global --window 40 --smoothed", writeLines("late.jsonl", 3));
  ASSERT_EQ(in_order.exit_code, 0) << in_order.output;
  ASSERT_EQ(late.exit_code, 0) << late.output;
  int inserted = 0, not_tracking = 0;
  for (const std::string& l : lines(late.output, "{\"step\":")) {
    inserted += l.find("\"late\":\"inserted\"") != std::string::npos;
    not_tracking += l.find("\"late\":\"not_tracking\"") != std::string::npos;
  }
  // Steps 0 and 1 give no global fix (as in order); step 2's late images start the window.
  EXPECT_EQ(not_tracking, 2) << late.output;
  EXPECT_EQ(inserted, 20) << late.output;
  const Dataset d = loadDataset(ds());
  auto worstError = [&](const std::map<long, std::vector<double>>& est) {
    double worst = 0;
    for (const auto& [step, v] : est)
      worst = std::max(worst, std::hypot(v[0] - d.groundtruth.at(static_cast<size_t>(step))->x,
                                         v[1] - d.groundtruth.at(static_cast<size_t>(step))->y));
    return worst;
  };
  const auto a = estimateLines(in_order.output, true), b = estimateLines(late.output, true);
  ASSERT_EQ(b.size(), a.size());
  double diff = 0;
  for (const auto& [step, v] : a) diff = std::max(diff, std::hypot(v[0] - b.at(step)[0], v[1] - b.at(step)[1]));
  RecordProperty("max_position_difference_mm", std::to_string(diff));
  EXPECT_LT(diff, 3.0);
  EXPECT_LT(worstError(b), worstError(a) + 2.0);
  const std::vector<std::string> out = lines(late.output, "{\"step\":");
  EXPECT_NE(out[24].find("\"status\":\"tracking\""), std::string::npos) << out[24];
  // The filters go back for them (replay their last steps): every late pair is inserted.
  for (const char* method : {"ekf", "pf"}) {
    const test::CliRun filter =
        test::runCli("stream --setup " + ds() + " --method " + method + " --init global", writeLines("late.jsonl", 3));
    ASSERT_EQ(filter.exit_code, 0) << filter.output;
    size_t replayed = 0;
    for (const std::string& l : lines(filter.output, "{\"step\":"))
      replayed += l.find("\"late\":\"inserted\"") != std::string::npos;
    EXPECT_EQ(replayed, loadDataset(ds()).steps.size() - 3) << method << filter.output;
    EXPECT_EQ(filter.output.find("too_late"), std::string::npos) << method << filter.output;
    EXPECT_NE(lines(filter.output, "{\"step\":").back().find("\"status\":\"tracking\""), std::string::npos)
        << method << filter.output;
  }
  // A replay horizon shorter than the delay: every late pair is too late, each said on stderr
  // (exit code 1 at the end).
  const test::CliRun short_replay = test::runCli(
      "stream --setup " + ds() + " --method ekf --init global --replay-steps 2", writeLines("late.jsonl", 3));
  EXPECT_EQ(short_replay.exit_code, 1) << short_replay.output;
  EXPECT_NE(short_replay.output.find("stdin:4: observations of step 0 are too late: the step is older than the "
                                     "filter's last 2 steps"),
            std::string::npos)
      << short_replay.output;
  size_t too_late = 0;
  for (const std::string& l : lines(short_replay.output, "{\"step\":"))
    too_late += l.find("\"late\":\"too_late\"") != std::string::npos;
  EXPECT_EQ(too_late, loadDataset(ds()).steps.size() - 3) << short_replay.output;
}

TEST_F(StreamImages, BadInputNeverStopsTheStream) {
  const Dataset d = loadDataset(ds());
  const std::string truncated = dir_->file("truncated.png"), small = dir_->file("small.png");
  {
    std::ifstream in(image("left", 2), std::ios::binary);
    const std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    std::ofstream(truncated, std::ios::binary) << bytes.substr(0, bytes.size() / 2);
  }
  writePngFile(small, cv::Mat(120, 160, CV_8UC3, cv::Scalar(0, 128, 0)));
  {
    std::ofstream f(dir_->file("bad.jsonl"));
    f << line(d.steps[0], 0, image("left", 0), image("right", 0)) << "\n";
    f << line(d.steps[1], 1, dir_->file("missing.png"), image("right", 1)) << "\n";  // 2: missing image
    f << line(d.steps[2], 2, truncated, image("right", 2)) << "\n";                   // 3: truncated PNG
    f << line(d.steps[3], 3, image("left", 3), small) << "\n";                        // 4: wrong size
    f << "this is not JSON\n";                                                       // 5
    f << line(d.steps[1], 1, image("left", 1), image("right", 1)) << "\n";           // 6: step goes back
    f << line(d.steps[4], 4, image("left", 4), image("right", 4)) << "\n";
    f << line(d.steps[5], 0, image("left", 0), image("right", 0)) << "\n";           // 8: older than the window
    f << line(d.steps[6], 6, image("left", 6), image("right", 6)) << "\n";
  }
  const test::CliRun r = test::runCli("stream --setup " + ds() + " --init global --window 2", dir_->file("bad.jsonl"));
  EXPECT_EQ(r.exit_code, 1) << r.output;
  for (const std::string& where : {"stdin:2: " + dir_->file("missing.png"),
                                  "stdin:3: " + truncated + ": cannot read the image (PNG cut short",
                                  "stdin:4: " + small, std::string("stdin:5: "), std::string("stdin:6: step 1 does not follow"),
                                  std::string("stdin:8: observations of step 0 are too late")})
    EXPECT_NE(r.output.find(where), std::string::npos) << where << "\n" << r.output;
  // One estimate for every line with usable odometry (the steps of lines 2-4 too), in order.
  const std::vector<std::string> out = lines(r.output, "{\"step\":");
  ASSERT_EQ(out.size(), 7u) << r.output;
  for (size_t i = 0; i < out.size(); ++i) EXPECT_EQ(field(out[i], "step"), static_cast<double>(i)) << out[i];
  EXPECT_NE(out[5].find("\"late\":\"too_late\""), std::string::npos) << out[5];
  EXPECT_NE(out[6].find("\"status\":\"tracking\""), std::string::npos) << out[6];
  EXPECT_EQ(r.output.find("null"), std::string::npos) << r.output;
  EXPECT_EQ(r.output.find("libpng"), std::string::npos) << r.output;  // the codec never sees the cut file
}

// The filters as the stream's tracker, on a realistic line's images: the self-calibrating and
// the iterated EKF give exactly `localize`'s estimates (and calibration), the particle filter
// the same estimates for the same seed; each tracker's options are refused with another.
// An odometry that runs late: the stream re-times it as it comes in, as localize re-times the
// dataset; a stream cannot fit the delay, nor undo a negative one.
TEST(CliStream, TheOdometryDelayGivesTheEstimatesOfLocalize) {
  test::TempDir dir("stream_delay");
  const std::string ds = dir.file("ds");
  const test::CliRun sim = test::runCli("simulate --scenario line --steps 60 --seed 3 --out " + ds);
  ASSERT_EQ(sim.exit_code, 0) << sim.output;
  const std::string options = " --method ekf --init global --odometry-delay 0.15";
  const std::string csv = dir.file("ekf.csv"), plain = dir.file("plain.csv");
  const test::CliRun loc = test::runCli("localize " + ds + options + " --out " + csv);
  ASSERT_EQ(loc.exit_code, 0) << loc.output;
  ASSERT_EQ(test::runCli("localize " + ds + " --method ekf --init global --out " + plain).exit_code, 0);
  const std::map<long, std::vector<double>> expected = estimateCsv(csv);
  ASSERT_GT(expected.size(), 40u);
  EXPECT_GT(worstRelativeDifference(estimateCsv(plain), expected), 0.0);  // the delay changes the estimates
  const test::CliRun r = test::runCli("stream --from " + ds + options);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_EQ(worstRelativeDifference(estimateLines(r.output, false), expected), 0.0);
  for (const char* bad : {"fit", "-0.1", "2.5"}) {
    const test::CliRun u = test::runCli("stream --from " + ds + " --method ekf --odometry-delay " + bad);
    EXPECT_EQ(u.exit_code, 2) << bad << ": " << u.output;
    EXPECT_NE(u.output.find("--odometry-delay"), std::string::npos) << bad << ": " << u.output;
  }

  // Handed over: the calibration file of a run with the delay carries it to the next runs,
  // localize and stream alike, and a further calibration carries it on.
  const std::string rig = dir.file("cal.yaml"), next = dir.file("next.yaml");
  const test::CliRun cal = test::runCli("localize " + ds + options + " --calibrate odometry --calibration-out " + rig +
                                        " --out " + dir.file("cal.csv"));
  ASSERT_EQ(cal.exit_code, 0) << cal.output;
  EXPECT_DOUBLE_EQ(YamlReader(rig).getDouble("odometry_delay_s"), 0.15);
  EXPECT_FALSE(YamlReader(rig).has("odometry_delay_sigma_s"));  // given, not estimated
  const test::CliRun check = test::runCli("selfcheck --samples 10 --rig " + rig);
  ASSERT_EQ(check.exit_code, 0) << check.output;
  EXPECT_NE(check.output.find("hands over: odometry delay 0.150 s"), std::string::npos) << check.output;
  const std::string on_rig = " --method ekf --init global --rig " + rig;
  const test::CliRun handed = test::runCli("localize " + ds + on_rig + " --out " + dir.file("handed.csv"));
  ASSERT_EQ(handed.exit_code, 0) << handed.output;
  EXPECT_NE(handed.output.find("odometry delay (handed over by the rig file): 0.150 s"), std::string::npos)
      << handed.output;
  const test::CliRun undelayed =
      test::runCli("localize " + ds + on_rig + " --odometry-delay 0 --out " + dir.file("undelayed.csv"));
  ASSERT_EQ(undelayed.exit_code, 0) << undelayed.output;
  EXPECT_GT(worstRelativeDifference(estimateCsv(dir.file("undelayed.csv")), estimateCsv(dir.file("handed.csv"))), 0.0);
  const test::CliRun refined = test::runCli("refine " + ds + " --init global --rig " + rig + " --out " + dir.file("r.csv"));
  ASSERT_EQ(refined.exit_code, 0) << refined.output;
  EXPECT_NE(refined.output.find("odometry delay (handed over by the rig file): 0.150 s"), std::string::npos)
      << refined.output;
  const test::CliRun streamed = test::runCli("stream --from " + ds + on_rig);
  ASSERT_EQ(streamed.exit_code, 0) << streamed.output;
  EXPECT_EQ(worstRelativeDifference(estimateLines(streamed.output, false), estimateCsv(dir.file("handed.csv"))), 0.0);
  const test::CliRun further = test::runCli("localize " + ds + on_rig + " --calibrate odometry --calibration-out " +
                                            next + " --out " + dir.file("next.csv"));
  ASSERT_EQ(further.exit_code, 0) << further.output;
  EXPECT_DOUBLE_EQ(YamlReader(next).getDouble("odometry_delay_s"), 0.15);
}

TEST(CliStream, TheFiltersGiveTheEstimatesOfLocalize) {
  test::TempDir dir("stream_filters");
  const std::string ds = dir.file("ds");
  const test::CliRun sim =
      test::runCli("simulate --scenario line --steps 40 --seed 7 --profile realistic --images --out " + ds);
  ASSERT_EQ(sim.exit_code, 0) << sim.output;
  const std::string noise = std::string(STEREOLOC_DATA_DIR) + "/noise_realistic.yaml";
  // The self-calibrating EKF with wheels that drift (the walk adds about half the prior's variance
  // over this drive).
  const std::string drifting = dir.file("noise_drifting.yaml");
  {
    std::ifstream in(noise);
    std::ofstream out(drifting);
    out << in.rdbuf() << "wheel_scale_drift: 0.01\nwheel_base_drift: 0.02\n";
  }
  const std::string calibrating = " --calibrate odometry,stereo --noise-model " + drifting;
  for (const std::string method : {"ekf", "iekf"}) {
    const bool ekf = method == "ekf";  // the self-calibrating EKF, which also writes its calibration
    const std::string options =
        " --method " + method + " --init global --frontend images" + (ekf ? calibrating : std::string());
    auto calibrationOut = [&](const std::string& name) { return ekf ? " --calibration-out " + dir.file(name) : ""; };
    const std::string csv = dir.file(method + ".csv");
    const test::CliRun loc =
        test::runCli("localize " + ds + options + " --out " + csv + calibrationOut("localize_rig.yaml"));
    ASSERT_EQ(loc.exit_code, 0) << loc.output;
    const std::map<long, std::vector<double>> expected = estimateCsv(csv);
    ASSERT_GT(expected.size(), 30u) << method;
    const test::CliRun r = test::runCli("stream --from " + ds + options + calibrationOut("stream_rig.yaml"));
    ASSERT_EQ(r.exit_code, 0) << r.output;
    EXPECT_EQ(r.output.find("calibration: wheel scales") != std::string::npos, ekf) << r.output;  // on stderr
    EXPECT_EQ(worstRelativeDifference(estimateLines(r.output, false), expected), 0.0) << method;
  }
  // The calibration files (the rig YAML names its own OpenCV file, so that line differs).
  auto text = [](const std::string& path) {
    std::ifstream in(path);
    std::string all, l;
    while (std::getline(in, l))
      if (l.rfind("calibration_file:", 0) != 0) all += l + "\n";
    return all;
  };
  EXPECT_EQ(text(dir.file("stream_rig.yaml")), text(dir.file("localize_rig.yaml")));
  EXPECT_EQ(text(dir.file("stream_rig_calibration.yml")), text(dir.file("localize_rig_calibration.yml")));
  EXPECT_NE(text(dir.file("stream_rig.yaml")).find("wheel_base_sigma_mm"), std::string::npos);

  // The EKF considering its calibration: localize's estimates, and no calibration to report.
  const std::string considering =
      " --method ekf --init global --frontend images --consider odometry,stereo --noise-model " + noise;
  const test::CliRun cl = test::runCli("localize " + ds + considering + " --out " + dir.file("consider.csv"));
  ASSERT_EQ(cl.exit_code, 0) << cl.output;
  const test::CliRun cs = test::runCli("stream --from " + ds + considering);
  ASSERT_EQ(cs.exit_code, 0) << cs.output;
  EXPECT_EQ(cs.output.find("calibration:"), std::string::npos) << cs.output;
  EXPECT_EQ(worstRelativeDifference(estimateLines(cs.output, false), estimateCsv(dir.file("consider.csv"))), 0.0);

  const std::string pf = "stream --from " + ds + " --frontend images --method pf --particles 400 --init global";
  const test::CliRun a = test::runCli(pf + " --seed 3"), b = test::runCli(pf + " --seed 3"),
                     c = test::runCli(pf + " --seed 4");
  for (const test::CliRun* r : {&a, &b, &c}) ASSERT_EQ(r->exit_code, 0) << r->output;
  const auto pa = estimateLines(a.output, false);
  EXPECT_GT(pa.size(), 30u);
  EXPECT_EQ(worstRelativeDifference(estimateLines(b.output, false), pa), 0.0);
  EXPECT_GT(worstRelativeDifference(estimateLines(c.output, false), pa), 0.0);
  EXPECT_NE(lines(a.output, "{\"step\":").back().find("\"status\":\"tracking\""), std::string::npos) << a.output;

  const std::vector<std::pair<std::string, std::string>> refused = {
      {"--method pf --calibrate odometry,range", "--calibrate"},
      {"--method iekf --calibrate odometry", "--calibrate"},
      {"--method ekf --window 5", "--window"},
      {"--method ekf --max-iterations 3", "--max-iterations"},
      {"--method pf --smoothed", "--smoothed"},
      {"--method ekf --noise-model " + noise, "--noise-model"},
      {"--method ekf --observation-model pixels", "--observation-model"},
      {"--method window --particles 10", "--particles"},
      {"--method ekf --seed 2", "--seed"},
      {"--method pf --no-gate", "--no-gate"},
      {"--method window --replay-steps 5", "--replay-steps"},
      {"--method pf --consider odometry", "--consider"},
      {"--method window --consider odometry", "--consider"},
      {"--method ekf --consider odometry --calibrate odometry", "--consider"},
      {"--method ekf --consider odometry --calibration-out " + dir.file("x.yaml"), "--calibration-out"},
      {"--method kalman", "--method"}};
  for (const auto& [options, named] : refused) {
    const test::CliRun r = test::runCli("stream --from " + ds + " " + options);
    EXPECT_EQ(r.exit_code, 2) << options << "\n" << r.output;
    EXPECT_NE(r.output.find(named), std::string::npos) << options << "\n" << r.output;
    EXPECT_EQ(r.output.find("{\"step\":"), std::string::npos) << options;
  }
}

}  // namespace
}  // namespace stereoloc

namespace stereoloc {
namespace {

// A rig that states the cameras' exposure offset: the stream moves each right column to the left
// camera's instant with the turn rate of the odometry it has received, as localize does with the
// dataset's, so both give the same estimates; the offset changes them.
TEST(CliStream, TheExposureOffsetGivesTheEstimatesOfLocalize) {
  test::TempDir dir("stream_exposure");
  const std::string ds = dir.file("ds");
  const test::CliRun sim = test::runCli("simulate --scenario circle --steps 60 --seed 3 --out " + ds);
  ASSERT_EQ(sim.exit_code, 0) << sim.output;
  const std::string rig = dir.file("timed.yaml");
  std::filesystem::copy_file(ds + "/rig.yaml", rig);
  std::ofstream(rig, std::ios::app) << "exposure_offset_s: 0.004\n";
  const std::string options = " --method ekf --init global";
  const std::string csv = dir.file("ekf.csv"), plain = dir.file("plain.csv");
  const test::CliRun loc = test::runCli("localize " + ds + options + " --rig " + rig + " --out " + csv);
  ASSERT_EQ(loc.exit_code, 0) << loc.output;
  ASSERT_EQ(test::runCli("localize " + ds + options + " --out " + plain).exit_code, 0);
  const std::map<long, std::vector<double>> expected = estimateCsv(csv);
  ASSERT_GT(expected.size(), 30u);
  EXPECT_GT(worstRelativeDifference(estimateCsv(plain), expected), 1e-6);  // the offset changes the estimates
  const test::CliRun r = test::runCli("stream --from " + ds + options + " --rig " + rig);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_EQ(worstRelativeDifference(estimateLines(r.output, false), expected), 0.0);
  // An offset out of range is an error naming the file and the key.
  std::filesystem::copy_file(ds + "/rig.yaml", dir.file("bad.yaml"));
  std::ofstream(dir.file("bad.yaml"), std::ios::app) << "exposure_offset_s: 0.3\n";
  const test::CliRun bad = test::runCli("localize " + ds + options + " --rig " + dir.file("bad.yaml") + " --out " + csv);
  EXPECT_NE(bad.exit_code, 0);
  EXPECT_NE(bad.output.find("bad.yaml"), std::string::npos) << bad.output;
  EXPECT_NE(bad.output.find("exposure_offset_s"), std::string::npos) << bad.output;
}

}  // namespace
}  // namespace stereoloc
