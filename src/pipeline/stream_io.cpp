#include "src/pipeline/stream_io.h"

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <utility>

#include "src/core/error.h"
#include "src/core/measurement_model.h"
#include "src/io/dataset.h"
#include "src/pipeline/localizer.h"

namespace stereoloc {
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
          // Which of two equal keys counts is left open by JSON; here neither does.
          for (const auto& kv : v.obj)
            if (kv.first == key) fail("duplicate key \"" + key + "\"");
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
      const size_t length = numberLength();
      if (length == 0) fail("expected a value");
      v.num = std::strtod(s_.substr(i_, length).c_str(), nullptr);
      i_ += length;
    }
    --depth_;
    return v;
  }
  // Characters of the JSON number at i_: -?(0|[1-9][0-9]*)(.[0-9]+)?([eE][+-]?[0-9]+)?; 0 when
  // there is none (strtod alone would also take "nan", "inf", hex, ".5" and "+1").
  size_t numberLength() const {
    size_t k = i_;
    auto digits = [&] {
      const size_t from = k;
      while (k < s_.size() && s_[k] >= '0' && s_[k] <= '9') ++k;
      return k - from;
    };
    if (k < s_.size() && s_[k] == '-') ++k;
    if (k < s_.size() && s_[k] == '0') {
      ++k;
    } else if (digits() == 0) {
      return 0;
    }
    if (k < s_.size() && s_[k] == '.') {
      ++k;
      if (digits() == 0) return 0;
    }
    if (k < s_.size() && (s_[k] == 'e' || s_[k] == 'E')) {
      ++k;
      if (k < s_.size() && (s_[k] == '+' || s_[k] == '-')) ++k;
      if (digits() == 0) return 0;
    }
    return k - i_;
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

std::string jsonNumber(double v) {
  if (!std::isfinite(v)) return "null";
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.17g", v);
  return buf;
}

long integer(const Json& o, const std::string& key) {
  const double v = number(o, key, "line");
  if (v != std::floor(v) || std::fabs(v) > 9e15) throw Error("\"" + key + "\" must be an integer");
  return static_cast<long>(v);
}

std::string text(const Json& o, const std::string& key) {
  const Json* v = o.get(key);
  if (!v || v->kind == Json::Null) return "";
  if (v->kind != Json::String || v->str.empty()) throw Error("\"" + key + "\" must be a non-empty string");
  return v->str;
}

Observation parseObservation(const Json& o, const std::string& where, const StereoRig& rig, double head_pan) {
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
      // The frontend's slide gain (Observation::slide_gain), 0 when absent.
      const double slide_gain = optionalNumber(o, "slide_gain", where).value_or(0.0);
      if (const Json* c = o.get("pixel_covariance")) {
        if (o.get("pixel_sigma")) throw Error(where + ": give \"pixel_sigma\" or \"pixel_covariance\", not both");
        if (c->kind != Json::Array || c->arr.size() != 10)
          throw Error(where + ": \"pixel_covariance\" must be an array of 10 numbers");
        Eigen::Matrix4d C;
        for (int i = 0, k = 0; i < 4; ++i)
          for (int j = i; j < 4; ++j, ++k) {
            const Json& e = c->arr[static_cast<size_t>(k)];
            if (e.kind != Json::Number || !std::isfinite(e.num))
              throw Error(where + ": \"pixel_covariance\" holds a value that is not a finite number");
            C(i, j) = C(j, i) = e.num;
          }
        checkPixelCovariance(C, where);
        Observation obs = observationFromPixels(rig, lid, type, px, head_pan, C);
        obs.slide_gain = slide_gain;
        return obs;
      }
      const double sigma = optionalNumber(o, "pixel_sigma", where).value_or(rig.params().pixel_sigma);
      Observation obs = observationFromPixels(rig, lid, type, px, head_pan, sigma);
      obs.slide_gain = slide_gain;
      return obs;
    }
    return observationFromRangeBearing(lid, type, number(o, "range", where), number(o, "bearing", where),
                                       number(o, "sigma_range", where), number(o, "sigma_bearing", where));
  } catch (const Error& e) {
    const std::string msg = e.what();
    throw Error(msg.rfind(where, 0) == 0 ? msg : where + ": " + msg);
  }
}

}  // namespace

