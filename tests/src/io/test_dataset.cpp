#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <random>

#include <filesystem>
#include <fstream>
#include <sstream>

#include "src/io/csv.h"
#include "src/core/measurement_model.h"
#include "src/io/dataset.h"
#include "src/core/error.h"
#include "src/sim/simulator.h"
#include "test_util.h"

namespace stereoloc {
namespace {
namespace fs = std::filesystem;

class TempDir {
 public:
  TempDir() {
    path_ = (fs::temp_directory_path() / ("stereoloc_test_dataset_" + std::to_string(::getpid()) + "_" +
                                          std::to_string(counter_++)))
                .string();
    fs::remove_all(path_);
  }
  ~TempDir() { fs::remove_all(path_); }
  const std::string& path() const { return path_; }
  std::string operator/(const std::string& f) const { return (fs::path(path_) / f).string(); }

 private:
  static inline int counter_ = 0;
  std::string path_;
};

void writeFile(const std::string& path, const std::string& text) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out << text;
}

// Replaces line `line` (1-based) of a file.
void replaceLine(const std::string& path, int line, const std::string& text) {
  std::istringstream in(test::readFile(path));
  std::string out, l;
  for (int i = 1; std::getline(in, l); ++i) out += (i == line ? text : l) + "\n";
  writeFile(path, out);
}

// The first data row of the CSV at `path` with its field `column` (0-based) replaced by `value`.
void replaceFirstRowField(const std::string& path, size_t column, const std::string& value) {
  std::istringstream in(test::readFile(path));
  std::string header, row;
  std::getline(in, header);
  std::getline(in, row);
  size_t begin = 0;
  for (size_t c = 0; c < column; ++c) begin = row.find(',', begin) + 1;
  const size_t end = row.find(',', begin);
  replaceLine(path, 2, row.substr(0, begin) + value + (end == std::string::npos ? "" : row.substr(end)));
}

Dataset sample(uint64_t seed = 3) {
  SimulationConfig cfg;
  cfg.landmarks = LandmarkSet::All;
  cfg.scenario.head_scan = true;
  return simulate("circle", 0, cfg, seed);
}

void expectSame(const Dataset& a, const Dataset& b) {
  ASSERT_EQ(a.steps.size(), b.steps.size());
  EXPECT_EQ(a.name, b.name);
  EXPECT_EQ(a.description, b.description);
  EXPECT_EQ(a.compass_sigma, b.compass_sigma);
  EXPECT_EQ(a.odometry.readings, b.odometry.readings);
  EXPECT_EQ(a.odometry.k_left, b.odometry.k_left);
  EXPECT_EQ(a.odometry.wheel_base_mm, b.odometry.wheel_base_mm);
  EXPECT_EQ(a.odometry.control_variance_floor, b.odometry.control_variance_floor);
  EXPECT_EQ(a.rig.focal(), b.rig.focal());
  EXPECT_EQ(a.rig.params().pixel_sigma, b.rig.params().pixel_sigma);
  EXPECT_EQ(a.map.landmarks().size(), b.map.landmarks().size());
  EXPECT_EQ(a.has_images, b.has_images);
  ASSERT_EQ(a.initial_pose.has_value(), b.initial_pose.has_value());
  if (a.initial_pose) {
    EXPECT_EQ(a.initial_pose->vector(), b.initial_pose->vector());
  }
  for (size_t i = 0; i < a.steps.size(); ++i) {
    const Step &s = a.steps[i], &t = b.steps[i];
    EXPECT_EQ(s.step, t.step);
    EXPECT_EQ(s.t, t.t);
    EXPECT_EQ(s.d_left, t.d_left);
    EXPECT_EQ(s.d_right, t.d_right);
    EXPECT_EQ(s.head_pan, t.head_pan);
    EXPECT_EQ(s.compass, t.compass);
    EXPECT_EQ(s.compass_sigma, t.compass_sigma);
    ASSERT_EQ(s.observations.size(), t.observations.size()) << i;
    for (size_t k = 0; k < s.observations.size(); ++k) {
      const Observation &o = s.observations[k], &p = t.observations[k];
      EXPECT_EQ(o.landmark_id, p.landmark_id);
      EXPECT_EQ(o.type, p.type);
      EXPECT_EQ(o.range, p.range);
      EXPECT_EQ(o.bearing, p.bearing);
      EXPECT_EQ(o.covariance, p.covariance);
      EXPECT_EQ(o.pixel_covariance, p.pixel_covariance);
      EXPECT_EQ(o.head_pan, p.head_pan);
      EXPECT_EQ(o.slide_gain, p.slide_gain);
    }
    ASSERT_EQ(a.groundtruth[i].has_value(), b.groundtruth[i].has_value());
    if (a.groundtruth[i]) {
      EXPECT_EQ(a.groundtruth[i]->vector(), b.groundtruth[i]->vector());
    }
  }
}

void expectError(const std::string& dir, const std::string& fragment1, const std::string& fragment2) {
  try {
    loadDataset(dir);
    FAIL() << "expected an error containing '" << fragment1 << "' and '" << fragment2 << "'";
  } catch (const Error& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find(fragment1), std::string::npos) << msg;
    EXPECT_NE(msg.find(fragment2), std::string::npos) << msg;
    EXPECT_EQ(msg.find('\n'), std::string::npos) << "one line: " << msg;
  }
}

