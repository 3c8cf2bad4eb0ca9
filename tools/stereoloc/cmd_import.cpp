// `stereoloc import mrclam SRC_DIR --robot N [--rate HZ] [--wheel-base MM] [--range-correction fit|C0,C1,C2]
// [--command-delay fit|SECONDS] [--correlated-errors] [--out DIR] [--force]`:
// converts a UTIAS MR.CLAM dataset (src/io/mrclam.h) into a stereoloc dataset directory and prints
// the import summary (row counts, dropped measurements, range/bearing error statistics and their
// correlation over sightings against ground truth, the fitted odometry noise). Without --out it
// only prints the summary.
#include <cmath>
#include <cstdio>
#include <iostream>
#include <memory>
#include <optional>
#include <string>

#include "src/io/dataset.h"
#include "src/io/mrclam.h"
#include "tools/stereoloc/cli_common.h"

namespace stereoloc::cli {
namespace {

struct ImportMrclamOptions {
  std::string src_dir, out_dir;
  int robot = 0;
  double rate_hz = 10.0;
  double wheel_base_mm = 260.0;
  double sigma_range_mm = 0.0;       // 0: estimate
  double sigma_bearing_deg = 0.0;    // 0: estimate
  double odometry_noise_scale = 1.0;
  double odometry_window_s = 1.0;
  bool correlated_errors = false;
  std::optional<std::string> range_correction;  // "fit" or "C0,C1,C2"
  std::optional<std::string> command_delay;     // "fit" or seconds
  bool force = false;
};

void runImportMrclam(const ImportMrclamOptions& o) {
  MrclamImportConfig config;
  config.robot = o.robot;
  config.rate_hz = o.rate_hz;
  config.wheel_base_mm = o.wheel_base_mm;
  config.odometry_noise_scale = o.odometry_noise_scale;
  config.odometry_window_s = o.odometry_window_s;
  config.correlated_errors = o.correlated_errors;
  if (o.range_correction == "fit") {
    config.range_correction = CorrectionSource::Fit;
  } else if (o.range_correction) {
    config.range_correction = CorrectionSource::Given;
    const std::vector<double> c = parseNumbers(*o.range_correction, 3, "--range-correction", "'fit' or three numbers C0,C1,C2");
    config.given_range_correction.c = Eigen::Vector3d(c[0], c[1], c[2]);
  }
  if (o.command_delay == "fit") {
    config.command_delay = CorrectionSource::Fit;
  } else if (o.command_delay) {
    config.command_delay = CorrectionSource::Given;
    config.given_command_delay_s = parseDelaySeconds(*o.command_delay, "--command-delay");
  }
  if (o.sigma_range_mm > 0) config.sigma_range_mm = o.sigma_range_mm;
  if (o.sigma_bearing_deg > 0) config.sigma_bearing_rad = deg2rad(o.sigma_bearing_deg);
  const MrclamImport imp = importMrclam(o.src_dir, config);
  std::cout << imp.report.summary();
  const Bounds& b = imp.map.bounds();
  std::printf("  map: %zu landmarks (ids = MR.CLAM subjects), bounds x [%.0f, %.0f] y [%.0f, %.0f] mm\n",
              imp.map.landmarks().size(), b.xmin, b.xmax, b.ymin, b.ymax);
  if (o.out_dir.empty()) {
    std::printf("  (no --out: nothing written)\n");
    return;
  }
  Dataset d;
  d.name = imp.name;
  d.map = imp.map;
  d.odometry = imp.odometry;
  d.steps = imp.steps;
  d.groundtruth = imp.groundtruth;
  d.initial_pose = imp.initial_pose;
  d.has_images = false;
  char buf[256];
  std::snprintf(buf, sizeof buf,
                "UTIAS MR.CLAM robot %d imported from %s; t = 0 is Unix time %.3f s; %.1f Hz grid plus measurement "
                "times; monocular barcode camera (the rig is a placeholder)%s",
                o.robot, o.src_dir.c_str(), imp.report.epoch_s, o.rate_hz,
                o.correlated_errors ? "; sigmas inflated for errors correlated over sightings" : "");
  d.description = buf;
  saveDataset(d, o.out_dir, o.force);
  std::printf("  wrote %s (%zu steps)\n", o.out_dir.c_str(), d.steps.size());
}

}  // namespace

void add_import_command(CLI::App& app) {
  CLI::App* imp = app.add_subcommand("import", "Import a third-party dataset into a stereoloc dataset directory");
  imp->require_subcommand(1);

  auto opts = std::make_shared<ImportMrclamOptions>();
  CLI::App* m = imp->add_subcommand(
      "mrclam", "UTIAS MR.CLAM (Barcodes.dat, Landmark_Groundtruth.dat, RobotN_{Odometry,Measurement,Groundtruth}.dat)");
  m->add_option("SRC_DIR", opts->src_dir, "Directory with the MR.CLAM .dat files")->required()->check(CLI::ExistingDirectory);
  m->add_option("--robot", opts->robot, "Robot number (the RobotN_*.dat files)")->required()->check(CLI::Range(1, 5));
  m->add_option("--rate", opts->rate_hz, "Step rate of the fixed grid, Hz (a step is added at every measurement time)")
      ->capture_default_str()
      ->check(CLI::Range(0.1, 1000.0));
  m->add_option("--wheel-base", opts->wheel_base_mm, "Wheel base used to turn (v, omega) into wheel travel, mm")
      ->capture_default_str()
      ->check(positiveNumber());
  m->add_option("--sigma-range", opts->sigma_range_mm, "Range sigma, mm (default: estimated against ground truth)")
      ->check(positiveNumber());
  m->add_option("--sigma-bearing-deg", opts->sigma_bearing_deg,
                "Bearing sigma, degrees (default: estimated against ground truth)")
      ->check(positiveNumber());
  m->add_option("--odometry-noise-scale", opts->odometry_noise_scale,
                "Multiplies the odometry noise fitted against ground truth (k and the x, y control floors)")
      ->capture_default_str()
      ->check(positiveNumber());
  m->add_option("--odometry-window", opts->odometry_window_s,
                "Length of the windows over which the odometry noise is fitted against ground truth, s")
      ->capture_default_str()
      ->check(positiveNumber());
  m->add_option("--range-correction", opts->range_correction,
                 "Divide each range by 1 + C0 + C1 b + C2 b^2 (b the bearing, rad): 'fit' fits C against ground truth "
                 "(printed), or give C0,C1,C2 fitted on another run");
  m->add_option("--command-delay", opts->command_delay,
                "Hold each velocity command from its time + this delay (the drive's latency): 'fit' fits it against "
                "ground truth (printed), or give seconds");
  m->add_flag("--correlated-errors", opts->correlated_errors,
              "Inflate each sighting's sigmas for the correlation of its errors with the previous sightings' "
              "(fitted against ground truth and printed either way)");
  m->add_option("--out", opts->out_dir, "Output dataset directory (default: print the summary only)");
  m->add_flag("--force", opts->force, "Replace an existing non-empty output directory");
  m->callback([opts] { runImportMrclam(*opts); });
}

}  // namespace stereoloc::cli
