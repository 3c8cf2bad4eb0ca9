// bench_pixel_noise: the frontend's stereo pixel errors per feature type, measured on rendered
// pairs against the exact projections (src/pipeline/pixel_noise.h), beside the covariance the
// frontend's parameters give each observation.
//
//   bench_pixel_noise [--pairs=N] [--seed=S] [--noise=GREY] [--params=frontend.yaml] [--scenario=NAME]
//   (--scenario: the poses of that scenario's path, N noisy passes over them, instead of N random poses)
//
// Prints per type: count, mean error, standard deviations and correlations of
// (u_l, v_l, u_r, v_r), the same in (u_l, v, d = u_l - u_r), by range bin (X-intersections also
// split into those located on both images and those that keep the patch match), and the landmarks whose
// mean error stands out (|mean| > 3 standard errors, >= 10 sightings).
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>

#include "frontend/frontend.h"
#include "src/core/field_map.h"
#include "src/core/stereo_rig.h"
#include "src/pipeline/pixel_noise.h"
#include "src/sim/simulator.h"

using namespace stereoloc;

namespace {

// (u_l, v_l, u_r, v_r) -> (u_l, v, d): v the mean row, d the disparity.
Eigen::Matrix<double, 3, 4> toUvd() {
  Eigen::Matrix<double, 3, 4> T;
  T << 1, 0, 0, 0, 0, 0.5, 0, 0.5, 1, 0, -1, 0;
  return T;
}

void printMoments(const char* label, const std::vector<PixelErrorSample>& s, const frontend::FrontendParams& params,
                  LandmarkType type) {
  const PixelErrorMoments m = pixelErrorMoments(s);
  if (m.n < 2) return;
  const Eigen::Vector4d sd = m.covariance.diagonal().cwiseSqrt();
  std::printf("%-16s n=%5ld  mean u_l %+.3f v_l %+.3f u_r %+.3f v_r %+.3f px\n", label, m.n, m.mean[0], m.mean[1],
              m.mean[2], m.mean[3]);
  std::printf("%16s  sd   u_l %.3f v_l %.3f u_r %.3f v_r %.3f px; rms %.3f %.3f %.3f %.3f\n", "", sd[0], sd[1], sd[2],
              sd[3], std::sqrt(m.second(0, 0)), std::sqrt(m.second(1, 1)), std::sqrt(m.second(2, 2)),
              std::sqrt(m.second(3, 3)));
  std::printf("%16s  corr(u_l,u_r) %.3f corr(u_l,v_l) %.3f corr(u_r,v_l) %.3f\n", "",
              m.covariance(0, 2) / (sd[0] * sd[2]), m.covariance(0, 1) / (sd[0] * sd[1]),
              m.covariance(2, 1) / (sd[2] * sd[1]));
  const auto T = toUvd();
  const Eigen::Matrix3d C3 = T * m.second * T.transpose();
  std::printf("%16s  about zero: sigma_u %.3f sigma_v %.3f sigma_d %.3f px, corr(u,d) %.3f corr(u,v) %.3f corr(v,d) %.3f\n",
              "", std::sqrt(C3(0, 0)), std::sqrt(C3(1, 1)), std::sqrt(C3(2, 2)),
              C3(0, 2) / std::sqrt(C3(0, 0) * C3(2, 2)), C3(0, 1) / std::sqrt(C3(0, 0) * C3(1, 1)),
              C3(1, 2) / std::sqrt(C3(1, 1) * C3(2, 2)));
  if (type != LandmarkType::Point) {
    const Eigen::Matrix4d model = params.stereo.pixelCovariance(type);
    const Eigen::Matrix3d M3 = T * model * T.transpose();
    std::printf("%16s  model:      sigma_u %.3f sigma_v %.3f sigma_d %.3f px, corr(u,d) %.3f\n", "",
                std::sqrt(M3(0, 0)), std::sqrt(M3(1, 1)), std::sqrt(M3(2, 2)),
                M3(0, 2) / std::sqrt(M3(0, 0) * M3(2, 2)));
  }
}

}  // namespace

