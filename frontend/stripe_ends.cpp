#include "frontend/stripe_ends.h"

#include <algorithm>
#include <cmath>
#include <utility>

namespace stereoloc::frontend {
namespace {

// Bilinear luma; -1 outside the image. The pixel (x0, y0) and its right and lower neighbours
// must lie in the image: 0 <= x < cols - 1, 0 <= y < rows - 1, where the truncation is the
// floor (std::floor without SSE4.1 costs ten instructions a coordinate; NaN fails too). The
// limits are converted once, and the grey levels are read as floats from a table (the same
// values as converting each byte).
class LumaSampler {
 public:
  explicit LumaSampler(const cv::Mat& g)
      : data_(g.data), step_(g.step[0]), xmax_(g.cols - 1), ymax_(g.rows - 1) {
    for (int v = 0; v < 256; ++v) level_[v] = static_cast<float>(v);
  }
  // Without a branch: a sample outside reads pixel (0, 0) and is then replaced by -1, so the
  // three samples of a position along the line overlap in the pipeline.
  float operator()(double x_in, double y_in) const {
    const bool inside = (x_in >= 0) & (y_in >= 0) & (x_in < xmax_) & (y_in < ymax_);
    const double x = inside ? x_in : 0.0, y = inside ? y_in : 0.0;
    const int x0 = static_cast<int>(x), y0 = static_cast<int>(y);
    const float fx = static_cast<float>(x - x0), fy = static_cast<float>(y - y0);
    const uint8_t* r0 = data_ + static_cast<size_t>(y0) * step_ + x0;
    const uint8_t* r1 = r0 + step_;
    const float v = (1 - fy) * ((1 - fx) * level_[r0[0]] + fx * level_[r0[1]]) +
                    fy * ((1 - fx) * level_[r1[0]] + fx * level_[r1[1]]);
    return inside ? v : -1.0f;
  }
  // The same value for a point known to be inside (0 <= x < cols - 1, 0 <= y < rows - 1).
  float interior(double x, double y) const {
    const int x0 = static_cast<int>(x), y0 = static_cast<int>(y);
    const float fx = static_cast<float>(x - x0), fy = static_cast<float>(y - y0);
    const uint8_t* r0 = data_ + static_cast<size_t>(y0) * step_ + x0;
    const uint8_t* r1 = r0 + step_;
    return (1 - fy) * ((1 - fx) * level_[r0[0]] + fx * level_[r0[1]]) + fy * ((1 - fx) * level_[r1[0]] + fx * level_[r1[1]]);
  }
  // The interval of t over which the points (ax + bx t +- ox, ay + by t +- oy) all lie at least
  // `margin` inside the sampled area (lo > hi: none).
  std::pair<double, double> interval(double ax, double bx, double ox, double ay, double by, double oy, double margin) const {
    return pathBoxInterval(ax, bx, ay, by, margin + std::fabs(ox), margin + std::fabs(oy),
                           xmax_ - margin - std::fabs(ox), ymax_ - margin - std::fabs(oy));
  }

