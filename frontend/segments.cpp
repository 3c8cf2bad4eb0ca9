#include "frontend/segments.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>

namespace stereoloc::frontend {

namespace {
// Margins of a peak's pixel pool beyond the first collection's band and bin range: refits move
// the line by a pixel or two and a degree or so (a speed setting only; see collect()).
constexpr double kPoolMarginPx = 4.0;
constexpr int kPoolMarginBins = 2;

// Sorts (t, index) pairs as std::sort would (by t, then index), on one 64-bit key per pair:
// the float's bits made monotonic in the high half, the index in the low half. Comparing
// pairs branched twice per comparison. The keys are unique, so every correct sort gives this
// order: a bucket sort (about one pair per bucket of equal width in t; the bucket a monotone
// function of t, so the buckets order as the keys do) and a sort of each bucket's few keys
// take a third of std::sort's time over all keys, whose comparisons mispredict at random.
void sortByPosition(std::vector<std::pair<float, int>>& v, std::vector<uint64_t>& keys, std::vector<uint64_t>& sorted,
                    std::vector<int>& start) {
  const size_t n = v.size();
  keys.resize(n);
  float tmin = 0.0f, tmax = 0.0f;
  bool finite = true;
  for (size_t k = 0; k < n; ++k) {
    uint32_t u;
    const float t = v[k].first + 0.0f;  // -0 -> +0: they compare equal as floats
    std::memcpy(&u, &t, sizeof u);
    u = (u & 0x80000000u) ? ~u : (u | 0x80000000u);
    keys[k] = (uint64_t{u} << 32) | static_cast<uint32_t>(v[k].second);
    tmin = k ? std::min(tmin, t) : t;
    tmax = k ? std::max(tmax, t) : t;
    finite = finite && std::isfinite(t);
  }
  const float span = tmax - tmin;
  if (n < 16 || !finite || !(span > 0.0f) || !std::isfinite(span)) {
    std::sort(keys.begin(), keys.end());
  } else {
    const int nb = static_cast<int>(n);
    const float scale = static_cast<float>(nb - 1) / span;
    // Monotone in t: a subtraction, a multiplication by a positive number and a truncation of
    // values in [0, nb - 1] (the minimum guards a rounding up at the top).
    auto bucketOf = [&](float t) { return std::min(static_cast<int>((t + 0.0f - tmin) * scale), nb - 1); };
    start.assign(static_cast<size_t>(nb) + 1, 0);
    for (size_t k = 0; k < n; ++k) ++start[static_cast<size_t>(bucketOf(v[k].first)) + 1];
    for (int b = 0; b < nb; ++b) start[b + 1] += start[b];
    sorted.resize(n);
    for (size_t k = 0; k < n; ++k) sorted[static_cast<size_t>(start[bucketOf(v[k].first)]++)] = keys[k];
    // start[b] is now the end of bucket b.
    size_t b0 = 0;
    for (int b = 0; b < nb; ++b) {
      const size_t b1 = static_cast<size_t>(start[b]);
      if (b1 - b0 > 16) {
        std::sort(sorted.begin() + static_cast<std::ptrdiff_t>(b0), sorted.begin() + static_cast<std::ptrdiff_t>(b1));
      } else {
        for (size_t i = b0 + 1; i < b1; ++i) {
          const uint64_t key = sorted[i];
          size_t j = i;
          for (; j > b0 && sorted[j - 1] > key; --j) sorted[j] = sorted[j - 1];
          sorted[j] = key;
        }
      }
      b0 = b1;
    }
    keys.swap(sorted);
  }
  for (size_t k = 0; k < n; ++k) {
    uint32_t u = static_cast<uint32_t>(keys[k] >> 32);
    u = (u & 0x80000000u) ? (u & 0x7fffffffu) : ~u;
    float t;
    std::memcpy(&t, &u, sizeof t);
    v[k] = {t, static_cast<int>(keys[k] & 0xffffffffu)};
  }
}
}  // namespace

bool fitLine(const std::vector<EdgePixel>& edges, const int* begin, const int* end, double theta_hint, double& theta,
             double& rho, double* rms) {
  const long n = end - begin;
  if (n < 2) return false;
  double mx = 0, my = 0;
  for (const int* p = begin; p != end; ++p) {
    mx += edges[*p].x;
    my += edges[*p].y;
  }
  mx /= n;
  my /= n;
  double sxx = 0, sxy = 0, syy = 0;
  for (const int* p = begin; p != end; ++p) {
    const double dx = edges[*p].x - mx, dy = edges[*p].y - my;
    sxx += dx * dx;
    sxy += dx * dy;
    syy += dy * dy;
  }
  // Direction of the largest spread; the normal is perpendicular to it.
  const double phi = 0.5 * std::atan2(2.0 * sxy, sxx - syy);
  if (sxx + syy <= 0) return false;
  double nx = -std::sin(phi), ny = std::cos(phi);
  if (nx * std::cos(theta_hint) + ny * std::sin(theta_hint) < 0) {
    nx = -nx;
    ny = -ny;
  }
  theta = std::atan2(ny, nx);
  if (theta < 0) theta += kTwoPi;
  rho = nx * mx + ny * my;
  if (rms) {
    double s = 0;
    for (const int* p = begin; p != end; ++p) {
      const double d = nx * edges[*p].x + ny * edges[*p].y - rho;
      s += d * d;
    }
    *rms = std::sqrt(s / n);
  }
  return true;
}

namespace {
double bilinearLuma(const cv::Mat& img, double x, double y) {
  const int x0 = static_cast<int>(std::floor(x)), y0 = static_cast<int>(std::floor(y));
  if (x0 < 0 || y0 < 0 || x0 + 1 >= img.cols || y0 + 1 >= img.rows) return -1.0;
  const double fx = x - x0, fy = y - y0;
  const uint8_t* r0 = img.ptr<uint8_t>(y0);
  const uint8_t* r1 = img.ptr<uint8_t>(y0 + 1);
  return (1 - fy) * ((1 - fx) * r0[x0] + fx * r0[x0 + 1]) + fy * ((1 - fx) * r1[x0] + fx * r1[x0 + 1]);
}

// A segment's end points: the extreme projections of its pixels [begin, end) onto its fitted
// line (x cos theta + y sin theta = rho, t along (-sin, cos)); also its pixel count.
void setExtent(const std::vector<EdgePixel>& edges, const int* begin, const int* end, Segment& seg) {
  const double cs = std::cos(seg.theta), sn = std::sin(seg.theta);
  double tmin = 1e30, tmax = -1e30;
  for (const int* q = begin; q != end; ++q) {
    const double t = -edges[*q].x * sn + edges[*q].y * cs;
    tmin = std::min(tmin, t);
    tmax = std::max(tmax, t);
  }
  seg.x1 = seg.rho * cs - tmin * sn;
  seg.y1 = seg.rho * sn + tmin * cs;
  seg.x2 = seg.rho * cs - tmax * sn;
  seg.y2 = seg.rho * sn + tmax * cs;
  seg.pixels = static_cast<int>(end - begin);
}
}  // namespace

void refineEndpoints(const cv::Mat& luma, std::vector<Segment>& segments) {
  constexpr double kSide = 1.5, kStep = 0.25;
  for (Segment& s : segments) {
    const double c = std::cos(s.theta), sn = std::sin(s.theta);
    auto contrast = [&](double x, double y) {
      const double hi = bilinearLuma(luma, x + kSide * c, y + kSide * sn);
      const double lo = bilinearLuma(luma, x - kSide * c, y - kSide * sn);
      return (hi < 0 || lo < 0) ? -1.0 : hi - lo;
    };
    const double len = s.length();
    if (len < 8) continue;
    const double dx = (s.x2 - s.x1) / len, dy = (s.y2 - s.y1) / len;
    const double ref = contrast(0.5 * (s.x1 + s.x2), 0.5 * (s.y1 + s.y2));
    if (!(ref > 0)) continue;
    for (int end = 0; end < 2; ++end) {
      const double ex = end ? s.x2 : s.x1, ey = end ? s.y2 : s.y1;
      const double ox = end ? dx : -dx, oy = end ? dy : -dy;  // outwards
      double prev_t = -2.0, prev_c = contrast(ex - 2.0 * ox, ey - 2.0 * oy);
      if (prev_c < 0.5 * ref) continue;
      for (double t = -2.0 + kStep; t <= 4.0; t += kStep) {
        const double ct = contrast(ex + t * ox, ey + t * oy);
        if (ct < 0) {
          // The step still holds where the samples leave the image: the edge runs on to the
          // image border (-0.5 or size - 0.5), where the renderer's truth clips it too.
          double tb = 1e9;
          if (ox > 1e-9) tb = std::min(tb, (luma.cols - 0.5 - ex) / ox);
          if (ox < -1e-9) tb = std::min(tb, (-0.5 - ex) / ox);
          if (oy > 1e-9) tb = std::min(tb, (luma.rows - 0.5 - ey) / oy);
          if (oy < -1e-9) tb = std::min(tb, (-0.5 - ey) / oy);
          if (tb < 6.0) {
            if (end) {
              s.x2 = ex + tb * ox;
              s.y2 = ey + tb * oy;
            } else {
              s.x1 = ex + tb * ox;
              s.y1 = ey + tb * oy;
            }
          }
          break;
        }
        if (ct < 0.5 * ref) {
          const double tt = prev_t + kStep * (prev_c - 0.5 * ref) / (prev_c - ct);
          if (end) {
            s.x2 = ex + tt * ox;
            s.y2 = ey + tt * oy;
          } else {
            s.x1 = ex + tt * ox;
            s.y1 = ey + tt * oy;
          }
          break;
        }
        prev_t = t;
        prev_c = ct;
      }
    }
  }
}

void splitAtBends(const std::vector<EdgePixel>& edges, const int* begin, const int* end, double theta, double bin_px,
                  double tol_px, std::vector<int>& cuts, double step_px, double tail_px) {
  BendScratch scratch;
  splitAtBends(edges, begin, end, theta, bin_px, tol_px, cuts, scratch, step_px, tail_px);
}

namespace {

// The pixels [begin, end) binned along the line (t = along, d = across; cos c, sin s of its
// normal), bin_px long: each bin's mean (t, d) and its first pixel, in scratch.bins.
void binAlongLine(const std::vector<EdgePixel>& edges, const int* begin, int n, double c, double s, double bin_px,
                  BendScratch& scratch) {
  // Bins along t: mean (t, d) and the index of their first pixel.
  std::vector<BendScratch::Bin>& bins = scratch.bins;
  bins.clear();
  const double t0 = -edges[begin[0]].x * s + edges[begin[0]].y * c;
  int k = 0;
  // (t of each pixel computed once: the binning was a third of this function's cost.)
  double tk = t0;
  while (k < n) {
    const int b = static_cast<int>((tk - t0) / bin_px);
    double st = 0, sd = 0;
    int m = 0;
    const int first = k;
    while (true) {
      const EdgePixel& e = edges[begin[k]];
      st += tk;
      sd += e.x * c + e.y * s;
      ++m;
      if (++k == n) break;
      tk = -edges[begin[k]].x * s + edges[begin[k]].y * c;
      if (static_cast<int>((tk - t0) / bin_px) != b) break;
    }
    bins.push_back(BendScratch::Bin{st / m, sd / m, first});
  }
}

// Douglas-Peucker on the bin means (an explicit stack; kept vertices are the cuts): marks the
// kept bins in scratch.keep and lists in scratch.runs the final runs [first bin, end bin) that
// the step test must look at (guard: the smaller of the step and tail thresholds in use, 0 for
// neither test).
void douglasPeucker(double tol_px, double guard, BendScratch& scratch) {
  const std::vector<BendScratch::Bin>& bins = scratch.bins;
  std::vector<uint8_t>& keep = scratch.keep;
  keep.assign(bins.size(), 0);
  std::vector<std::pair<int, int>>& stack = scratch.stack;
  stack.assign(1, {0, static_cast<int>(bins.size()) - 1});
  scratch.runs.clear();  // DP's final runs [first bin, end bin) that the step test looks at
  while (!stack.empty()) {
    const auto [a, b] = stack.back();
    stack.pop_back();
    if (b - a < 2) continue;
    const double dt = bins[b].t - bins[a].t, dd = bins[b].d - bins[a].d, len = std::hypot(dt, dd);
    if (!(len > 0)) continue;
    double worst = 0;
    int at = -1;
    for (int i = a + 1; i < b; ++i) {
      const double dist = std::fabs(dt * (bins[i].d - bins[a].d) - dd * (bins[i].t - bins[a].t)) / len;
      if (dist > worst) {
        worst = dist;
        at = i;
      }
    }
    if (worst <= tol_px || at < 0) {
      // A final run. The step test below only looks at runs whose bins leave the chord by
      // more than step_px / 4: the bins beside a step h lie at least h / 2 off the chord
      // (max(f, 1 - f) h for a step at the fraction f), so straighter runs (nearly all, and
      // the test's cost) hold none; likewise a bend with a tail off by tail_px. Run [a, b) for the test; the last one includes bin b.
      if (guard > 0 && worst > 0.25 * guard && b - a + 1 >= 6)
        scratch.runs.push_back({a, b + 1 == static_cast<int>(bins.size()) ? b + 1 : b});
      continue;
    }
    keep[at] = 1;
    stack.push_back({a, at});
    stack.push_back({at, b});
  }
}

// Marks in scratch.keep the steps and bend tails DP does not see, in the runs it listed.
void markSteps(double step_px, double tail_px, BendScratch& scratch) {
  const std::vector<BendScratch::Bin>& bins = scratch.bins;
  std::vector<std::pair<int, int>>& stack = scratch.stack;
  // Steps DP does not see: a step near one end of a run deviates from the chord between the
  // run's end bins by only (1 - f) h for a step h at the fraction f of the run, and the chord
  // of a stepped pair (a far wall foot and a goal foot 2 px behind it, often with a gap where
  // the weak goal foot has no pixels) passed within 1 px of every bin. So each DP run is also
  // tested as two lines: the split between bins that leaves the least squared residual of
  // two lines d(t) fitted to the bin means, accepted when the two lines are more than step_px
  // apart midway between the bins at the split (a bend meets there with no offset),
  // and repeated on both parts. Prefix sums keep it linear in the bins per test.
  const int nb = static_cast<int>(bins.size());
  std::vector<double>& ps = scratch.sums;
  ps.assign(static_cast<size_t>(5 * (nb + 1)), 0.0);  // prefix sums of 1, t, d, tt, td
  const double tref = bins[0].t;
  for (int i = 0; i < nb; ++i) {
    const double t = bins[i].t - tref, d = bins[i].d;
    double* q = &ps[static_cast<size_t>(5 * i)];
    q[5] = q[0] + 1;
    q[6] = q[1] + t;
    q[7] = q[2] + d;
    q[8] = q[3] + t * t;
    q[9] = q[4] + t * d;
  }
  // Least-squares line d = a + b t over bins [i, j); its squared residual needs dd too, but
  // comparing splits only needs sum d^2 - (explained part), and sum d^2 is the same for every
  // split of one run, so the explained part is maximised instead.
  auto fit = [&](int i, int j, double& a, double& b) {
    const double* p = &ps[static_cast<size_t>(5 * i)];
    const double* r = &ps[static_cast<size_t>(5 * j)];
    const double m = r[0] - p[0], st = r[1] - p[1], sd = r[2] - p[2], stt = r[3] - p[3], std_ = r[4] - p[4];
    const double den = m * stt - st * st;
    b = den > 1e-9 ? (m * std_ - st * sd) / den : 0.0;
    a = (sd - b * st) / m;
    return a * sd + b * std_;  // explained: sum d^2 minus the residual
  };
  constexpr int kMinBins = 3;                   // each side: a line through fewer bin means is not a line
  std::vector<uint8_t>& cut_at = scratch.keep;  // DP's cuts, then the steps
  stack.swap(scratch.runs);
  while (!stack.empty()) {
    const auto [a, b] = stack.back();
    stack.pop_back();
    if (b - a < 2 * kMinBins) continue;
    double best = -1e300;
    int at = -1;
    for (int s2 = a + kMinBins; s2 + kMinBins <= b; ++s2) {
      double a1, b1, a2, b2;
      const double e = fit(a, s2, a1, b1) + fit(s2, b, a2, b2);
      if (e > best) {
        best = e;
        at = s2;
      }
    }
    if (at < 0) continue;
    double a1, b1, a2, b2;
    fit(a, at, a1, b1);
    fit(at, b, a2, b2);
    const double tm = 0.5 * (bins[at - 1].t + bins[at].t) - tref;
    bool split = step_px > 0 && std::fabs(a1 + b1 * tm - a2 - b2 * tm) > step_px;
    if (!split && tail_px > 0) {
      // The shorter side's outer bin against the longer side's line, extended: the tail of a
      // bend, which leaves DP's chord by only half as much in the middle of a run.
      const bool first_short = at - a < b - at;
      const double to = (first_short ? bins[a].t : bins[b - 1].t) - tref;
      const double dev = first_short ? a1 + b1 * to - a2 - b2 * to : a2 + b2 * to - a1 - b1 * to;
      split = std::fabs(dev) > tail_px;
    }
    if (!split) continue;
    cut_at[at] = 1;
    stack.push_back({a, at});
    stack.push_back({at, b});
  }
}

// Moves each inner cut of the pixels at `begin` to where the runs beside it explain them best.
void refineCuts(const std::vector<EdgePixel>& edges, const int* begin, double theta, double c, double s, double bin_px,
                std::vector<int>& cuts) {
  // The polyline vertex is only bin-accurate, and at a shallow bend a bin error is several px
  // along the line: move each cut to where the two runs' own lines explain the pixels best
  // (least total |residual|, lines fitted away from the cut, search within +-2 bins).
  for (size_t ci = 1; ci + 1 < cuts.size(); ++ci) {
    const int lo = cuts[ci - 1], mid = cuts[ci], hi = cuts[ci + 1];
    auto tOf = [&](int q) { return -edges[begin[q]].x * s + edges[begin[q]].y * c; };
    const double t_mid = tOf(mid);
    int a_end = mid, b_start = mid;
    while (a_end > lo && tOf(a_end - 1) > t_mid - 2 * bin_px) --a_end;
    while (b_start < hi && tOf(b_start) < t_mid + 2 * bin_px) ++b_start;
    double tha, rha, thb, rhb;
    if (a_end - lo < 4 || hi - b_start < 4 || !fitLine(edges, begin + lo, begin + a_end, theta, tha, rha) ||
        !fitLine(edges, begin + b_start, begin + hi, theta, thb, rhb))
      continue;
    // (cos and sin once per line, not per pixel: with errno semantics the compiler keeps the calls.)
    const double ca = std::cos(tha), sa = std::sin(tha), cb = std::cos(thb), sb = std::sin(thb);
    auto res = [&](int q, double cth, double sth, double rh) {
      return std::fabs(edges[begin[q]].x * cth + edges[begin[q]].y * sth - rh);
    };
    // cost(k) = sum_{a_end <= j < k} resA(j) + sum_{k <= j < b_start} resB(j)
    double cost = 0;
    for (int j = a_end; j < b_start; ++j) cost += res(j, cb, sb, rhb);
    double best = cost;
    int at = a_end;
    for (int q = a_end; q < b_start; ++q) {
      cost += res(q, ca, sa, rha) - res(q, cb, sb, rhb);
      if (cost < best) {
        best = cost;
        at = q + 1;
      }
    }
    cuts[ci] = at;
  }
}

}  // namespace

void splitAtBends(const std::vector<EdgePixel>& edges, const int* begin, const int* end, double theta, double bin_px,
                  double tol_px, std::vector<int>& cuts, BendScratch& scratch, double step_px, double tail_px) {
  const int n = static_cast<int>(end - begin);
  cuts.clear();
  cuts.push_back(0);
  if (n < 4 || !(bin_px > 0)) {
    cuts.push_back(n);
    return;
  }
  const double c = std::cos(theta), s = std::sin(theta);
  binAlongLine(edges, begin, n, c, s, bin_px, scratch);
  // The smaller of the step and tail thresholds in use (0: neither test).
  const double guard = step_px > 0 && tail_px > 0 ? std::min(step_px, tail_px) : std::max(step_px, tail_px);
  douglasPeucker(tol_px, guard, scratch);
  if (!scratch.runs.empty()) markSteps(step_px, tail_px, scratch);
  const std::vector<BendScratch::Bin>& bins = scratch.bins;
  for (size_t i = 1; i + 1 < bins.size(); ++i)
    if (scratch.keep[i]) cuts.push_back(bins[i].first);
  cuts.push_back(n);
  refineCuts(edges, begin, theta, c, s, bin_px, cuts);
}

void SegmentExtractor::collect(const std::vector<EdgePixel>& edges, const std::vector<uint8_t>& used, double theta,
                               double rho, double band, int tol_bins) {
  cand_.clear();
  const double c = std::cos(theta), s = std::sin(theta);
  const int b0 = static_cast<int>(std::lround(theta * 360.0 / kTwoPi));
  // From the peak's pool when it provably holds every pixel this collect can find: the bins
  // [b0 - tol_bins, b0 + tol_bins] lie in the pool's, and every point of the edge-pixel box
  // within `band` of this line lies within the pool's band of the peak's line. The difference
  // of the two distances is linear in the point, so its largest magnitude over that strip is
  // at the ends of this line clipped to the box grown by `band`, plus band |n - n_pool|. The
  // pool keeps the bucket order, so cand_ comes out in the same order as from the buckets.
  if (pool_valid_) {
    int delta = b0 - pool_b0_;
    delta = ((delta % 360) + 540) % 360 - 180;
    if (std::abs(delta) + tol_bins <= pool_tol_bins_) {
      const double pc = std::cos(pool_theta_), ps = std::sin(pool_theta_);
      const double x0 = box_[0] - band, y0 = box_[1] - band, x1 = box_[2] + band, y1 = box_[3] + band;
      // Line points (rho c - t s, rho s + t c); t clipped to the grown box.
      const auto [lo, hi] = lineBoxInterval(rho, theta, x0, y0, x1, y1);
      double worst = 0;
      if (lo <= hi)
        for (double t : {lo, hi}) {
          const double x = rho * c - t * s, y = rho * s + t * c;
          worst = std::max(worst, std::fabs(x * pc + y * ps - pool_rho_));  // its own distance is 0
        }
      worst += band * std::hypot(c - pc, s - ps);
      if (worst + band <= pool_band_) {
        const int g0 = delta - tol_bins + pool_tol_bins_, g1 = delta + tol_bins + pool_tol_bins_ + 1;
        if (reference_pools_) {
          for (int j = pool_off_[g0]; j < pool_off_[g1]; ++j) {
            const int i = pool_[j];
            if (used[i]) continue;
            const double d = edges[i].x * c + edges[i].y * s - rho;
            if (std::fabs(d) <= band) cand_.push_back(i);
          }
        } else {
          // Branch-free, as in fillPool().
          const int j0 = pool_off_[g0], j1 = pool_off_[g1];
          cand_.resize(static_cast<size_t>(j1 - j0));
          int* out = cand_.data();
          const int* items = pool_.data();
          const float* px = pool_x_.data();
          const float* py = pool_y_.data();
          const uint8_t* u = used.data();
          size_t m = 0;
          for (int j = j0; j < j1; ++j) {
            const int i = items[j];
            const double d = px[j] * c + py[j] * s - rho;
            out[m] = i;
            m += static_cast<size_t>((std::fabs(d) <= band) & (u[i] == 0));
          }
          cand_.resize(m);
        }
        return;
      }
    }
  }
  // Not covered: re-centre the pool on this line (a refit moved it), which the next refits of
  // the line, close to this one, will hit.
  fillPool(edges, used, theta, rho, band + kPoolMarginPx, tol_bins + kPoolMarginBins);
  const int j0 = pool_off_[kPoolMarginBins], j1 = pool_off_[kPoolMarginBins + 2 * tol_bins + 1];
  if (reference_pools_) {
    for (int j = j0; j < j1; ++j) {
      const int i = pool_[j];
      const double d = edges[i].x * c + edges[i].y * s - rho;
      if (std::fabs(d) <= band) cand_.push_back(i);
    }
    return;
  }
  cand_.resize(static_cast<size_t>(j1 - j0));
  size_t m = 0;
  for (int j = j0; j < j1; ++j) {
    const double d = pool_x_[j] * c + pool_y_[j] * s - rho;
    cand_[m] = pool_[j];
    m += static_cast<size_t>(std::fabs(d) <= band);
  }
  cand_.resize(m);
}

void SegmentExtractor::fillPool(const std::vector<EdgePixel>& edges, const std::vector<uint8_t>& used, double theta,
                                double rho, double band, int tol_bins) {
  pool_valid_ = false;
  pool_.clear();
  pool_x_.clear();
  pool_y_.clear();
  pool_off_.assign(1, 0);
  const double c = std::cos(theta), s = std::sin(theta);
  const int b0 = static_cast<int>(std::lround(theta * 360.0 / kTwoPi));
  for (int k = b0 - tol_bins; k <= b0 + tol_bins; ++k) {
    const int b = ((k % 360) + 360) % 360;
    const int j0 = bucket_start_[b], j1 = bucket_start_[b + 1];
    if (reference_pools_) {
      for (int j = j0; j < j1; ++j) {
        const int i = bucket_items_[j];
        if (used[i]) continue;  // never cleared again within extract()
        const double d = edges[i].x * c + edges[i].y * s - rho;
        if (std::fabs(d) <= band) pool_.push_back(i);
      }
    } else {
      // The same test without a branch per pixel: on photographs the carpet's texture edges
      // fill the bins of every direction, a pool keeps about one pixel in six, and the
      // mispredicted branches of the pixel-by-pixel loop were most of the segment stage's
      // excess over rendered images.
      const size_t n = pool_.size();
      pool_.resize(n + static_cast<size_t>(j1 - j0));
      pool_x_.resize(pool_.size());
      pool_y_.resize(pool_.size());
      int* out = pool_.data() + n;
      float* ox = pool_x_.data() + n;
      float* oy = pool_y_.data() + n;
      const int* items = bucket_items_.data();
      const float* bx = bucket_x_.data();
      const float* by = bucket_y_.data();
      const uint8_t* u = used.data();
      size_t m = 0;
      for (int j = j0; j < j1; ++j) {
        const int i = items[j];
        const double d = bx[j] * c + by[j] * s - rho;
        out[m] = i;
        ox[m] = bx[j];
        oy[m] = by[j];
        m += static_cast<size_t>((std::fabs(d) <= band) & (u[i] == 0));
      }
      pool_.resize(n + m);
      pool_x_.resize(n + m);
      pool_y_.resize(n + m);
    }
    pool_off_.push_back(static_cast<int>(pool_.size()));
  }
  pool_theta_ = theta;
  pool_rho_ = rho;
  pool_band_ = band;
  pool_b0_ = b0;
  pool_tol_bins_ = tol_bins;
  pool_valid_ = true;
}

// Length beyond an end pixel (x, y) up to the image border along (dx, dy), when it is within
// the unobserved frame of `frame` px (see segments.h), else 0; none for an unknown image size.
struct SegmentExtractor::BorderCredit {
  int width = 0, height = 0;
  double frame = 0;
  double operator()(double x, double y, double dx, double dy) const {
    if (width <= 0 || height <= 0) return 0.0;
    double t = 1e30;
    if (dx > 1e-9) t = std::min(t, (width - 0.5 - x) / dx);
    if (dx < -1e-9) t = std::min(t, (-0.5 - x) / dx);
    if (dy > 1e-9) t = std::min(t, (height - 0.5 - y) / dy);
    if (dy < -1e-9) t = std::min(t, (-0.5 - y) / dy);
    return t <= frame ? std::max(0.0, t) : 0.0;
  }
};

void SegmentExtractor::bucketByDirection(const std::vector<EdgePixel>& edges) {
  // Counting sort of the edge pixels by direction bin, so a peak only looks at pixels of
  // nearly its own direction.
  bucket_start_.assign(361, 0);
  for (const EdgePixel& e : edges) ++bucket_start_[e.dir_bin + 1];
  for (int b = 0; b < 360; ++b) bucket_start_[b + 1] += bucket_start_[b];
  bucket_items_.resize(edges.size());
  {
    std::vector<int>& fill = cand_;
    fill.assign(bucket_start_.begin(), bucket_start_.end() - 1);
    for (size_t i = 0; i < edges.size(); ++i) bucket_items_[fill[edges[i].dir_bin]++] = static_cast<int>(i);
  }
  bucket_x_.resize(edges.size());
  bucket_y_.resize(edges.size());
  for (size_t j = 0; j < edges.size(); ++j) {
    bucket_x_[j] = edges[bucket_items_[j]].x;
    bucket_y_[j] = edges[bucket_items_[j]].y;
  }
  // Bounding box of the edge pixels (for the pool test in collect()).
  box_[0] = box_[1] = 1e30;
  box_[2] = box_[3] = -1e30;
  for (const EdgePixel& e : edges) {
    box_[0] = std::min<double>(box_[0], e.x);
    box_[1] = std::min<double>(box_[1], e.y);
    box_[2] = std::max<double>(box_[2], e.x);
    box_[3] = std::max<double>(box_[3], e.y);
  }
}

bool SegmentExtractor::seedLongestRun(const std::vector<EdgePixel>& edges, double theta, const SegmentParams& prm) {
  const double c = std::cos(theta), s = std::sin(theta);
  proj_.clear();
  for (int i : cand_) proj_.emplace_back(static_cast<float>(-edges[i].x * s + edges[i].y * c), i);
  sortByPosition(proj_, keys_, sorted_keys_, key_start_);
  size_t best_b = 0, best_e = proj_.size(), b = 0;
  double best_len = -1;
  for (size_t k = 1; k <= proj_.size(); ++k)
    if (k == proj_.size() || proj_[k].first - proj_[k - 1].first > prm.gap_min_px) {
      if (proj_[k - 1].first - proj_[b].first > best_len) {
        best_len = proj_[k - 1].first - proj_[b].first;
        best_b = b;
        best_e = k;
      }
      b = k;
    }
  if (best_len < prm.min_piece_px) return false;
  seed_.clear();
  for (size_t k = best_b; k < best_e; ++k) seed_.push_back(proj_[k].second);
  return true;
}

bool SegmentExtractor::densestBand(const std::vector<EdgePixel>& edges, double theta, double rho, double rho_step_px,
                                   const SegmentParams& prm, double* shift) {
  const double bin = 0.5 * prm.band_px, c = std::cos(theta), s = std::sin(theta);
  const double reach = 0.5 * rho_step_px + 2.0;
  const int nb = static_cast<int>(std::ceil(2 * reach / bin)) + 1;
  hist_.assign(static_cast<size_t>(nb), 0);
  for (int i : cand_) {
    const int b = static_cast<int>((edges[i].x * c + edges[i].y * s - rho + reach) / bin);
    if (b >= 0 && b < nb) ++hist_[static_cast<size_t>(b)];
  }
  int best = -1, best_n = 0;
  for (int b = 0; b + 3 < nb; ++b) {
    const int n = hist_[b] + hist_[b + 1] + hist_[b + 2] + hist_[b + 3];
    if (n > best_n) {
      best_n = n;
      best = b;
    }
  }
  if (best < 0) return false;
  *shift = (best + 2) * bin - reach;
  return true;
}

bool SegmentExtractor::lineMembers(const std::vector<EdgePixel>& edges, std::vector<uint8_t>& used, double theta,
                                   double c, double s, double rho, double tol_cos, double min_pixels,
                                   const SegmentParams& prm) {
  // Direction check against the refitted line (the buckets are +-1 bin coarse).
  const double theta_deg = theta * 360.0 / kTwoPi;
  proj_.clear();
  for (int i : cand_) {
    // Pixels whose 1 deg direction bin (the angle rounded) lies a degree inside the
    // tolerance pass without the exact test: same result, and the float sin and cos per
    // candidate were 1.3 % of the frontend's instructions.
    double dd = std::fabs(edges[i].dir_bin - theta_deg);
    if (dd > 180) dd = 360 - dd;
    if (dd + 1.0 >= prm.direction_tolerance_deg) {
      const float a = edges[i].angle;
      if (std::cos(a) * c + std::sin(a) * s < tol_cos) continue;
    }
    proj_.emplace_back(static_cast<float>(-edges[i].x * s + edges[i].y * c), i);
    if (!prm.release_unused) used[i] = 1;  // Algorithm 2, line 50: remove F from the feature points
  }
  if (proj_.size() < min_pixels) return false;
  sortByPosition(proj_, keys_, sorted_keys_, key_start_);
  // Beyond band_px (out to member_band_px) a pixel belongs to the line only where it is the
  // line's nearest pixel at its position along it (1 px cells): a far edge bent by 1-3 deg
  // strays up to 1.5 px from one fitted line, while a parallel edge beside it has pixels
  // at the same positions, nearer ones on the line itself.
  if (prm.member_band_px > prm.band_px) {
    size_t out = 0, k = 0;
    while (k < proj_.size()) {
      const double cell = std::floor(proj_[k].first);
      size_t e = k;
      double dmin = 1e30;
      for (; e < proj_.size() && std::floor(proj_[e].first) == cell; ++e) {
        const EdgePixel& q = edges[proj_[e].second];
        dmin = std::min(dmin, std::fabs(q.x * c + q.y * s - rho));
      }
      for (size_t j = k; j < e; ++j) {
        const EdgePixel& q = edges[proj_[j].second];
        const double d = std::fabs(q.x * c + q.y * s - rho);
        if (d <= prm.band_px || d == dmin) proj_[out++] = proj_[j];
      }
      k = e;
    }
    proj_.resize(out);
    if (proj_.size() < min_pixels) return false;
  }
  return true;
}

void SegmentExtractor::splitAndEmit(const std::vector<EdgePixel>& edges, std::vector<uint8_t>& used, double theta,
                                    double c, double s, double rho, const SegmentParams& prm,
                                    const BorderCredit& borderCredit, std::vector<Segment>& segments) {
  // Split at Gap_min, drop noise pieces, merge under Gap_max.
  merged.clear();
  size_t start = 0;
  auto flush = [&](size_t b, size_t e) {
    const float t0 = proj_[b].first, t1 = proj_[e - 1].first;
    if (t1 - t0 < prm.min_piece_px) return;
    if (!merged.empty() && t0 - merged.back().t1 < prm.gap_max_px) {
      merged.back().e = e;
      merged.back().t1 = t1;
    } else {
      merged.push_back(Piece{b, e, t0, t1});
    }
  };
  for (size_t k = 1; k <= proj_.size(); ++k)
    if (k == proj_.size() || proj_[k].first - proj_[k - 1].first > prm.gap_min_px) {
      flush(start, k);
      start = k;
    }
  // Point at line coordinate t, and the L_min length of [t0, t1] with the border credit.
  auto creditedLength = [&](double t0, double t1) {
    return t1 - t0 + borderCredit(rho * c - t0 * s, rho * s + t0 * c, s, -c) +
           borderCredit(rho * c - t1 * s, rho * s + t1 * c, -s, c);
  };
  for (const Piece& pc : merged) {
    if (creditedLength(pc.t0, pc.t1) < prm.min_length_px) continue;
    // Pixels of the piece, excluding the dropped noise pieces inside it.
    piece_.clear();
    size_t run = pc.b;
    for (size_t k = pc.b + 1; k <= pc.e; ++k)
      if (k == pc.e || proj_[k].first - proj_[k - 1].first > prm.gap_min_px) {
        if (proj_[k - 1].first - proj_[run].first >= prm.min_piece_px)
          for (size_t q = run; q < k; ++q) piece_.push_back(proj_[q].second);
        run = k;
      }
    splitAtBends(edges, piece_.data(), piece_.data() + piece_.size(), theta, prm.straightness_bin_px,
                 prm.straightness_px, cuts_, bend_scratch_, prm.step_px, prm.tail_px);
    for (size_t ci = 0; ci + 1 < cuts_.size(); ++ci) {
      const int* rb = piece_.data() + cuts_[ci];
      const int* re = piece_.data() + cuts_[ci + 1];
      if (re - rb < 2) continue;
      const auto tOf = [&](int i) { return -edges[i].x * s + edges[i].y * c; };
      const double len = tOf(*(re - 1)) - tOf(*rb);
      if (creditedLength(tOf(*rb), tOf(*(re - 1))) < prm.min_length_px || (re - rb) < prm.min_density * len) continue;
      Segment seg;
      double rms = 0;
      if (!fitLine(edges, rb, re, theta, seg.theta, seg.rho, &rms)) continue;
      setExtent(edges, rb, re, seg);
      seg.rms = rms;
      segments.push_back(seg);
      for (const int* q = rb; q != re; ++q) {
        pix_.push_back(*q);
        used[*q] = 1;  // Algorithm 2, line 50: remove F from the feature points
      }
      off_.push_back(static_cast<int>(pix_.size()));
    }
  }
}

void SegmentExtractor::extract(const std::vector<EdgePixel>& edges, const std::vector<HoughPeak>& peaks,
                               double rho_step_px, const SegmentParams& prm, std::vector<uint8_t>& used,
                               std::vector<Segment>& segments, int width, int height) {
  used.assign(edges.size(), 0);
  segments.clear();
  pix_.clear();
  off_.assign(1, 0);
  bucketByDirection(edges);
  pool_valid_ = false;
  const int tol_bins = static_cast<int>(std::ceil(prm.direction_tolerance_deg));
  const double tol_cos = std::cos(prm.direction_tolerance_deg * kTwoPi / 360.0);
  const double min_pixels = 0.5 * prm.min_length_px;
  const BorderCredit border_credit{width, height, 2.5 + prm.gap_min_px};

  for (const HoughPeak& peak : peaks) {
    // The peak's pool: the unused pixels of a wider bin range and band around its line, which
    // the repeated collections of its rounds and refits filter instead of the whole buckets
    // (collect() checks that the pool covers each one; the result is the same either way).
    fillPool(edges, used, peak.theta, peak.rho, 0.5 * rho_step_px + 1.0 + kPoolMarginPx, tol_bins + kPoolMarginBins);
    for (int round = 0; round < std::max(1, prm.rounds_per_peak); ++round) {
      double theta = peak.theta, rho = peak.rho;
      collect(edges, used, theta, rho, 0.5 * rho_step_px + 1.0, tol_bins);
      if (cand_.size() < min_pixels) break;
      // Seed: the longest run of the cell's pixels without a gap over Gap_min along the peak's
      // line. A cell (and its +-1 px margin) often holds pieces of several lines a few degrees
      // apart (a far wall foot, the corner triangle's foot, the goal's foot); a fit through all
      // of them has a compromise angle that none of them fits within the band.
      if (!seedLongestRun(edges, theta, prm)) break;
      bool ok = fitLine(edges, seed_.data(), seed_.data() + seed_.size(), theta, theta, rho);
      // The densest 2 band_px window of the pixels' distances from the fitted line, in bins of
      // band_px / 2: parallel edges in the cell are separate clusters, the fit lies between.
      double shift = 0;
      if (ok && densestBand(edges, theta, rho, rho_step_px, prm, &shift)) rho += shift;
      for (int it = 0; it < std::max(1, prm.refit_iterations) && ok; ++it) {
        collect(edges, used, theta, rho, prm.band_px, tol_bins);
        ok = cand_.size() >= min_pixels && fitLine(edges, cand_.data(), cand_.data() + cand_.size(), theta, theta, rho);
      }
      if (ok) collect(edges, used, theta, rho, std::max(prm.band_px, prm.member_band_px), tol_bins);
      if (!ok || cand_.size() < min_pixels) break;
      const double c = std::cos(theta), s = std::sin(theta);
      if (!lineMembers(edges, used, theta, c, s, rho, tol_cos, min_pixels, prm)) break;
      const size_t found_before = segments.size();
      splitAndEmit(edges, used, theta, c, s, rho, prm, border_credit, segments);
      if (segments.size() == found_before) break;  // nothing new: the peak is exhausted
    }
  }
  pool_valid_ = false;
  mergeCollinearSegments(edges, prm, segments, pix_, off_, merge_pix_);
}

void mergeCollinearSegments(const std::vector<EdgePixel>& edges, const SegmentParams& prm, std::vector<Segment>& segments,
                            std::vector<int>& pix_, std::vector<int>& off_, std::vector<int>& merge_pix_) {
  // See segments.h. A far edge bent by a fraction of a pixel, or broken by noise, votes into
  // neighbouring cells; the end-point test against the joint fit keeps real bends apart.
  const double cos_tol = std::cos(2.0 * kTwoPi / 360.0);
  bool merged_any = true;
  while (merged_any) {
    merged_any = false;
    for (size_t i = 0; i < segments.size() && !merged_any; ++i)
      for (size_t j = i + 1; j < segments.size() && !merged_any; ++j) {
        const Segment& a = segments[i];
        const Segment& b = segments[j];
        if (std::cos(a.theta - b.theta) < cos_tol) continue;
        // Along a's direction: extents, gap and overlap.
        const double c = std::cos(a.theta), sn = std::sin(a.theta);
        auto tOf = [&](double x, double y) { return -x * sn + y * c; };
        const double a0 = std::min(tOf(a.x1, a.y1), tOf(a.x2, a.y2)), a1 = std::max(tOf(a.x1, a.y1), tOf(a.x2, a.y2));
        const double b0 = std::min(tOf(b.x1, b.y1), tOf(b.x2, b.y2)), b1 = std::max(tOf(b.x1, b.y1), tOf(b.x2, b.y2));
        const double gap = std::max(b0 - a1, a0 - b1);
        if (gap < -prm.gap_min_px || gap > prm.gap_max_px) continue;  // overlapping (parallel) or too far
        auto off = [&](const Segment& l, double x, double y) {
          return std::fabs(x * std::cos(l.theta) + y * std::sin(l.theta) - l.rho);
        };
        if (off(a, b.x1, b.y1) > 2 * prm.straightness_px || off(a, b.x2, b.y2) > 2 * prm.straightness_px) continue;
        // No step at the gap: each piece's near end within straightness_px of the other's line
        // (a joint fit alone tilts to pass between two parallel edges stepped by 2 px, a far
        // wall foot and the goal's foot beside it).
        const bool a_first = a0 < b0;
        const double ax = (tOf(a.x1, a.y1) > tOf(a.x2, a.y2)) == a_first ? a.x1 : a.x2;
        const double ay = (tOf(a.x1, a.y1) > tOf(a.x2, a.y2)) == a_first ? a.y1 : a.y2;
        const double bx = (tOf(b.x1, b.y1) < tOf(b.x2, b.y2)) == a_first ? b.x1 : b.x2;
        const double by = (tOf(b.x1, b.y1) < tOf(b.x2, b.y2)) == a_first ? b.y1 : b.y2;
        if (off(a, bx, by) > prm.straightness_px || off(b, ax, ay) > prm.straightness_px) continue;
        // Joint fit over both pixel sets.
        merge_pix_.assign(pix_.begin() + off_[i], pix_.begin() + off_[i + 1]);
        merge_pix_.insert(merge_pix_.end(), pix_.begin() + off_[j], pix_.begin() + off_[j + 1]);
        Segment m;
        double rms = 0;
        if (!fitLine(edges, merge_pix_.data(), merge_pix_.data() + merge_pix_.size(), a.theta, m.theta, m.rho, &rms)) continue;
        if (off(m, a.x1, a.y1) > prm.straightness_px || off(m, a.x2, a.y2) > prm.straightness_px ||
            off(m, b.x1, b.y1) > prm.straightness_px || off(m, b.x2, b.y2) > prm.straightness_px)
          continue;
        setExtent(edges, merge_pix_.data(), merge_pix_.data() + merge_pix_.size(), m);
        m.rms = rms;
        // Rebuild the pixel lists: segment i becomes the merged one, j goes.
        std::vector<int> pix;
        std::vector<int> offs(1, 0);
        pix.reserve(pix_.size());
        for (size_t k = 0; k < segments.size(); ++k) {
          if (k == j) continue;
          if (k == i)
            pix.insert(pix.end(), merge_pix_.begin(), merge_pix_.end());
          else
            pix.insert(pix.end(), pix_.begin() + off_[k], pix_.begin() + off_[k + 1]);
          offs.push_back(static_cast<int>(pix.size()));
        }
        pix_.swap(pix);
        off_.swap(offs);
        segments[i] = m;
        segments.erase(segments.begin() + static_cast<long>(j));
        merged_any = true;
      }
  }
}

}  // namespace stereoloc::frontend
