#include "src/io/dataset.h"

#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <limits>
#include <system_error>

#include "src/core/atomic_file.h"
#include "src/io/csv.h"
#include "src/core/error.h"
#include "src/core/measurement_model.h"
#include "src/core/yaml_util.h"

namespace stereoloc {
namespace fs = std::filesystem;
namespace {

// The largest position coordinate a dataset states (mm): a thousand kilometres.
constexpr double kMaxPositionMm = 1e9;

const std::vector<std::string> kOdometryHeader = {"step", "t", "d_left", "d_right"};
const std::vector<std::string> kOdometryPanHeader = {"step", "t", "d_left", "d_right", "head_pan"};
const std::vector<std::string> kCompassHeader = {"step", "t", "theta"};
const std::vector<std::string> kPixelHeader = {"step", "t", "landmark_id", "u_left", "v_left", "u_right", "v_right", "head_pan"};
// Pixels with their own covariance (px^2): the upper triangle of C row by row, in the order
// (u_l, v_l, u_r, v_r) of Observation::pixel_covariance.
const std::vector<std::string> kPixelCovarianceHeader = {
    "step",      "t",         "landmark_id", "u_left",    "v_left",    "u_right",   "v_right",   "head_pan",
    "cov_ul_ul", "cov_ul_vl", "cov_ul_ur",   "cov_ul_vr", "cov_vl_vl", "cov_vl_ur", "cov_vl_vr", "cov_ur_ur",
    "cov_ur_vr", "cov_vr_vr"};
constexpr int kCovarianceColumn = 8;
// Either pixel header with the frontend's slide gain (Observation::slide_gain) as a last column.
std::vector<std::string> withSlideGain(std::vector<std::string> header) {
  header.push_back("slide_gain");
  return header;
}

Eigen::Matrix4d covarianceFromUpper(const double* c) {
  Eigen::Matrix4d C;
  for (int i = 0, k = 0; i < 4; ++i)
    for (int j = i; j < 4; ++j, ++k) C(i, j) = C(j, i) = c[k];
  return C;
}
const std::vector<std::string> kRangeBearingHeader = {"step",    "t",           "landmark_id",  "range",
                                                      "bearing", "sigma_range", "sigma_bearing"};
const std::vector<std::string> kGroundTruthHeader = {"step", "t", "x", "y", "theta"};

std::string join(const std::string& dir, const std::string& file) { return (fs::path(dir) / file).string(); }

// Maps step numbers to indices into Dataset::steps (strictly increasing), for the files that
// refer to odometry steps. Their rows come in step order, so the search starts at the previous
// row's step: amortised O(1) per row, no index held in memory.
class StepIndex {
 public:
  explicit StepIndex(const std::vector<Step>& steps) : steps_(steps) {}
  // Checks the order (strictly increasing unless `allow_repeat`) and the existence of the step,
  // and that t agrees with odometry.csv.
  size_t lookup(CsvReader& in, long step, double t, bool allow_repeat) {
    if (have_last_ && (step < last_ || (!allow_repeat && step == last_)))
      in.fail("step " + std::to_string(step) + " out of order (after step " + std::to_string(last_) + ")");
    have_last_ = true;
    last_ = step;
    while (cursor_ < steps_.size() && steps_[cursor_].step < step) ++cursor_;
    if (cursor_ == steps_.size() || steps_[cursor_].step != step)
      in.fail("step " + std::to_string(step) + " is not in odometry.csv");
    if (std::fabs(steps_[cursor_].t - t) > 1e-9 * std::max(1.0, std::fabs(t)))
      in.failColumn(1, "t " + formatDouble(t) + " does not match odometry.csv (" + formatDouble(steps_[cursor_].t) + ")");
    return cursor_;
  }