StreamLine parseStreamLine(const std::string& line, const StereoRig& rig, double default_compass_sigma) {
  const Json j = JsonParser(line).parse();
  if (j.kind != Json::Object) throw Error("a line must be a JSON object");
  StreamLine s;
  s.has_odometry = j.get("step") != nullptr;
  if (s.has_odometry) {
    s.step.step = integer(j, "step");
    s.step.t = optionalNumber(j, "t", "step").value_or(0.0);
    s.step.d_left = number(j, "d_left", "step");
    s.step.d_right = number(j, "d_right", "step");
    s.step.head_pan = optionalNumber(j, "head_pan", "step").value_or(0.0);
    s.step.compass = optionalNumber(j, "compass", "step");
    if (s.step.compass) {
      s.step.compass_sigma = optionalNumber(j, "compass_sigma", "step").value_or(default_compass_sigma);
      if (!usableCompassSigma(s.step.compass_sigma))
        throw Error("\"compass\" needs a \"compass_sigma\" within [1e-06, 2 pi] rad");
    }
  } else if (!j.get("obs_step")) {
    throw Error("missing \"step\" (odometry) and \"obs_step\" (late observations)");
  }
  s.obs_step = j.get("obs_step") ? integer(j, "obs_step") : s.step.step;
  if (s.has_odometry && s.obs_step > s.step.step)
    throw Error("\"obs_step\" " + std::to_string(s.obs_step) + " is after \"step\" " + std::to_string(s.step.step));
  s.left_image = text(j, "left");
  s.right_image = text(j, "right");
  if (s.left_image.empty() != s.right_image.empty()) throw Error("\"left\" and \"right\" come together");
  const Json* obs = j.get("observations");
  if (obs && obs->kind != Json::Null) {
    if (!s.left_image.empty()) throw Error("a line carries \"observations\" or images, not both");
    if (obs->kind != Json::Array) throw Error("\"observations\" must be an array");
    for (size_t i = 0; i < obs->arr.size(); ++i)
      s.observations.push_back(
          parseObservation(obs->arr[i], "observations[" + std::to_string(i) + "]", rig, s.step.head_pan));
  }
  if (!s.has_odometry && !s.hasObservationData()) throw Error("\"obs_step\" without observations or images");
  return s;
}

std::string formatStreamEstimate(const Estimate& e, const StreamOutputExtras& x) {
  std::string line = "{\"step\":" + std::to_string(e.step) + ",\"t\":" + jsonNumber(e.t);
  if (e.status != EstimateStatus::Uninitialised) {
    line += ",\"x\":" + jsonNumber(e.pose.x) + ",\"y\":" + jsonNumber(e.pose.y) + ",\"theta\":" + jsonNumber(e.pose.theta);
    line += ",\"covariance\":[";
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) line += (r || c ? "," : "") + jsonNumber(e.covariance(r, c));
    line += "]";
  }
  line += ",\"status\":\"" + toString(e.status) + "\"";
  if (x.compute_ms) {
    char buf[32];
    std::snprintf(buf, sizeof buf, "%.4f", *x.compute_ms);
    line += ",\"compute_ms\":" + std::string(buf);
  }
  if (!x.late.empty()) {
    if (x.obs_step) line += ",\"obs_step\":" + std::to_string(*x.obs_step);
    line += ",\"late\":\"" + x.late + "\"";
  }
  if (x.smoothed) line += ",\"smoothed\":true";
  return line + "}\n";
}

StreamLineResult feedStreamLine(Localizer& localizer, const StreamLine& s) {
  StreamLineResult r;
  if (s.has_odometry) {
    try {
      localizer.addStep(s.step);
    } catch (const Error& e) {
      r.errors.push_back(e.what());
      return r;
    }
  }
  StreamOutputExtras x;
  if (s.hasObservationData()) {
    try {
      const ObservationDelivery d =
          s.left_image.empty() ? localizer.addObservations(s.obs_step, s.observations)
                               : localizer.addImageFiles(s.obs_step, s.left_image, s.right_image, s.step.head_pan);
      if (d != ObservationDelivery::WithStep) {
        x.obs_step = s.obs_step;
        x.late = toString(d);
      }
      if (d == ObservationDelivery::TooLate)
        r.errors.push_back("observations of step " + std::to_string(s.obs_step) + " are too late: " +
                           (localizer.config().method == LocalizerMethod::Window
                                ? std::string("the step has left the window")
                                : "the step is older than the filter's last " +
                                      std::to_string(localizer.config().replay_steps) + " steps"));
    } catch (const Error& e) {
      r.errors.push_back(e.what());
    }
  }
  try {
    const Estimate e = localizer.estimate();
    x.compute_ms = localizer.computeMilliseconds();
    r.output = formatStreamEstimate(e, x);
  } catch (const Error& e) {
    r.errors.push_back(e.what());
  }
  return r;
}

StreamLine streamLineOf(const Step& step, const std::string& dataset_dir, bool images) {
  StreamLine s;
  s.has_odometry = true;
  s.step = step;
  s.obs_step = step.step;
  if (images) {
    s.step.observations.clear();
    s.left_image = dataset_dir + "/" + imageFileName("left", step.step);
    s.right_image = dataset_dir + "/" + imageFileName("right", step.step);
  }
  return s;
}

}  // namespace stereoloc