TEST(Dataset, PixelRoundTripIsExact) {
  TempDir dir;
  const Dataset d = sample();
  saveDataset(d, dir.path(), false);
  expectSame(d, loadDataset(dir.path()));
  EXPECT_TRUE(fs::exists(dir / "compass.csv"));
  EXPECT_TRUE(fs::exists(dir / "groundtruth.csv"));
  EXPECT_EQ(test::readFile(dir / "observations.csv").rfind("step,t,landmark_id,u_left", 0), 0u);
}

TEST(Dataset, PixelCovarianceRoundTripsAndBadOnesNameTheRow) {
  TempDir dir;
  Dataset d = sample();
  const Eigen::Matrix4d C = stereoPixelCovariance(0.3, 0.12, 0.07, 0.1);
  for (Step& s : d.steps)
    for (Observation& o : s.observations) o = observationFromPixels(d.rig, o.landmark_id, o.type, *o.pixels, o.head_pan, C);
  saveDataset(d, dir.path(), false);
  EXPECT_NE(test::readFile(dir / "observations.csv").find("cov_ul_ul"), std::string::npos);
  expectSame(d, loadDataset(dir.path()));
  // A covariance that is not positive definite: one line naming the file, row and column.
  const std::string text = test::readFile(dir / "observations.csv");
  const size_t row2 = text.find('\n') + 1;
  std::string line = text.substr(row2, text.find('\n', row2) - row2);
  std::vector<std::string> cells;
  std::stringstream ss(line);
  for (std::string c; std::getline(ss, c, ',');) cells.push_back(c);
  cells[8] = "-1";  // cov_ul_ul
  std::string bad;
  for (size_t i = 0; i < cells.size(); ++i) bad += (i ? "," : "") + cells[i];
  replaceLine(dir / "observations.csv", 2, bad);
  expectError(dir.path(), "observations.csv", "cov_ul_ul");
}

// The frontend's slide gains go with the pixels, with and without their own covariance; a bad
// one names the file, row and column.
TEST(Dataset, SlideGainsRoundTripAndBadOnesNameTheRow) {
  for (bool own_covariance : {false, true}) {
    TempDir dir;
    Dataset d = sample();
    const Eigen::Matrix4d C = stereoPixelCovariance(0.3, 0.12, 0.07, 0.1);
    int k = 0;
    for (Step& s : d.steps)
      for (Observation& o : s.observations) {
        if (own_covariance) o = observationFromPixels(d.rig, o.landmark_id, o.type, *o.pixels, o.head_pan, C);
        o.slide_gain = 0.25 * (k++ % 7) - 0.8;
      }
    saveDataset(d, dir.path(), false);
    const std::string text = test::readFile(dir / "observations.csv");
    EXPECT_NE(text.substr(0, text.find('\n')).find(",slide_gain"), std::string::npos);
    expectSame(d, loadDataset(dir.path()));
    const size_t row2 = text.find('\n') + 1;
    std::string line = text.substr(row2, text.find('\n', row2) - row2);
    replaceLine(dir / "observations.csv", 2, line.substr(0, line.rfind(',') + 1) + "nan");
    expectError(dir.path(), "observations.csv:2", "slide_gain");
  }
  // Without gains the file keeps the plain header.
  TempDir dir;
  saveDataset(sample(), dir.path(), false);
  EXPECT_EQ(test::readFile(dir / "observations.csv").find("slide_gain"), std::string::npos);
}