 private:
  const std::vector<Step>& steps_;
  size_t cursor_ = 0;
  bool have_last_ = false;
  long last_ = 0;
};

std::string resolve(const std::string& dir, const std::string& file) {
  return fs::path(file).is_absolute() ? file : join(dir, file);
}

void requireFile(const YamlNode& node, const std::string& key, const std::string& path) {
  std::error_code ec;
  if (!fs::is_regular_file(path, ec)) node.fail(key, "referenced file '" + path + "' does not exist");
}

}  // namespace

std::string imageFileName(const std::string& kind, long step) {
  char buf[64];
  std::snprintf(buf, sizeof(buf), "images/%s_%06ld.%s", kind.c_str(), step, kind == "truth" ? "json" : "png");
  return buf;
}

namespace {

// dataset.yaml: the header, the map, the rig, the robot and the noise (the steps come later).
Dataset readDatasetYaml(const std::string& dir, const YamlReader& y) {
  const std::string format = y.getString("format");
  if (format != "stereoloc-dataset") y.fail("format", "expected 'stereoloc-dataset', found '" + format + "'");
  const int version = y.getInt("format_version");
  if (version != kDatasetFormatVersion)
    y.fail("format_version", "unsupported version " + std::to_string(version) + " (this build reads " +
                                 std::to_string(kDatasetFormatVersion) + ")");
  Dataset d;
  d.name = y.getString("name");
  d.description = y.getString("description", "");
  const std::string map_path = resolve(dir, y.getString("map_file"));
  requireFile(y, "map_file", map_path);
  d.map = FieldMap::load(map_path);
  const std::string rig_path = resolve(dir, y.getString("rig_file"));
  requireFile(y, "rig_file", rig_path);
  d.rig = StereoRig::load(rig_path);
  {
    const YamlNode r = y.child("robot");
    try {
      d.odometry.readings = odometryReadingsFromString(r.getString("readings", toString(d.odometry.readings)));
    } catch (const Error& e) {
      r.fail("readings", e.what());
    }
    d.odometry.wheel_base_mm = r.getDouble("wheel_base_mm");
    d.odometry.k_left = r.getDouble("k_left");
    d.odometry.k_right = r.getDouble("k_right");
    d.odometry.wheel_variance_floor = r.getDouble("wheel_variance_floor", d.odometry.wheel_variance_floor);
    if (r.has("control_variance_floor")) {
      const YamlNode f = r.child("control_variance_floor");
      d.odometry.control_variance_floor =
          Eigen::Vector3d(f.getDouble("x"), f.getDouble("y"), f.getDouble("theta"));
    }
    try {
      d.odometry.validate();
    } catch (const Error& e) {
      r.fail("", e.what());
    }
  }
  const YamlNode noise = y.child("noise");
  d.compass_sigma = noise.getDouble("compass_sigma");
  if (d.compass_sigma != 0.0 && !usableCompassSigma(d.compass_sigma))
    noise.fail("compass_sigma", "must be 0 (no compass) or within [1e-06, 2 pi] rad");
  // A copy of the rig's pixel sigma for readers of the file: one that differs would read as a
  // setting that silently does nothing, so it must agree with the rig.
  if (noise.has("pixel_sigma")) {
    const double copy = noise.getDouble("pixel_sigma"), used = d.rig.params().pixel_sigma;
    if (std::fabs(copy - used) > 1e-9 * std::max(1.0, std::fabs(used)))
      noise.fail("pixel_sigma", "is " + formatDouble(copy) + " but the rig's pixel_sigma (" + rig_path + ") is " +
                                    formatDouble(used) + "; the rig's is the one used: change it there");
  }
  if (y.has("initial_pose")) {
    const YamlNode p = y.child("initial_pose");
    d.initial_pose = Pose2(p.getDouble("x"), p.getDouble("y"), p.getDouble("theta"));
    for (const char* key : {"x", "y"})
      if (std::fabs(p.getDouble(key)) > kMaxPositionMm) p.fail(key, "beyond 1000 km");
  }
  d.has_images = y.getBool("has_images", false);
  return d;
}

// odometry.csv: the list of steps.
void readSteps(const std::string& dir, const YamlReader& y, Dataset* dp) {
  Dataset& d = *dp;
  const std::string path = join(dir, "odometry.csv");
  requireFile(y, "", path);
  CsvReader in(path);
  const bool with_pan = in.expectHeader({kOdometryHeader, kOdometryPanHeader}) == 1;
  while (in.next()) {
    Step s;
    s.step = in.getLong(0);
    s.t = in.getDouble(1);
    s.d_left = in.getDouble(2);
    s.d_right = in.getDouble(3);
    for (size_t c : {2, 3})
      if (std::fabs(c == 2 ? s.d_left : s.d_right) > kMaxWheelIncrementMm) in.failColumn(c, "beyond 1 km in one step");
    if (with_pan) s.head_pan = in.getDouble(4);
    if (!d.steps.empty()) {
      if (s.step <= d.steps.back().step)
        in.fail("step " + std::to_string(s.step) + " out of order (after step " + std::to_string(d.steps.back().step) + ")");
      if (s.t < d.steps.back().t) in.failColumn(1, "time goes backwards");
    }
    d.steps.push_back(s);
  }
  if (d.steps.empty()) in.fail("no steps");
}

// compass.csv (optional).
void readCompass(const std::string& dir, Dataset* dp) {
  Dataset& d = *dp;
  std::error_code ec;
  const std::string path = join(dir, "compass.csv");
  if (fs::exists(path, ec)) {
    CsvReader in(path);
    in.expectHeader({kCompassHeader});
    if (!(d.compass_sigma > 0)) in.fail("compass readings present but dataset.yaml noise.compass_sigma is 0");
    StepIndex idx(d.steps);
    while (in.next()) {
      const long step = in.getLong(0);
      const double t = in.getDouble(1);
      const double theta = in.getDouble(2);
      Step& s = d.steps[idx.lookup(in, step, t, false)];
      s.compass = wrapAngle(theta);
      s.compass_sigma = d.compass_sigma;
    }
  }
}

// observations.csv: pixels or range-bearing.
void readObservations(const std::string& dir, const YamlReader& y, Dataset* dp) {
  Dataset& d = *dp;
  const std::string path = join(dir, "observations.csv");
  requireFile(y, "", path);
  CsvReader in(path);
  const size_t header = in.expectHeader({kPixelHeader, kRangeBearingHeader, kPixelCovarianceHeader,
                                         withSlideGain(kPixelHeader), withSlideGain(kPixelCovarianceHeader)});
  const bool pixels = header != 1, covariance = header == 2 || header == 4, slide = header >= 3;
  StepIndex idx(d.steps);
  while (in.next()) {
    const long step = in.getLong(0);
    const double t = in.getDouble(1);
    const long id = in.getLong(2);
    double v[16];
    for (size_t c = 3; c < in.size(); ++c) v[c - 3] = in.getDouble(c);
    Step& s = d.steps[idx.lookup(in, step, t, true)];
    LandmarkType type = LandmarkType::Point;
    if (id != -1) {
      if (id < 0 || id > std::numeric_limits<int>::max())
        in.failColumn(2, "landmark id " + std::to_string(id) + " out of range");
      const Landmark* l = d.map.find(static_cast<int>(id));
      if (!l) in.failColumn(2, "unknown landmark id " + std::to_string(id) + " (not in the map)");
      type = l->type;
    }
    if (covariance) {
      try {
        checkPixelCovariance(covarianceFromUpper(v + kCovarianceColumn - 3), "pixel covariance");
      } catch (const Error& e) {
        in.failColumn(kCovarianceColumn, e.what());
      }
    }
    if (pixels) {
      // Far outside the image a pixel is no detection (a rectified one lies in it, give or take
      // a lens's edge): half an image's margin.
      const int w = d.rig.params().image_width, h = d.rig.params().image_height;
      for (size_t k = 0; k < 4; ++k) {
        const double size = k % 2 == 0 ? w : h;
        if (!(v[k] >= -0.5 * size && v[k] <= 1.5 * size))
          in.failColumn(3 + k, "pixel " + formatDouble(v[k]) + " lies far outside the " + std::to_string(w) + " x " +
                                   std::to_string(h) + " image");
      }
    }
    try {
      if (pixels) {
        const StereoPixels px{v[0], v[1], v[2], v[3]};
        if (covariance) {
          const Eigen::Matrix4d C = covarianceFromUpper(v + kCovarianceColumn - 3);
          s.observations.push_back(observationFromPixels(d.rig, static_cast<int>(id), type, px, v[4], C));
        } else {
          s.observations.push_back(
              observationFromPixels(d.rig, static_cast<int>(id), type, px, v[4], d.rig.params().pixel_sigma));
        }
        if (slide) s.observations.back().slide_gain = v[in.size() - 4];
      } else {
        s.observations.push_back(observationFromRangeBearing(static_cast<int>(id), type, v[0], v[1], v[2], v[3]));
      }
    } catch (const Error& e) {
      in.fail(e.what());
    }
  }
}

// groundtruth.csv (optional).
void readGroundTruth(const std::string& dir, Dataset* dp) {
  Dataset& d = *dp;
  std::error_code ec;
  d.groundtruth.assign(d.steps.size(), std::nullopt);
  const std::string path = join(dir, "groundtruth.csv");
  if (fs::exists(path, ec)) {
    CsvReader in(path);
    in.expectHeader({kGroundTruthHeader});
    StepIndex idx(d.steps);
    while (in.next()) {
      const long step = in.getLong(0);
      const double t = in.getDouble(1);
      const Pose2 p(in.getDouble(2), in.getDouble(3), in.getDouble(4));
      for (size_t c : {2, 3})
        if (std::fabs(c == 2 ? p.x : p.y) > kMaxPositionMm) in.failColumn(c, "beyond 1000 km");
      d.groundtruth[idx.lookup(in, step, t, false)] = p;
    }
  }
}

// The image pair of every step, when dataset.yaml says there are images.
void checkImages(const std::string& dir, const YamlReader& y, const Dataset& d) {
  std::error_code ec;
    for (const Step& s : d.steps)
      for (const char* kind : {"left", "right"}) {
        const std::string path = join(dir, imageFileName(kind, s.step));
        if (!fs::is_regular_file(path, ec)) y.fail("has_images", "referenced file '" + path + "' does not exist");
      }
}

}  // namespace

Dataset loadDataset(const std::string& dir) {
  std::error_code ec;
  if (!fs::is_directory(dir, ec)) throw Error(dir + ": not a dataset directory");
  const std::string yaml_path = join(dir, "dataset.yaml");
  if (!fs::is_regular_file(yaml_path, ec)) throw Error(yaml_path + ": missing (not a stereoloc dataset)");
  YamlReader y(yaml_path);
  Dataset d = readDatasetYaml(dir, y);
  readSteps(dir, y, &d);
  readCompass(dir, &d);
  readObservations(dir, y, &d);
  readGroundTruth(dir, &d);
  if (d.has_images) checkImages(dir, y, d);
  return d;
}

namespace {

// What the files of a dataset hold beyond the fixed columns, decided once from all its steps.
struct DatasetLayout {
  bool all_pixels = true;       // observations.csv in pixels (else range-bearing)
  bool any_pan = false;         // odometry.csv has a head_pan column
  bool any_compass = false;     // compass.csv is written
  bool own_covariance = false;  // pixel rows carry their covariance (not the rig's sigma^2 I)
  bool any_slide = false;       // pixel rows carry a slide gain
};

// Checks what the files cannot represent (throws stereoloc::Error) and lays them out.
DatasetLayout layoutOf(const Dataset& d) {
  if (d.groundtruth.size() != d.steps.size() && !d.groundtruth.empty())
    throw Error("saveDataset: groundtruth must have one entry per step (or none)");
  DatasetLayout l;
  const Eigen::Matrix4d rig_covariance =
      d.rig.params().pixel_sigma * d.rig.params().pixel_sigma * Eigen::Matrix4d::Identity();
  for (size_t i = 0; i < d.steps.size(); ++i) {
    const Step& s = d.steps[i];
    if (i > 0 && s.step <= d.steps[i - 1].step) throw Error("saveDataset: step numbers must increase");
    l.any_pan |= s.head_pan != 0.0;
    l.any_compass |= s.compass.has_value();
    for (const Observation& o : s.observations) {
      l.all_pixels &= o.pixels.has_value();
      l.own_covariance |= o.pixels.has_value() && o.pixel_covariance != rig_covariance;
      l.any_slide |= o.slide_gain != 0.0;
      if (!std::isfinite(o.slide_gain)) throw Error("saveDataset: an observation's slide gain is not finite");
    }
  }
  // Pixel observations whose covariance is not the rig's sigma^2 I carry it in their rows, and
  // those with a slide gain carry it in a last column; range-bearing rows carry neither.
  l.own_covariance &= l.all_pixels;
  l.any_slide &= l.all_pixels;
  if (l.any_compass && !(d.compass_sigma > 0))
    throw Error("saveDataset: steps carry compass readings but compass_sigma is 0");
  return l;
}

void writeDatasetYaml(const Dataset& d, const DatasetLayout& layout, const std::string& dir) {
  YamlWriter y;
  y.comment("stereoloc dataset (docs/dataset_format.md). Units: mm, rad, s.");
  cv::FileStorage& f = y.fs();
  f << "format" << "stereoloc-dataset";
  f << "format_version" << kDatasetFormatVersion;
  f << "name" << d.name;
  f << "description" << d.description;
  f << "map_file" << "map.yaml";
  f << "rig_file" << "rig.yaml";
  const OdometryParams& o = d.odometry;
  f << "robot" << "{" << "readings" << toString(o.readings) << "wheel_base_mm" << o.wheel_base_mm << "k_left" << o.k_left << "k_right" << o.k_right
    << "wheel_variance_floor" << o.wheel_variance_floor << "control_variance_floor" << "{" << "x"
    << o.control_variance_floor.x() << "y" << o.control_variance_floor.y() << "theta" << o.control_variance_floor.z()
    << "}" << "}";
  f << "noise" << "{" << "compass_sigma" << d.compass_sigma << "pixel_sigma" << d.rig.params().pixel_sigma << "}";
  if (d.initial_pose)
    f << "initial_pose" << "{" << "x" << d.initial_pose->x << "y" << d.initial_pose->y << "theta"
      << d.initial_pose->theta << "}";
  f << "observation_kind" << (layout.all_pixels ? "pixels" : "range_bearing");
  f << "has_images" << (d.has_images ? 1 : 0);
  y.writeAtomically(join(dir, "dataset.yaml"));
}

void addObservationRow(const Step& s, const Observation& ob, const DatasetLayout& layout, CsvWriter* obs) {
  obs->add(s.step).add(s.t).add(ob.landmark_id);
  if (layout.all_pixels) {
    const StereoPixels& p = *ob.pixels;
    obs->add(p.u_left).add(p.v_left).add(p.u_right).add(p.v_right).add(ob.head_pan);
    if (layout.own_covariance)
      for (int r = 0; r < 4; ++r)
        for (int c = r; c < 4; ++c) obs->add(ob.pixel_covariance(r, c));
    if (layout.any_slide) obs->add(ob.slide_gain);
  } else {
    obs->add(ob.range).add(ob.bearing).add(std::sqrt(ob.covariance(0, 0))).add(std::sqrt(ob.covariance(1, 1)));
  }
  obs->endRow();
}

// odometry.csv, observations.csv, and compass.csv and groundtruth.csv when there is any.
void writeStepFiles(const Dataset& d, const DatasetLayout& layout, const std::string& dir) {
  CsvWriter odo(layout.any_pan ? kOdometryPanHeader : kOdometryHeader);
  CsvWriter compass(kCompassHeader);
  const std::vector<std::string>& pixel_header = layout.own_covariance ? kPixelCovarianceHeader : kPixelHeader;
  CsvWriter obs(!layout.all_pixels ? kRangeBearingHeader : layout.any_slide ? withSlideGain(pixel_header) : pixel_header);
  CsvWriter gt(kGroundTruthHeader);
  for (size_t i = 0; i < d.steps.size(); ++i) {
    const Step& s = d.steps[i];
    odo.add(s.step).add(s.t).add(s.d_left).add(s.d_right);
    if (layout.any_pan) odo.add(s.head_pan);
    odo.endRow();
    if (s.compass) {
      compass.add(s.step).add(s.t).add(*s.compass);
      compass.endRow();
    }
    for (const Observation& ob : s.observations) addObservationRow(s, ob, layout, &obs);
    if (!d.groundtruth.empty() && d.groundtruth[i]) {
      const Pose2& p = *d.groundtruth[i];
      gt.add(s.step).add(s.t).add(p.x).add(p.y).add(p.theta);
      gt.endRow();
    }
  }
  writeFileAtomically(join(dir, "odometry.csv"), odo.str());
  writeFileAtomically(join(dir, "observations.csv"), obs.str());
  if (layout.any_compass) writeFileAtomically(join(dir, "compass.csv"), compass.str());
  if (gt.rows() > 0) writeFileAtomically(join(dir, "groundtruth.csv"), gt.str());
}

void writeFiles(const Dataset& d, const std::string& dir) {
  const DatasetLayout layout = layoutOf(d);
  d.map.save(join(dir, "map.yaml"));
  d.rig.save(join(dir, "rig.yaml"));
  writeDatasetYaml(d, layout, dir);
  writeStepFiles(d, layout, dir);
}

}  // namespace

void saveDataset(const Dataset& d, const std::string& dir, bool force) { saveDataset(d, dir, force, nullptr); }

void saveDataset(const Dataset& d, const std::string& dir_in, bool force, const DatasetExtraWriter& extra) {
  fs::path target = fs::path(dir_in).lexically_normal();
  if (target.has_filename() == false) target = target.parent_path();
  const std::string dir = target.string();
  if (dir.empty()) throw Error("saveDataset: empty output directory");
  std::error_code ec;
  const bool exists = fs::exists(target, ec);
  if (exists) {
    if (!fs::is_directory(target, ec)) throw Error(dir + ": exists and is not a directory");
    if (!fs::is_empty(target, ec) && !force)
      throw Error(dir + ": directory exists and is not empty (use --force to replace it)");
  }
  if (target.has_parent_path()) fs::create_directories(target.parent_path(), ec);
  const std::string pid = std::to_string(static_cast<long>(::getpid()));
  const fs::path tmp = dir + ".tmp." + pid;
  fs::remove_all(tmp, ec);
  if (!fs::create_directories(tmp, ec)) throw Error(tmp.string() + ": cannot create temporary directory");
  try {
    writeFiles(d, tmp.string());
    if (extra) extra(tmp.string());
    if (exists) {
      const fs::path old = dir + ".old." + pid;
      fs::remove_all(old, ec);
      fs::rename(target, old, ec);
      if (ec) throw Error(dir + ": cannot move the old directory aside: " + ec.message());
      fs::rename(tmp, target, ec);
      if (ec) {
        fs::rename(old, target);
        throw Error(dir + ": cannot rename the temporary directory into place: " + ec.message());
      }
      fs::remove_all(old, ec);
    } else {
      fs::rename(tmp, target, ec);
      if (ec) throw Error(dir + ": cannot rename the temporary directory into place: " + ec.message());
    }
  } catch (...) {
    fs::remove_all(tmp, ec);
    throw;
  }
}

}  // namespace stereoloc
