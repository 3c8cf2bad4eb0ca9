// A robot's localization loop on the installed stereoloc::Localizer (src/pipeline/localizer.h):
// wheel encoders and compass every step, a stereo pair whenever the camera has one, the pose
// with its covariance after each step. The "robot" here replays a recorded run (`stereoloc simulate
// --images`); on a real robot the encoder and camera drivers take the place of the dataset.
//   robot_loop DATASET_DIR      (prints the last pose; exit 1 on bad data)
#include <cmath>
#include <cstdio>
#include <string>

#include "src/core/error.h"
#include "src/io/dataset.h"
#include "src/pipeline/localizer.h"

int main(int argc, char** argv) {
  if (argc != 2) return std::fprintf(stderr, "usage: robot_loop DATASET_DIR\n"), 2;
  try {
    const std::string dir = argv[1];
    const stereoloc::Dataset recording = stereoloc::loadDataset(dir);
    stereoloc::LocalizerConfig config;  // sliding window W = 20, vision frontend
    config.map = recording.map;
    config.rig = recording.rig;
    config.odometry = recording.odometry;
    config.init = stereoloc::globalBelief();  // start from the first global fix
    config.window.keep_history = false;       // runs for ever in bounded memory
    stereoloc::Localizer localizer(config);
    stereoloc::Estimate pose;
    for (const stereoloc::Step& tick : recording.steps) {
      stereoloc::Step reading = tick;  // wheel increments (mm), compass (rad) of this step
      reading.observations.clear();    // the camera's come from the frontend
      localizer.addStep(reading);
      if (recording.has_images) {
        try {  // a bad frame is lost, the robot goes on
          localizer.addImageFiles(tick.step, dir + "/" + stereoloc::imageFileName("left", tick.step),
                                  dir + "/" + stereoloc::imageFileName("right", tick.step), tick.head_pan);
        } catch (const stereoloc::Error& e) {
          std::fprintf(stderr, "frame %ld: %s\n", tick.step, e.what());
        }
      }
      pose = localizer.estimate();  // act on pose.pose, pose.covariance here
    }
    std::printf("step %ld: x %.1f mm, y %.1f mm, theta %.3f rad, sigma_x %.1f mm, %s, %.2f ms\n", pose.step,
                pose.pose.x, pose.pose.y, pose.pose.theta, std::sqrt(pose.covariance(0, 0)),
                stereoloc::toString(pose.status).c_str(), localizer.computeMilliseconds());
    return pose.status == stereoloc::EstimateStatus::Uninitialised ? 1 : 0;
  } catch (const stereoloc::Error& e) {
    std::fprintf(stderr, "robot_loop: %s\n", e.what());
    return 1;
  }
}