TEST(Dataset, RangeBearingRoundTripIsExact) {
  TempDir dir;
  Dataset d = sample();
  for (Step& s : d.steps)
    for (Observation& o : s.observations)
      o = observationFromRangeBearing(o.landmark_id, o.type, o.range, o.bearing, 10.0 + o.range / 100, 0.01);
  d.groundtruth[5].reset();  // ground truth may be partial
  d.odometry.readings = OdometryReadings::Commands;
  saveDataset(d, dir.path(), false);
  EXPECT_EQ(test::readFile(dir / "observations.csv").rfind("step,t,landmark_id,range,bearing,sigma_range,sigma_bearing\n", 0), 0u);
  expectSame(d, loadDataset(dir.path()));
}

TEST(Dataset, SameSeedGivesByteIdenticalFiles) {
  TempDir a, b, c;
  saveDataset(sample(11), a.path(), false);
  saveDataset(sample(11), b.path(), false);
  saveDataset(sample(12), c.path(), false);
  size_t files = 0;
  for (const auto& e : fs::directory_iterator(a.path())) {
    const std::string name = e.path().filename().string();
    EXPECT_EQ(test::readFile(a / name), test::readFile(b / name)) << name;
    ++files;
  }
  EXPECT_EQ(files, 7u);  // dataset.yaml map.yaml rig.yaml odometry compass observations groundtruth
  EXPECT_NE(test::readFile(a / "odometry.csv"), test::readFile(c / "odometry.csv"));
}

TEST(Dataset, RefusesNonEmptyDirectoryUnlessForced) {
  TempDir dir;
  fs::create_directories(dir.path());
  writeFile(dir / "keep.txt", "x");
  EXPECT_THROW(saveDataset(sample(), dir.path(), false), Error);
  EXPECT_TRUE(fs::exists(dir / "keep.txt"));
  saveDataset(sample(), dir.path(), true);
  EXPECT_FALSE(fs::exists(dir / "keep.txt"));
  EXPECT_NO_THROW(loadDataset(dir.path()));
  // An empty existing directory is fine without --force; no temporaries are left behind.
  TempDir empty;
  fs::create_directories(empty.path());
  saveDataset(sample(), empty.path(), false);
  for (const auto& e : fs::directory_iterator(fs::path(empty.path()).parent_path()))
    EXPECT_EQ(e.path().string().find(empty.path() + ".tmp"), std::string::npos);
}

TEST(Dataset, ExtraWriterRunsBeforeTheRenameAndFailuresLeaveNothing) {
  TempDir dir;
  saveDataset(sample(), dir.path(), false, [](const std::string& tmp) { writeFile(tmp + "/extra.txt", "y"); });
  EXPECT_TRUE(fs::exists(dir / "extra.txt"));
  TempDir failed;
  EXPECT_THROW(saveDataset(sample(), failed.path(), false, [](const std::string&) { throw Error("interrupted"); }),
               Error);
  EXPECT_FALSE(fs::exists(failed.path()));
}

class Malformed : public ::testing::Test {
 protected:
  void SetUp() override {
    Dataset d = sample();
    saveDataset(d, dir.path(), false);
  }
  TempDir dir;
};

TEST_F(Malformed, WrongColumnCount) {
  replaceLine(dir / "odometry.csv", 3, "1,0.1,2.0");
  expectError(dir.path(), "odometry.csv:3:", "expected 5 columns");
}

TEST_F(Malformed, NonNumericField) {
  replaceLine(dir / "compass.csv", 4, "2,0.20000000000000001,north");
  expectError(dir.path(), "compass.csv:4:", "'north' is not a number");
}

