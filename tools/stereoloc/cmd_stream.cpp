// `stereoloc stream [--window W]`: the sliding-window smoother as a filter on JSON Lines. Each
// input line is one step,
//   {"step":12,"t":1.2,"d_left":10.1,"d_right":12.3,"compass":0.31,"compass_sigma":0.05,
//    "observations":[{"landmark_id":3,"range":812.0,"bearing":-0.2,"sigma_range":20,"sigma_bearing":0.01}]}
// (mm, rad, s); an observation may instead carry its pixels, {"landmark_id":3,"u_left":..,
// "v_left":..,"u_right":..,"v_right":..} (optionally "pixel_sigma"; range, bearing and R then come
// from the rig model, 5.26-5.32). For each step one line is printed as soon as it is computed:
//   {"step":12,"t":1.2,"x":..,"y":..,"theta":..,"covariance":[9 values, row-major],"status":"tracking"}
// A malformed line gets one error on stderr naming the line, and the stream goes on; the exit
// code is then 1 at the end. `--from DIR` replays a dataset the same way. `--smoothed` prints the
// smoothed trajectory (finish()) after the input ends, marked "smoothed":true. `--from DIR
// --frontend images` replays the dataset's images through the vision frontend instead of its
// observations.csv (tools/stereoloc/frontend_source.h).
#include <cmath>
#include <cstdio>
#include <iostream>
#include <limits>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "solvers/initialisation.h"
#include "solvers/sliding_window_smoother.h"
#include "src/io/dataset.h"
#include "src/core/field_map.h"
#include "src/core/stereo_rig.h"
#include "tools/stereoloc/cli_common.h"
#include "tools/stereoloc/localize_common.h"

namespace stereoloc::cli {
namespace {

// ---- A minimal JSON reader (objects, arrays, numbers, strings, true/false/null): enough for
// one step per line, with errors that say what is wrong.
struct Json {
  enum Kind { Null, Bool, Number, String, Array, Object } kind = Null;
  bool b = false;
  double num = 0.0;
  std::string str;
  std::vector<Json> arr;
  std::vector<std::pair<std::string, Json>> obj;
  const Json* get(const std::string& key) const {
    for (const auto& kv : obj)
      if (kv.first == key) return &kv.second;
    return nullptr;
  }
};

class JsonParser {
 public:
  explicit JsonParser(const std::string& s) : s_(s) {}
  Json parse() {
    Json v = value();
    ws();
    if (i_ != s_.size()) fail("unexpected text after the JSON value");
    return v;
  }

