#include "frontend/peaks.h"

#include <algorithm>
#include <cstdint>
#include <cstring>

namespace stereoloc::frontend {

void detectPeaks(const HoughAccumulator& acc, const PeakParams& params, std::vector<HoughPeak>& peaks) {
  peaks.clear();
  const int nt = acc.numTheta(), nr = acc.numRho();
  const uint16_t* a = acc.cells().data();
  const int thr = std::max(1, params.min_votes);
  // Most cells are far below the threshold: test 4 cells at once for a bit at or above the
  // highest power of two <= thr (a cell without one is below thr). A branch per cell was most
  // of this stage's time.
  int low = 1;
  while (2 * low <= thr && low < (1 << 15)) low *= 2;
  const uint64_t lane = static_cast<uint16_t>(~(low - 1));
  const uint64_t high_bits = lane | (lane << 16) | (lane << 32) | (lane << 48);
  for (int t = 0; t < nt; ++t) {
    const uint16_t* row = a + static_cast<size_t>(t) * nr;
    const uint16_t* prev = a + static_cast<size_t>(t == 0 ? nt - 1 : t - 1) * nr;
    const uint16_t* next = a + static_cast<size_t>(t == nt - 1 ? 0 : t + 1) * nr;
    for (int r = 1; r < nr - 1; ++r) {
      if (r + 4 <= nr - 1) {
        uint64_t word;
        std::memcpy(&word, row + r, sizeof word);
        if ((word & high_bits) == 0) {
          r += 3;
          continue;
        }
      }
      const int v = row[r];
      if (v < thr) continue;
      // Ties broken towards the lower index, so a plateau yields one peak.
      if (v < row[r + 1] || v <= row[r - 1]) continue;
      if (v < next[r - 1] || v < next[r] || v < next[r + 1]) continue;
      if (v <= prev[r - 1] || v <= prev[r] || v <= prev[r + 1]) continue;
      peaks.push_back(HoughPeak{t, r, v, 0.0, 0.0});
    }
  }
  std::sort(peaks.begin(), peaks.end(), [](const HoughPeak& p, const HoughPeak& q) {
    if (p.votes != q.votes) return p.votes > q.votes;
    if (p.theta_bin != q.theta_bin) return p.theta_bin < q.theta_bin;
    return p.rho_bin < q.rho_bin;
  });
  size_t kept = 0;
  for (size_t i = 0; i < peaks.size() && static_cast<int>(kept) < params.max_peaks; ++i) {
    bool suppressed = false;
    for (size_t j = 0; j < kept && !suppressed; ++j) {
      int dt = std::abs(peaks[i].theta_bin - peaks[j].theta_bin);
      dt = std::min(dt, nt - dt);
      suppressed = dt <= params.window_theta_bins && std::abs(peaks[i].rho_bin - peaks[j].rho_bin) <= params.window_rho_bins;
    }
    if (!suppressed) peaks[kept++] = peaks[i];
  }
  peaks.resize(kept);
  for (HoughPeak& p : peaks) {
    p.theta = acc.theta(p.theta_bin);
    p.rho = acc.rho(p.theta_bin, p.rho_bin);
  }
}

}  // namespace stereoloc::frontend