TEST_F(Malformed, NaN) {
  replaceLine(dir / "groundtruth.csv", 2, "0,0,nan,650,1.5");
  expectError(dir.path(), "groundtruth.csv:2:", "not a finite number");
}

TEST_F(Malformed, Infinity) {
  replaceLine(dir / "odometry.csv", 2, "0,0,inf,0,0");
  expectError(dir.path(), "odometry.csv:2:", "column 'd_left': 'inf' is not a finite number");
}

TEST_F(Malformed, StepsOutOfOrder) {
  const std::string odo = test::readFile(dir / "odometry.csv");
  std::istringstream in(odo);
  std::string header, l2, l3, rest, l;
  std::getline(in, header);
  std::getline(in, l2);
  std::getline(in, l3);
  while (std::getline(in, l)) rest += l + "\n";
  writeFile(dir / "odometry.csv", header + "\n" + l3 + "\n" + l2 + "\n" + rest);
  expectError(dir.path(), "odometry.csv:3:", "step 0 out of order");
}

TEST_F(Malformed, ObservationStepsOutOfOrder) {
  const std::string obs = test::readFile(dir / "observations.csv");
  std::istringstream in(obs);
  std::string header, l, last;
  std::getline(in, header);
  std::vector<std::string> lines;
  while (std::getline(in, l)) lines.push_back(l);
  ASSERT_GT(lines.size(), 3u);
  writeFile(dir / "observations.csv", header + "\n" + lines.back() + "\n" + lines.front() + "\n");
  expectError(dir.path(), "observations.csv:3:", "out of order");
}

TEST_F(Malformed, UnknownLandmarkId) {
  replaceFirstRowField(dir / "observations.csv", 2, "999");
  expectError(dir.path(), "observations.csv:2:", "unknown landmark id 999");
}

TEST_F(Malformed, UnknownStep) {
  replaceLine(dir / "groundtruth.csv", 2, "5000,0,1,2,0");
  expectError(dir.path(), "groundtruth.csv:2:", "step 5000 is not in odometry.csv");
}

TEST_F(Malformed, MissingReferencedFile) {
  fs::remove(dir / "map.yaml");
  expectError(dir.path(), "dataset.yaml", "map_file: referenced file");
}

TEST_F(Malformed, MissingOdometry) {
  fs::remove(dir / "odometry.csv");
  expectError(dir.path(), "odometry.csv", "does not exist");
}

TEST_F(Malformed, MissingImages) {
  std::string y = test::readFile(dir / "dataset.yaml");
  y.replace(y.find("has_images: 0"), 13, "has_images: 1");
  writeFile(dir / "dataset.yaml", y);
  expectError(dir.path(), "has_images", "images/left_000000.png");
}

TEST_F(Malformed, UnknownOdometryReadings) {
  std::string y = test::readFile(dir / "dataset.yaml");
  y.replace(y.find("readings: encoders"), 18, "readings: velocity");
  writeFile(dir / "dataset.yaml", y);
  expectError(dir.path(), "readings", "unknown odometry readings 'velocity'");
}

TEST_F(Malformed, WrongHeader) {
  replaceLine(dir / "compass.csv", 1, "step,t,heading");
  expectError(dir.path(), "compass.csv:1:", "expected header 'step,t,theta'");
}

TEST_F(Malformed, BadYaml) {
  std::string y = test::readFile(dir / "dataset.yaml");
  y.replace(y.find("format_version: 1"), 17, "format_version: 7");
  writeFile(dir / "dataset.yaml", y);
  expectError(dir.path(), "dataset.yaml", "unsupported version 7");
}

TEST_F(Malformed, PixelSigmaCopyThatDisagreesWithTheRig) {
  // dataset.yaml's noise.pixel_sigma only repeats the rig's: a different one would do nothing.
  std::string y = test::readFile(dir / "dataset.yaml");
  const size_t at = y.find("pixel_sigma:");
  ASSERT_NE(at, std::string::npos);
  y.replace(at, y.find('\n', at) - at, "pixel_sigma: 0.25");
  writeFile(dir / "dataset.yaml", y);
  expectError(dir.path(), "noise.pixel_sigma", "the rig's pixel_sigma");
  y.replace(at, y.find('\n', at) - at, "pixel_sigma: wide");
  writeFile(dir / "dataset.yaml", y);
  expectError(dir.path(), "noise.pixel_sigma", "not a number");
}