 private:
  [[noreturn]] void fail(const std::string& what) const {
    throw Error("column " + std::to_string(i_ + 1) + ": " + what);
  }
  void ws() {
    while (i_ < s_.size() && (s_[i_] == ' ' || s_[i_] == '\t' || s_[i_] == '\r' || s_[i_] == '\n')) ++i_;
  }
  bool literal(const char* word) {
    const std::string w(word);
    if (s_.compare(i_, w.size(), w) == 0) {
      i_ += w.size();
      return true;
    }
    return false;
  }
  Json value() {
    if (++depth_ > 64) fail("nested too deeply");
    ws();
    if (i_ >= s_.size()) fail("unexpected end of line");
    Json v;
    const char c = s_[i_];
    if (c == '{') {
      v.kind = Json::Object;
      ++i_;
      ws();
      if (i_ < s_.size() && s_[i_] == '}') {
        ++i_;
      } else {
        while (true) {
          ws();
          if (i_ >= s_.size() || s_[i_] != '"') fail("expected a key string");
          std::string key = string();
          ws();
          if (i_ >= s_.size() || s_[i_] != ':') fail("expected ':' after key \"" + key + "\"");
          ++i_;
          v.obj.emplace_back(std::move(key), value());
          ws();
          if (i_ < s_.size() && s_[i_] == ',') {
            ++i_;
            continue;
          }
          if (i_ < s_.size() && s_[i_] == '}') {
            ++i_;
            break;
          }
          fail("expected ',' or '}'");
        }
      }
    } else if (c == '[') {
      v.kind = Json::Array;
      ++i_;
      ws();
      if (i_ < s_.size() && s_[i_] == ']') {
        ++i_;
      } else {
        while (true) {
          v.arr.push_back(value());
          ws();
          if (i_ < s_.size() && s_[i_] == ',') {
            ++i_;
            continue;
          }
          if (i_ < s_.size() && s_[i_] == ']') {
            ++i_;
            break;
          }
          fail("expected ',' or ']'");
        }
      }
    } else if (c == '"') {
      v.kind = Json::String;
      v.str = string();
    } else if (literal("true")) {
      v.kind = Json::Bool;
      v.b = true;
    } else if (literal("false")) {
      v.kind = Json::Bool;
    } else if (literal("null")) {
      v.kind = Json::Null;
    } else {
      v.kind = Json::Number;
      const char* begin = s_.c_str() + i_;
      char* end = nullptr;
      v.num = std::strtod(begin, &end);
      if (end == begin) fail("expected a value");
      i_ += static_cast<size_t>(end - begin);
    }
    --depth_;
    return v;
  }
  std::string string() {
    ++i_;  // opening quote
    std::string out;
    while (i_ < s_.size() && s_[i_] != '"') {
      if (s_[i_] == '\\') {
        if (++i_ >= s_.size()) break;
        const char e = s_[i_];
        out += e == 'n' ? '\n' : e == 't' ? '\t' : e;  // \uXXXX is not needed for our keys
      } else {
        out += s_[i_];
      }
      ++i_;
    }
    if (i_ >= s_.size()) fail("unterminated string");
    ++i_;
    return out;
  }
  const std::string& s_;
  size_t i_ = 0;
  int depth_ = 0;
};

double number(const Json& o, const std::string& key, const std::string& where) {
  const Json* v = o.get(key);
  if (!v) throw Error(where + ": missing \"" + key + "\"");
  if (v->kind != Json::Number || !std::isfinite(v->num)) throw Error(where + ": \"" + key + "\" is not a finite number");
  return v->num;
}
std::optional<double> optionalNumber(const Json& o, const std::string& key, const std::string& where) {
  const Json* v = o.get(key);
  if (!v || v->kind == Json::Null) return std::nullopt;
  return number(o, key, where);
}

struct StreamContext {
  StereoRig rig;
  double compass_sigma = 0;  // default when a line has a compass but no compass_sigma
};

Step parseStep(const std::string& line, const StreamContext& ctx) {
  const Json j = JsonParser(line).parse();
  if (j.kind != Json::Object) throw Error("a step must be a JSON object");
  Step s;
  const double step = number(j, "step", "step");
  if (step != std::floor(step) || std::fabs(step) > 9e15) throw Error("\"step\" must be an integer");
  s.step = static_cast<long>(step);
  s.t = optionalNumber(j, "t", "step").value_or(0.0);
  s.d_left = number(j, "d_left", "step");
  s.d_right = number(j, "d_right", "step");
  s.head_pan = optionalNumber(j, "head_pan", "step").value_or(0.0);
  s.compass = optionalNumber(j, "compass", "step");
  if (s.compass) {
    s.compass_sigma = optionalNumber(j, "compass_sigma", "step").value_or(ctx.compass_sigma);
    if (!(s.compass_sigma > 0)) throw Error("\"compass\" needs a positive \"compass_sigma\"");
  }
  const Json* obs = j.get("observations");
  if (obs && obs->kind != Json::Null) {
    if (obs->kind != Json::Array) throw Error("\"observations\" must be an array");
    for (size_t i = 0; i < obs->arr.size(); ++i) {
      const Json& o = obs->arr[i];
      const std::string where = "observations[" + std::to_string(i) + "]";
      if (o.kind != Json::Object) throw Error(where + ": must be an object");
      const std::optional<double> id = optionalNumber(o, "landmark_id", where);
      if (id && (*id != std::floor(*id) || *id < -1 || *id > 1e9)) throw Error(where + ": bad \"landmark_id\"");
      LandmarkType type = LandmarkType::Point;
      if (const Json* t = o.get("type")) {
        if (t->kind != Json::String) throw Error(where + ": \"type\" must be a string");
        type = landmarkTypeFromString(t->str);
      }
      const int lid = id ? static_cast<int>(*id) : -1;
      try {
        if (o.get("u_left")) {
          StereoPixels px;
          px.u_left = number(o, "u_left", where);
          px.v_left = number(o, "v_left", where);
          px.u_right = number(o, "u_right", where);
          px.v_right = number(o, "v_right", where);
          const double sigma = optionalNumber(o, "pixel_sigma", where).value_or(ctx.rig.params().pixel_sigma);
          s.observations.push_back(observationFromPixels(ctx.rig, lid, type, px, s.head_pan, sigma));
        } else {
          s.observations.push_back(observationFromRangeBearing(lid, type, number(o, "range", where),
                                                               number(o, "bearing", where),
                                                               number(o, "sigma_range", where),
                                                               number(o, "sigma_bearing", where)));
        }
      } catch (const Error& e) {
        const std::string msg = e.what();
        throw Error(msg.rfind(where, 0) == 0 ? msg : where + ": " + msg);
      }
    }
  }
  return s;
}

std::string jsonNumber(double v) {
  if (!std::isfinite(v)) return "null";
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.17g", v);
  return buf;
}

void printEstimate(const Estimate& e, bool smoothed) {
  std::string line = "{\"step\":" + std::to_string(e.step) + ",\"t\":" + jsonNumber(e.t);
  if (e.status != EstimateStatus::Uninitialised) {
    line += ",\"x\":" + jsonNumber(e.pose.x) + ",\"y\":" + jsonNumber(e.pose.y) + ",\"theta\":" + jsonNumber(e.pose.theta);
    line += ",\"covariance\":[";
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) line += (r || c ? "," : "") + jsonNumber(e.covariance(r, c));
    line += "]";
  }
  line += ",\"status\":\"" + toString(e.status) + "\"";
  if (smoothed) line += ",\"smoothed\":true";
  line += "}\n";
  std::fwrite(line.data(), 1, line.size(), stdout);
  std::fflush(stdout);  // as soon as it is computed
}

struct StreamArgs {
  int window = 20;
  std::string from, map_path, rig_path, init = "auto";
  std::vector<double> pose, pose_sigma = {30.0, 30.0, 0.0872664626};
  double compass_sigma = 0;
  double wheel_base = OdometryParams().wheel_base_mm;
  int max_iterations = 5;
  bool no_gate = false, smoothed = false;
  std::string frontend = "pixels", frontend_landmarks = "all", frontend_params;
  std::string observation_model = "pixel_columns";
};

void runStream(const StreamArgs& a) {
  StreamContext ctx;
  FieldMap map;
  OdometryParams odometry;
  std::optional<Pose2> initial_pose;
  std::vector<Step> replay;
  if (a.frontend != "pixels" && a.from.empty())
    throw UsageError("--frontend images needs --from DIR (a dataset with images); stdin carries observations");
  if (!a.from.empty()) {
    // The frontend's summary goes to stderr: stdout is JSON Lines.
    Dataset d = loadDatasetWithFrontend(a.from, a.frontend, a.frontend_landmarks, a.frontend_params, stderr);
    map = d.map;
    ctx.rig = d.rig;
    odometry = d.odometry;
    ctx.compass_sigma = d.compass_sigma;
    initial_pose = d.initial_pose;
    replay = std::move(d.steps);
  } else {
    map = a.map_path.empty() ? FieldMap::miroSot() : FieldMap::load(a.map_path);
    if (!a.rig_path.empty()) ctx.rig = StereoRig::load(a.rig_path);
    odometry.wheel_base_mm = a.wheel_base;
    ctx.compass_sigma = a.compass_sigma;
  }
  if (a.compass_sigma > 0) ctx.compass_sigma = a.compass_sigma;
  if (!a.pose.empty()) {
    if (a.pose.size() != 3) throw UsageError("--pose takes x,y,theta (mm, mm, rad)");
    initial_pose = Pose2(a.pose[0], a.pose[1], a.pose[2]);
  }
  if (a.pose_sigma.size() != 3 || !(a.pose_sigma[0] > 0 && a.pose_sigma[1] > 0 && a.pose_sigma[2] > 0))
    throw UsageError("--pose-sigma takes three positive numbers (mm, mm, rad)");
  SlidingWindowConfig c;
  try {
    c.observation_model = {observationModelFromString(a.observation_model), ctx.rig};
  } catch (const Error& e) {
    throw UsageError(std::string("--observation-model: ") + e.what());
  }
  c.window = a.window;
  c.max_iterations = a.max_iterations;
  c.gate_enabled = !a.no_gate;
  c.keep_history = a.smoothed;
  const bool known = a.init == "known" || (a.init == "auto" && initial_pose);
  if (known) {
    if (!initial_pose) throw UsageError("--init known needs --pose (or a dataset with an initial pose)");
    const Eigen::Vector3d s(a.pose_sigma[0], a.pose_sigma[1], a.pose_sigma[2]);
    c.init = knownBelief(*initial_pose, s.cwiseAbs2().asDiagonal());
  }
  SlidingWindowSmoother win(map, odometry, c);
  long errors = 0;
  auto processLine = [&](const std::string& where, const Step& step) {
    try {
      printEstimate(win.process(step), false);
    } catch (const Error& e) {
      ++errors;
      std::cerr << "stereoloc stream: " << where << ": " << e.what() << std::endl;
    }
  };
  if (!a.from.empty()) {
    for (const Step& s : replay) processLine(a.from + ": step " + std::to_string(s.step), s);
  } else {
    std::string line;
    long n = 0;
    while (std::getline(std::cin, line)) {
      ++n;
      if (line.find_first_not_of(" \t\r") == std::string::npos) continue;  // blank line
      const std::string where = "stdin:" + std::to_string(n);
      Step step;
      try {
        step = parseStep(line, ctx);
      } catch (const Error& e) {
        ++errors;
        std::cerr << "stereoloc stream: " << where << ": " << e.what() << std::endl;
        continue;
      }
      processLine(where, step);
    }
  }
  if (a.smoothed)
    for (const Estimate& e : win.finish()) printEstimate(e, true);
  if (errors > 0) throw Error("stream: " + std::to_string(errors) + " step(s) rejected (see the messages above)");
}

}  // namespace

