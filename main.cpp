#include <opencv2/imgcodecs.hpp>
#include <filesystem>
#include <cstdio>
#include <ctime>
#include "frontend/frontend.h"
#include "src/core/field_map.h"
extern double g_s[8];
using namespace stereoloc; using namespace stereoloc::frontend;
static double now(){timespec t; clock_gettime(CLOCK_MONOTONIC,&t); return t.tv_sec*1e9+t.tv_nsec;}
int main() {
  std::string dir = "/work/wt/fspeed4/data/real";
  FrontendParams prm = FrontendParams::load(dir + "/frontend.yaml");
  Frontend fr(StereoRig::load(dir + "/rig.yaml"), FieldMap::miroSot(), prm);
  std::vector<std::string> names; for (auto& e : std::filesystem::directory_iterator(dir + "/images")) names.push_back(e.path().string());
  std::vector<cv::Mat> lumas; std::vector<std::vector<LineFeature>> L;
  for (auto& n : names) { cv::Mat bgr = cv::imread(n), l; bgrToLuma(bgr, l); lumas.push_back(l);
    FrontendParams p2 = prm; p2.ends.enabled = false; p2.ends.extend_px = 0; Frontend f2(StereoRig::load(dir + "/rig.yaml"), FieldMap::miroSot(), p2);
    const auto& r = f2.detectFeatures(bgr); L.push_back(r.lines); }
  StripeEndScratch sc; int reps = 300; double t0 = now();
  for (int r = 0; r < reps; ++r) for (size_t i = 0; i < L.size(); ++i) { auto lines = L[i]; trimStripeEnds(lumas[i], prm.ends, lines, sc); }
  double t = (now() - t0) / reps / L.size() / 1e3, N = reps * L.size() * 1e3;
  printf("total %.2f us: trim sampling %.2f trim medians %.2f extension %.2f\n", t, g_s[0]/N, g_s[1]/N, g_s[2]/N);
}