// Finite numbers no robot produces: each refused with its file, line and column, before an
// estimator turns it into an infinite RMSE, a solver failure or a landmark of another id.
TEST_F(Malformed, ImplausibleWheelIncrement) {
  replaceLine(dir / "odometry.csv", 3, "1,0.10000000000000001,1e150,0,0");
  expectError(dir.path(), "odometry.csv:3:", "beyond 1 km in one step");
}

TEST_F(Malformed, ImplausibleGroundTruth) {
  replaceLine(dir / "groundtruth.csv", 2, "0,0,1e308,650,1.5");
  expectError(dir.path(), "groundtruth.csv:2:", "beyond 1000 km");
}

TEST_F(Malformed, LandmarkIdBeyondInt) {
  replaceFirstRowField(dir / "observations.csv", 2, "4294967299");
  expectError(dir.path(), "observations.csv:2:", "landmark id 4294967299 out of range");
}

TEST_F(Malformed, PixelFarOutsideTheImage) {
  ASSERT_EQ(test::readFile(dir / "observations.csv").rfind("step,t,landmark_id,u_left,", 0), 0u);
  replaceFirstRowField(dir / "observations.csv", 3, "1000000");
  expectError(dir.path(), "observations.csv:2:", "lies far outside the");
}

TEST_F(Malformed, CompassSigmaBelowAnyCompass) {
  std::string y = test::readFile(dir / "dataset.yaml");
  const size_t at = y.find("compass_sigma:");
  ASSERT_NE(at, std::string::npos);
  y.replace(at, y.find('\n', at) - at, "compass_sigma: 1e-300");
  writeFile(dir / "dataset.yaml", y);
  expectError(dir.path(), "noise.compass_sigma", "within [1e-06, 2 pi] rad");
}

TEST_F(Malformed, HeaderWithoutLineBreaksIsShownShort) {
  std::string odo = test::readFile(dir / "odometry.csv");
  for (char& c : odo)
    if (c == '\n') c = '\r';
  writeFile(dir / "odometry.csv", odo);
  try {
    loadDataset(dir.path());
    FAIL() << "a file without line breaks was read";
  } catch (const Error& e) {
    const std::string m = e.what();
    EXPECT_NE(m.find("odometry.csv:1: expected header"), std::string::npos) << m;
    EXPECT_LT(m.size(), 400u) << m;
    EXPECT_EQ(m.find('\r'), std::string::npos);
  }
}

TEST_F(Malformed, TimeMismatch) {
  replaceLine(dir / "compass.csv", 3, "1,0.5,0.1");
  expectError(dir.path(), "compass.csv:3:", "does not match odometry.csv");
}

TEST(Csv, ReaderIsStrict) {
  TempDir dir;
  fs::create_directories(dir.path());
  writeFile(dir / "a.csv", "a,b\r\n1,2.5\r\n# comment\n3,-4e2\n");
  CsvReader r(dir / "a.csv");
  ASSERT_TRUE(r.next());
  EXPECT_EQ(r.getLong(0), 1);
  EXPECT_EQ(r.getDouble(1), 2.5);
  ASSERT_TRUE(r.next());
  EXPECT_EQ(r.line(), 4);
  EXPECT_EQ(r.getDouble(1), -400.0);
  EXPECT_THROW(r.getLong(1), Error);
  EXPECT_FALSE(r.next());

  writeFile(dir / "b.csv", "a,b\n1,2\n\n3,4\n");
  CsvReader b(dir / "b.csv");
  ASSERT_TRUE(b.next());
  try {
    b.next();
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("b.csv:3: empty line"), std::string::npos) << e.what();
  }
  writeFile(dir / "c.csv", "a\n1.5x\n 2\n");
  CsvReader c(dir / "c.csv");
  ASSERT_TRUE(c.next());
  EXPECT_THROW(c.getDouble(0), Error);
  ASSERT_TRUE(c.next());
  EXPECT_THROW(c.getDouble(0), Error);  // leading space
  EXPECT_THROW(CsvReader(dir / "missing.csv"), Error);
  writeFile(dir / "d.csv", "");
  EXPECT_THROW(CsvReader(dir / "d.csv"), Error);
}