void add_stream_command(CLI::App& app) {
  auto a = std::make_shared<StreamArgs>();
  CLI::App* sub = app.add_subcommand(
      "stream",
      "Sliding-window smoother on JSON Lines: one step per line on stdin (or --from DIR), one estimate per line "
      "on stdout as soon as it is computed");
  sub->add_option("--window", a->window, "Window size W (poses)")->capture_default_str()->check(CLI::Range(1, 100000));
  sub->add_option("--observation-model", a->observation_model,
                  "How the window uses pixel observations: range_bearing, pixel_columns or pixels (see `localize "
                  "--help`); range-bearing observations stay range-bearing")
      ->capture_default_str();
  sub->add_option("--from", a->from, "Replay a dataset directory instead of reading stdin");
  sub->add_option("--map", a->map_path, "Map YAML (default: the MiroSot field); ignored with --from");
  sub->add_option("--rig", a->rig_path, "Stereo rig YAML for pixel observations (default rig); ignored with --from");
  sub->add_option("--init", a->init, "Start: auto (known when a pose is given), known, global (first global fix)")
      ->capture_default_str()
      ->check(CLI::IsMember({"auto", "known", "global"}));
  sub->add_option("--pose", a->pose, "Initial pose x,y,theta (mm, mm, rad)")->delimiter(',')->expected(3);
  sub->add_option("--pose-sigma", a->pose_sigma, "Initial sigmas x,y,theta (mm, mm, rad)")
      ->delimiter(',')
      ->expected(3)
      ->capture_default_str();
  sub->add_option("--compass-sigma", a->compass_sigma, "Compass sigma (rad) for lines without compass_sigma");
  sub->add_option("--wheel-base", a->wheel_base, "Wheel base (mm); ignored with --from")->capture_default_str();
  sub->add_option("--max-iterations", a->max_iterations, "Solver iterations per step")
      ->capture_default_str()
      ->check(CLI::Range(1, 1000));
  sub->add_flag("--no-gate", a->no_gate, "Fuse every observation (no validation gate)");
  sub->add_flag("--smoothed", a->smoothed, "After the input ends, print the smoothed trajectory (\"smoothed\":true)");
  addFrontendOptions(sub, a->frontend, a->frontend_landmarks, a->frontend_params);
  sub->callback([a] { runStream(*a); });
}

}  // namespace stereoloc::cli