 private:
  const uint8_t* data_;
  size_t step_;
  double xmax_, ymax_;
  float level_[256];
};

// The value std::nth_element would place at k, of the n (at most kSmall) values v: the one
// with fewer than k + 1 values below it and more than k at or below it. The counts are
// branch-free loops the compiler vectorises; nth_element's comparisons of a few unordered
// values mispredict about every other time.
constexpr size_t kSmall = 32;
float selectSmall(const float* v, size_t n, size_t k) {
  for (size_t i = 0; i + 1 < n; ++i) {
    const float x = v[i];
    size_t below = 0, at_or_below = 0;
    for (size_t j = 0; j < n; ++j) {
      below += v[j] < x;
      at_or_below += v[j] <= x;
    }
    if (below <= k && k < at_or_below) return x;
  }
  return v[n - 1];  // the only one left
}

// The value std::nth_element would place at v.size() / 2, for values in [-256, 256) (luma
// samples and their differences). A counting pass over one bin per grey level finds the bin
// holding it, and only that bin's few values are selected from: nth_element's unpredictable
// comparisons over all of them take two fifths of this stage.
float median(const std::vector<float>& v, StripeEndScratch& sc) {
  // An end's reference: clearing the bins would cost more than the select.
  if (v.size() <= kSmall) return selectSmall(v.data(), v.size(), v.size() / 2);
  constexpr int kBins = 512;
  const size_t n = v.size();
  sc.bin.resize(n);
  uint16_t* bins = sc.bin.data();
  int lo = kBins - 1, hi = 0;
  for (size_t i = 0; i < n; ++i) {
    // Monotone in the value, so the bins are ordered as the values are.
    const int b = std::clamp(static_cast<int>(v[i] + 256.0f), 0, kBins - 1);
    bins[i] = static_cast<uint16_t>(b);
    lo = std::min(lo, b);
    hi = std::max(hi, b);
  }
  // Four interleaved tables, cleared between the lowest and highest bin only: a line's values
  // fall into few grey levels, and increments of one counter in a row wait for each other.
  uint32_t c[4][kBins];
  for (auto& t : c) std::fill(t + lo, t + hi + 1, 0u);
  size_t i = 0;
  for (; i + 4 <= n; i += 4) {
    ++c[0][bins[i]];
    ++c[1][bins[i + 1]];
    ++c[2][bins[i + 2]];
    ++c[3][bins[i + 3]];
  }
  for (; i < n; ++i) ++c[0][bins[i]];
  auto count = [&](int bin) { return c[0][bin] + c[1][bin] + c[2][bin] + c[3][bin]; };
  const size_t k = n / 2;
  size_t below = 0;
  int b = lo;
  while (below + count(b) <= k) below += count(b++);
  // The bin's values, without a branch per value (+ 1: a value outside the bin may be written
  // past them).
  sc.pick.resize(count(b) + 1);
  float* pick = sc.pick.data();
  size_t m = 0;
  for (size_t j = 0; j < n; ++j) {
    pick[m] = v[j];
    m += bins[j] == b;
  }
  if (m <= kSmall) return selectSmall(pick, m, k - below);
  const auto mid = sc.pick.begin() + static_cast<std::ptrdiff_t>(k - below);
  std::nth_element(sc.pick.begin(), mid, sc.pick.begin() + static_cast<std::ptrdiff_t>(m));
  return *mid;
}

// A stripe line's samples: the line, its unit normal (nx, ny), the side samples' offset across it
// (px) and the t range [tin0, tin1] whose three samples lie a pixel inside the image.
struct StripeSamples {
  const LumaSampler& luma;
  double nx, ny, off, tin0, tin1;
};

// The trim (StripeEndParams::enabled), on n samples at l.t_min + k: moves an end of l inwards to
// where the stripe is present along the line, judged against the line's median contrast. Its
// samples stay in sc (the extension reuses the first ones). False when the line gives no verdict
// (too few samples, too little contrast, no stripe along it): then it is left as it is and not
// extended either.
bool trimStripe(LineFeature& l, int n, const StripeSamples& ss, const StripeEndParams& prm, StripeEndScratch& sc) {
  const LumaSampler& sampleLuma = ss.luma;
  const double nx = ss.nx, ny = ss.ny, off = ss.off, tin0 = ss.tin0, tin1 = ss.tin1;
  auto& centre = sc.centre;
  auto& dark = sc.dark;
  auto& bright = sc.bright;
  auto& contrast = sc.contrast;
  auto& floor = sc.floor;
  auto& present = sc.present;
  centre.assign(n, -1.0f);
  dark.assign(n, -1.0f);
  bright.assign(n, -1.0f);
  contrast.resize(static_cast<size_t>(n));
  floor.resize(static_cast<size_t>(n));
  size_t judged = 0;
  const double kin0 = std::max(-1.0, std::min(tin0 - l.t_min, static_cast<double>(n)));
  const double kin1 = std::max(-1.0, std::min(tin1 - l.t_min, static_cast<double>(n)));
  for (int k = 0; k < n; ++k) {
    // LineFeature::x/y without 4 trig calls
    const double t = l.t_min + k, x = l.rho * nx - t * ny, y = l.rho * ny + t * nx;
    float c, s1, s2;
    if (k >= kin0 && k <= kin1) {
      c = sampleLuma.interior(x, y);
      s1 = sampleLuma.interior(x + off * nx, y + off * ny);
      s2 = sampleLuma.interior(x - off * nx, y - off * ny);
    } else {
      c = sampleLuma(x, y);
      s1 = sampleLuma(x + off * nx, y + off * ny);
      s2 = sampleLuma(x - off * nx, y - off * ny);
      if (c < 0 || s1 < 0 || s2 < 0) continue;
    }
    centre[k] = c;
    dark[k] = std::min(s1, s2);
    bright[k] = std::max(s1, s2);
    contrast[judged] = c - bright[k];
    floor[judged] = dark[k];
    ++judged;
  }
  contrast.resize(judged);
  floor.resize(judged);
  if (contrast.size() < 4) return false;
  const double c_ref = median(contrast, sc), floor_ref = median(floor, sc);
  if (c_ref < prm.min_contrast) return false;
  const double need = prm.min_fraction * c_ref;
  // Samples outside the image: no verdict, kept. Without a branch per sample (the verdicts
  // along a stripe's ragged end alternate).
  present.resize(static_cast<size_t>(n));
  const double floor_need = floor_ref + need;
  for (int k = 0; k < n; ++k) {
    const float c = centre[k];
    const bool stripe = (static_cast<double>(c - bright[k]) >= need) | (static_cast<double>(c) >= floor_need);
    present[k] = static_cast<uint8_t>(c >= 0 ? stripe : true);
  }
  // First index from an end (step +1 or -1) where the stripe is present twice in a row.
  auto firstRun = [&](int start, int step) {
    for (int k = start; k >= 0 && k + step >= 0 && k < n && k + step < n; k += step)
      if (present[k] && present[k + step]) return k;
    return -1;
  };
  // A piece at an end that is shorter than the gap without the stripe behind it is not the
  // stripe continuing beyond an occluder (a stripe seen past a robot shows more of itself than
  // the robot hides); it is the bright wall or board the line's edge ran into.
  auto dropShortPiece = [&](int k, int step) {
    while (k >= 0) {
      int a = k;
      while (a >= 0 && a < n && present[a]) a += step;
      int b = a;
      while (b >= 0 && b < n && !present[b]) b += step;
      if (b < 0 || b >= n || std::abs(b - a) < prm.min_run_px || std::abs(a - k) >= std::abs(b - a)) return k;
      k = firstRun(b, step);
    }
    return k;
  };
  const int lo = dropShortPiece(firstRun(0, 1), 1), hi = dropShortPiece(firstRun(n - 1, -1), -1);
  if (lo < 0 || hi < 0 || hi - lo < 4) return false;  // no stripe along it to judge the ends by
  // The end goes half a sample outside the first present one: the stripe stops between them.
  const double t0 = l.t_min;
  if (lo >= prm.min_run_px) l.t_min = t0 + lo - 0.5;
  if (n - 1 - hi >= prm.min_run_px) l.t_max = t0 + hi + 0.5;
  return true;
}

// The extension (extend_px >= 1): moves each end of l outwards while the stripe stands out of its
// brighter side by min_fraction of its median contrast near that end. n_trim, t_trim: the trim's
// samples (t_trim + k, k < n_trim, in sc; n_trim 0 without the trim).
void extendStripe(LineFeature& l, const StripeSamples& ss, const StripeEndParams& prm, int n_trim, double t_trim,
                  StripeEndScratch& sc) {
  const LumaSampler& sampleLuma = ss.luma;
  const double nx = ss.nx, ny = ss.ny, off = ss.off, tin0 = ss.tin0, tin1 = ss.tin1;
  const auto& centre = sc.centre;
  const auto& dark = sc.dark;
  const auto& bright = sc.bright;
  auto& contrast = sc.contrast;
  // The stripe's contrast over its brighter side at line coordinate t; -1e9 without a verdict
  // (a sample outside the image).
  auto standOut = [&](double t) {
    const double x = l.rho * nx - t * ny, y = l.rho * ny + t * nx;
    if (t >= tin0 && t <= tin1)
      return static_cast<double>(sampleLuma.interior(x, y) - 0.5f * (sampleLuma.interior(x + off * nx, y + off * ny) +
                                                                     sampleLuma.interior(x - off * nx, y - off * ny)));
    const float c = sampleLuma(x, y), s1 = sampleLuma(x + off * nx, y + off * ny),
                s2 = sampleLuma(x - off * nx, y - off * ny);
    // Near the image border one side may leave the image first: the other side alone judges.
    if (c < 0 || (s1 < 0 && s2 < 0)) return -1e9;
    return static_cast<double>(c - (s1 < 0 ? s2 : s2 < 0 ? s1 : 0.5f * (s1 + s2)));
  };
  for (int e = 0; e < 2; ++e) {
    const double te = e ? l.t_max : l.t_min, out = e ? 1.0 : -1.0;
    const int nref = static_cast<int>(std::min(prm.extend_ref_px, l.t_max - l.t_min));
    // A start the trim left in place has its reference samples at the trim's first positions
    // (te + k is t_trim + k): those with all three samples inside are taken from there (the
    // two sides' mean is the same sum of the same two values).
    const bool reuse = !e && n_trim > 0 && te == t_trim;
    contrast.clear();
    for (int k = 0; k <= nref; ++k) {
      const double c = reuse && k < n_trim && centre[k] >= 0
                           ? static_cast<double>(centre[k] - 0.5f * (dark[k] + bright[k]))
                           : standOut(te - out * k);
      if (c > -1e8) contrast.push_back(static_cast<float>(c));
    }
    if (contrast.size() < 4) continue;
    const double ref = median(contrast, sc);
    if (ref < prm.min_contrast) continue;
    const double need = prm.min_fraction * ref;
    int last = 0, missing = 0;
    for (int k = 1; k <= static_cast<int>(prm.extend_px); ++k) {
      const double c = standOut(te + out * k);
      if (c < -1e8) break;  // the image border: snapLineEnds takes an end near it onto it
      if (c >= need) {
        last = k;
        missing = 0;
      } else if (++missing >= prm.min_run_px) {
        break;
      }
    }
    if (last == 0) continue;
    if (e)
      l.t_max = te + last + 0.5;
    else
      l.t_min = te - last - 0.5;
  }
}

}  // namespace

void trimStripeEnds(const cv::Mat& luma, const StripeEndParams& prm, std::vector<LineFeature>& lines,
                    StripeEndScratch& sc) {
  const bool extend = prm.extend_px >= 1.0;
  if (!prm.enabled && !extend) return;
  // No bilinear sample fits in an image narrower or lower than 2 px: nothing to judge (and the
  // sampler reads pixel (0, 0) and its neighbours for samples outside).
  if (luma.cols < 2 || luma.rows < 2) return;
  const LumaSampler sampleLuma(luma);
  for (LineFeature& l : lines) {
    if (!l.marking || l.t_max - l.t_min < 4.0) continue;
    const double nx = std::cos(l.theta), ny = std::sin(l.theta);
    const double off = 0.5 * l.width + prm.side_px;
    // Positions t whose three samples lie a pixel inside the image skip the sampler's test.
    const auto [tin0, tin1] = sampleLuma.interval(l.rho * nx, -ny, off * nx, l.rho * ny, nx, off * ny, 1.0);
    const StripeSamples ss{sampleLuma, nx, ny, off, tin0, tin1};
    // The trim's samples lie at t_trim + k, k < n_trim (none without the trim).
    int n_trim = 0;
    double t_trim = 0.0;
    if (prm.enabled) {
      n_trim = static_cast<int>(std::floor(l.t_max - l.t_min)) + 1;
      t_trim = l.t_min;
      if (!trimStripe(l, n_trim, ss, prm, sc)) continue;
    }
    if (extend) extendStripe(l, ss, prm, n_trim, t_trim, sc);
  }
}

}  // namespace stereoloc::frontend