TEST(Csv, WriterRoundTripsDoublesExactly) {
  CsvWriter w({"x"});
  const double values[] = {0.1, 1.0 / 3.0, -2.5e-300, 123456789.123456789, 0.0, -0.0};
  for (double v : values) {
    w.add(v);
    w.endRow();
  }
  EXPECT_THROW(w.add(std::nan("")), Error);
  CsvWriter w2({"a", "b"});
  w2.add(1L);
  EXPECT_THROW(w2.endRow(), Error);
  TempDir dir;
  fs::create_directories(dir.path());
  writeFile(dir / "x.csv", w.str());
  CsvReader r(dir / "x.csv");
  for (double v : values) {
    ASSERT_TRUE(r.next());
    EXPECT_EQ(r.getDouble(0), v);
  }
}

TEST(Csv, FormatDoubleHasThePrintfDigits) {
  // The files keep their text: the fast formatter prints what printf("%.17g") printed (but 0 for -0).
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<double> mantissa(-1.0, 1.0);
  std::uniform_int_distribution<int> exponent(-1070, 1020);  // binary exponents: subnormal to huge
  std::vector<double> values = {0.1, 1.0 / 3.0, 1e21, 1e-5, 123456789012345678.0, 5e-324, -1.7976931348623157e308};
  for (int i = 0; i < 20000; ++i) values.push_back(std::ldexp(mantissa(rng), exponent(rng)));
  for (double v : values) {
    if (!std::isfinite(v)) continue;
    char expected[64];
    std::snprintf(expected, sizeof(expected), "%.17g", v);
    ASSERT_EQ(formatDouble(v), v == 0.0 ? std::string("0") : std::string(expected));
    double back = 0;
    ASSERT_TRUE(parseDouble(formatDouble(v), &back));
    ASSERT_EQ(back, v == 0.0 ? 0.0 : v);
  }
  EXPECT_EQ(formatDouble(-0.0), "0");
}

TEST(Csv, ParseDoubleReadsWhatStrtodReads) {
  double v = 0;
  EXPECT_TRUE(parseDouble("+1.5", &v));
  EXPECT_EQ(v, 1.5);
  EXPECT_TRUE(parseDouble("0x10", &v));
  EXPECT_EQ(v, 16.0);
  EXPECT_TRUE(parseDouble("1e-400", &v));  // underflow: as strtod, a tiny number
  EXPECT_FALSE(parseDouble("1e400", &v));  // overflow
  EXPECT_FALSE(parseDouble(" 1", &v));
  EXPECT_FALSE(parseDouble("1 ", &v));
  EXPECT_FALSE(parseDouble("", &v));
  EXPECT_FALSE(parseDouble("1.5.2", &v));
  EXPECT_TRUE(parseDouble("nan", &v));  // a number; callers reject non-finite values
  EXPECT_TRUE(std::isnan(v));
}

TEST(Csv, ReaderNamesOverflowAndKeepsFieldsPerRow) {
  TempDir dir;
  fs::create_directories(dir.path());
  writeFile(dir / "o.csv", "a,b\n1e400,+7\nlonger-than-the-small-string-buffer-of-std-string,2\n3,4\n");
  CsvReader r(dir / "o.csv");
  ASSERT_TRUE(r.next());
  try {
    r.getDouble(0);
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("o.csv:2: column 'a': '1e400' is out of range"), std::string::npos) << e.what();
  }
  EXPECT_EQ(r.getLong(1), 7);
  ASSERT_TRUE(r.next());
  ASSERT_TRUE(r.next());
  EXPECT_EQ(r.field(0), "3");
  EXPECT_EQ(r.getDouble(1), 4.0);
  EXPECT_EQ(r.size(), 2u);
}

}  // namespace
}  // namespace stereoloc
