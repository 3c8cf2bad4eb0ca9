// `stereoloc info DIR`: validates a stereoloc dataset and prints a summary.
#include <cmath>
#include <cstdio>
#include <map>
#include <memory>

#include "src/io/dataset.h"
#include "src/pipeline/frontend_source.h"
#include "tools/stereoloc/cli_common.h"

namespace stereoloc::cli {
namespace {

void runInfo(const std::string& dir) {
  const Dataset d = loadDataset(dir);
  const size_t n = d.steps.size();
  std::printf("dataset: %s (%s)\n", dir.c_str(), d.name.c_str());
  if (!d.description.empty()) std::printf("  %s\n", d.description.c_str());
  std::printf("  map: %s, %zu landmarks; rig %dx%d px, f = %.2f px, baseline %.1f mm, pixel sigma %.3g px\n",
              d.map.name().c_str(), d.map.landmarks().size(), d.rig.params().image_width, d.rig.params().image_height,
              d.rig.focal(), d.rig.params().baseline_mm, d.rig.params().pixel_sigma);
  std::printf("  steps: %zu (%ld..%ld), duration %.3f s\n", n, d.steps.front().step, d.steps.back().step,
              d.steps.back().t - d.steps.front().t);
  // Path length: from the ground truth when every step has it, else from the odometry.
  double odo_len = 0, gt_len = 0;
  size_t gt_count = 0;
  for (size_t i = 0; i < n; ++i) {
    odo_len += 0.5 * std::fabs(d.steps[i].d_left + d.steps[i].d_right);
    if (d.groundtruth[i]) ++gt_count;
    if (i > 0 && d.groundtruth[i] && d.groundtruth[i - 1])
      gt_len += (d.groundtruth[i]->translation() - d.groundtruth[i - 1]->translation()).norm();
  }
  std::printf("  path length: %.1f mm (odometry)", odo_len);
  if (gt_count > 0) std::printf(", %.1f mm (ground truth, %zu of %zu steps)", gt_len, gt_count, n);
  std::printf("\n");
  size_t compass = 0, blind = 0, total = 0;
  std::map<int, size_t> per_landmark;
  for (const Step& s : d.steps) {
    compass += s.compass ? 1 : 0;
    blind += s.observations.empty() ? 1 : 0;
    total += s.observations.size();
    for (const Observation& o : s.observations) ++per_landmark[o.landmark_id];
  }
  std::printf("  compass: %zu readings, sigma %.3g deg\n", compass, rad2deg(d.compass_sigma));
  std::printf("  observations: %zu; steps without observations: %zu of %zu\n", total, blind, n);
  for (const auto& [id, count] : per_landmark) {
    const Landmark* l = d.map.find(id);
    std::printf("    landmark %3d %-32s %6zu\n", id, l ? l->name.c_str() : "(unidentified)", count);
  }
  if (d.initial_pose)
    std::printf("  initial pose: [%.1f %.1f %.2f deg]\n", d.initial_pose->x, d.initial_pose->y,
                rad2deg(d.initial_pose->theta));
  if (d.has_images)
    std::printf("  images: %zu stereo pairs, every one readable, %dx%d px\n", checkDatasetImages(d, dir),
                d.rig.params().image_width, d.rig.params().image_height);
  else
    std::printf("  images: none\n");
}

}  // namespace

void add_info_command(CLI::App& app) {
  auto dir = std::make_shared<std::string>();
  CLI::App* sub = app.add_subcommand("info", "Validate a stereoloc dataset (every file, and every image decoded and of the rig's size) and print a summary");
  sub->add_option("DIR", *dir, "Dataset directory")->required();
  sub->callback([dir] { runInfo(*dir); });
}

}  // namespace stereoloc::cli
