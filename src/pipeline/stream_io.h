#pragma once
// JSON Lines for the real-time stream (`stereoloc stream`, src/pipeline/localizer.h): one input
// line per step, one estimate line out. Units mm, rad, s.
//
// Input line: the odometry of step "step", with the observations of that step or of an earlier
// one ("obs_step", a camera slower than the encoders), given as observations or as a stereo pair
// of image files for the frontend:
//   {"step":12,"t":1.2,"d_left":10.1,"d_right":12.3,"compass":0.31,"compass_sigma":0.05,"head_pan":0,
//    "observations":[{"landmark_id":3,"range":812.0,"bearing":-0.2,"sigma_range":20,"sigma_bearing":0.01}]}
//   {"step":13,"t":1.3,"d_left":10.0,"d_right":10.2,"obs_step":11,"left":"l11.png","right":"r11.png"}
//   {"obs_step":11,"observations":[...]}            (observations alone, between odometry lines)
// An observation may carry its pixels instead, {"landmark_id":3,"u_left":..,"v_left":..,"u_right":..,
// "v_right":..} (optionally "pixel_sigma", px, or "pixel_covariance", px^2: the 10 values of the
// upper triangle row by row in the order u_l, v_l, u_r, v_r); range, bearing and R then come
// from the rig (5.26-5.32).
// "landmark_id" -1 or absent: not identified (associated by the estimator), with an optional "type".
// "t" (s) may be left out (0); a step's t is never earlier than the step before it. "compass"
// (with "compass_sigma" or the stream's default), "head_pan" and "obs_step" are optional. Strict
// JSON: numbers as the JSON grammar writes them (no NaN, inf, hex, ".5" or "+1"), no key twice.
//
// Output line: {"step":12,"t":1.2,"x":..,"y":..,"theta":..,"covariance":[9 values, row-major],
// "status":"tracking","compute_ms":0.84} plus, for a line with late observations,
// "obs_step":11,"late":"inserted" (or "too_late", "not_tracking").
#include <optional>
#include <string>
#include <vector>

#include "src/core/stereo_rig.h"
#include "src/core/types.h"

namespace stereoloc {

// One parsed input line.
struct StreamLine {
  bool has_odometry = false;       // "step" with "d_left" and "d_right"
  Step step;                       // step, t, d_left, d_right, compass, head_pan (observations empty)
  long obs_step = 0;               // the step the observations or images belong to
  std::vector<Observation> observations;
  std::string left_image, right_image;  // both set, or both empty
  bool hasObservationData() const { return !observations.empty() || !left_image.empty(); }
};

// Parses one line. `rig` turns pixel observations into range-bearing; `default_compass_sigma`
// (rad) is used for a "compass" without "compass_sigma". Throws stereoloc::Error with one line
// saying what is wrong ("column 17: expected ',' or '}'", "\"d_left\" is not a finite number").
StreamLine parseStreamLine(const std::string& line, const StereoRig& rig, double default_compass_sigma);

// The fields an output line carries besides the estimate.
struct StreamOutputExtras {
  std::optional<double> compute_ms;       // wall time the pipeline spent on this line
  std::optional<long> obs_step;           // with `late`
  std::string late;                       // toString(ObservationDelivery) of late data, or empty
  bool smoothed = false;                  // a line of the smoothed trajectory after the input
};

class Localizer;

// What one input line did: the output line (empty when the line's odometry was refused) and one
// message per problem (an unreadable image, observations too late, ...).
struct StreamLineResult {
  std::string output;
  std::vector<std::string> errors;
};

// Feeds one line to the Localizer: the step's odometry first (refused: nothing else is done),
// then its observations or images (refused: the odometry still counts), then the estimate.
StreamLineResult feedStreamLine(Localizer& localizer, const StreamLine& line);

// The line of a dataset step, with its images at DIR/images/... instead of its observations
// when `images` (the replay of `stream --from DIR --frontend images`).
StreamLine streamLineOf(const Step& step, const std::string& dataset_dir, bool images);

// One output line (with the trailing newline); numbers with 17 significant digits, so that
// reading them back gives the same doubles. An uninitialised estimate has no pose fields.
std::string formatStreamEstimate(const Estimate& estimate, const StreamOutputExtras& extras = StreamOutputExtras());

}  // namespace stereoloc