int main(int argc, char** argv) {
  PixelNoiseOptions o;
  std::string params_path, scenario;
  for (int i = 1; i < argc; ++i) {
    if (!std::strncmp(argv[i], "--pairs=", 8)) o.pairs = std::atoi(argv[i] + 8);
    else if (!std::strncmp(argv[i], "--seed=", 7)) o.seed = std::strtoull(argv[i] + 7, nullptr, 10);
    else if (!std::strncmp(argv[i], "--noise=", 8)) o.image_noise = std::atof(argv[i] + 8);
    else if (!std::strncmp(argv[i], "--params=", 9)) params_path = argv[i] + 9;
    else if (!std::strncmp(argv[i], "--scenario=", 11)) scenario = argv[i] + 11;
    else {
      std::fprintf(stderr, "bench_pixel_noise: unknown argument '%s'\n", argv[i]);
      return 2;
    }
  }
  try {
    SimulationTrace trace;
    const Dataset d = simulate(scenario.empty() ? "line" : scenario, 0, SimulationConfig(), 1, &trace);
    if (!scenario.empty()) {
      o.poses = trace.scenario.poses;
      o.head_pans = trace.scenario.head_pan;
    }
    const frontend::FrontendParams params =
        params_path.empty() ? frontend::FrontendParams() : frontend::FrontendParams::load(params_path);
    const auto samples = measurePixelErrors(d.map, d.rig, params, o);
    std::printf("frontend pixel errors: %d %s, seed %llu, sensor noise %.2f grey levels, %zu samples\n", o.pairs,
                scenario.empty() ? "rendered pairs at random poses" : ("passes over the path of " + scenario).c_str(),
                static_cast<unsigned long long>(o.seed), o.image_noise, samples.size());
    for (const auto& [type, s] : samplesByType(samples)) {
      printMoments(toString(type).c_str(), s, params, type);
      const double bins[] = {0, 400, 800, 1200, 1e9};
      for (int b = 0; b < 4; ++b) {
        std::vector<PixelErrorSample> in;
        for (const auto& e : s)
          if (e.range_mm >= bins[b] && e.range_mm < bins[b + 1]) in.push_back(e);
        char label[64];
        std::snprintf(label, sizeof label, "  %.0f-%.0f mm", bins[b], std::min(bins[b + 1], 9999.0));
        printMoments(label, in, params, LandmarkType::Point);
      }
      if (type == LandmarkType::Intersection) {
        // Located on both images (crossingInRightImage) or matched by patch correlation.
        std::vector<PixelErrorSample> located, patch;
        for (const auto& e : s) (e.located_in_both_images ? located : patch).push_back(e);
        printMoments("  located in both", located, params, LandmarkType::Point);
        printMoments("  patch match", patch, params, LandmarkType::Point);
      }
    }
    std::printf("landmarks with a mean error over 3 standard errors (>= 10 sightings):\n");
    for (const auto& [id, s] : samplesByLandmark(samples)) {
      const PixelErrorMoments m = pixelErrorMoments(s);
      if (m.n < 10) continue;
      const Eigen::Vector4d se = (m.covariance.diagonal() / static_cast<double>(m.n)).cwiseSqrt();
      const Eigen::Vector4d z = m.mean.cwiseQuotient(se);
      if (z.cwiseAbs().maxCoeff() < 3) continue;
      std::printf("  %-28s %-15s n=%4ld mean u_l %+.3f v_l %+.3f u_r %+.3f  d %+.3f px (z %+.1f %+.1f %+.1f)\n",
                  d.map.landmarks()[static_cast<size_t>(id)].name.c_str(), toString(s[0].type).c_str(), m.n,
                  m.mean[0], m.mean[1], m.mean[2], m.mean[0] - m.mean[2], z[0], z[1], z[2]);
    }
  } catch (const std::exception& e) {
    std::fprintf(stderr, "bench_pixel_noise: %s\n", e.what());
    return 1;
  }
  return 0;
}
