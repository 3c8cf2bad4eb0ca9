#pragma once
// sin/cos and atan2 for the particle filter's inner loops (solvers/particle_filter.cpp).
//
// With 3000 particles the filter evaluates one sin/cos pair per particle (the heading after
// prediction) and one atan2 per particle and observation (the bearing likelihood). libm's calls
// cost 15-40 ns each and were the filter's hot spot. These inline versions use S. Moshier's
// Cephes minimax polynomials (sin.c, atan.c; relative error about 2e-16 on the reduced
// intervals) with branch-free range reduction, so the loops carry no calls; they agree with
// std::sin, std::cos, std::atan2 to a few ulp (tests/solvers/test_particle_filter.cpp).
// They are not a new angle convention: inputs and outputs are plain radians, and results are
// wrapped with wrapAngle (src/core/angles.h) wherever a wrap is needed.
#include <cmath>

namespace stereoloc {
namespace fast_trig {

// Cephes sin.c: sin(r) = r + r z P(z), cos(r) = 1 - z/2 + z^2 Q(z), z = r^2, |r| <= pi/4.
constexpr double kSinP[6] = {1.58962301576546568060E-10, -2.50507477628578072866E-8, 2.75573136213857245213E-6,
                             -1.98412698295895385996E-4, 8.33333333332211858878E-3, -1.66666666666666307295E-1};
constexpr double kCosP[6] = {-1.13585365213876817300E-11, 2.08757008419747316778E-9, -2.75573141792967388112E-7,
                             2.48015872888517045348E-5,   -1.38888888888730564116E-3, 4.16666666666665929218E-2};
// pi/2 split in three parts (Cody-Waite) so that x - q pi/2 is exact for |q| < 2^26.
constexpr double kPio2Part1 = 2.0 * 7.85398125648498535156E-1;
constexpr double kPio2Part2 = 2.0 * 3.77489470793079817668E-8;
constexpr double kPio2Part3 = 2.0 * 2.69515142907905952645E-15;
constexpr double kTwoOverPi = 0.636619772367581343075535053490057448;
// Adding and subtracting 1.5 * 2^52 rounds a double of magnitude below 2^51 to the nearest
// integer (ties to even) without a call (we do not compile with -ffast-math, which would fold it).
constexpr double kRoundMagic = 6755399441055744.0;

// sin(x) and cos(x) for |x| < 1e7 (the filter's headings are wrapped to [-pi, pi)).
inline void sinCos(double x, double* s, double* c) {
  const double q = (x * kTwoOverPi + kRoundMagic) - kRoundMagic;  // nearest multiple of pi/2
  const double r = ((x - q * kPio2Part1) - q * kPio2Part2) - q * kPio2Part3;  // |r| <= pi/4
  const double z = r * r;
  const double ps = ((((kSinP[0] * z + kSinP[1]) * z + kSinP[2]) * z + kSinP[3]) * z + kSinP[4]) * z + kSinP[5];
  const double pc = ((((kCosP[0] * z + kCosP[1]) * z + kCosP[2]) * z + kCosP[3]) * z + kCosP[4]) * z + kCosP[5];
  const double sr = r + r * z * ps;
  const double cr = 1.0 - 0.5 * z + z * z * pc;
  const int quadrant = static_cast<int>(static_cast<long long>(q) & 3);  // two's complement: -1 -> 3
  const bool swap = (quadrant & 1) != 0;
  const double s0 = swap ? cr : sr, c0 = swap ? sr : cr;
  *s = (quadrant == 2 || quadrant == 3) ? -s0 : s0;  // sin: +sr, +cr, -sr, -cr
  *c = (quadrant == 1 || quadrant == 2) ? -c0 : c0;  // cos: +cr, -sr, -cr, +sr
}

// Cephes atan.c: atan(t) = t + t z P(z) / Q(z), z = t^2, for |t| <= 0.66.
constexpr double kAtanP[5] = {-8.750608600031904122785E-1, -1.615753718733365076637E1, -7.500855792314704667340E1,
                              -1.228866684490136173410E2, -6.485021904942025371773E1};
constexpr double kAtanQ[5] = {2.485846490142306297962E1, 1.650270098316988542046E2, 4.328810604912902668951E2,
                              4.853903996359136964868E2, 1.945506571482613964425E2};  // monic: z^5 + ...
constexpr double kMoreBits = 6.123233995736765886130E-17;  // pi/2 - fl(pi/2)
constexpr double kPio4 = 7.85398163397448309616E-1;
constexpr double kPio2 = 1.57079632679489661923E0;
constexpr double kPiD = 3.14159265358979323846E0;

// atan2(y, x) in [-pi, pi]; (0, 0) gives 0. Finite inputs.
inline double atan2(double y, double x) {
  const double ax = std::fabs(x), ay = std::fabs(y);
  const double hi = ax > ay ? ax : ay, lo = ax > ay ? ay : ax;
  // t = lo / hi is the tangent of the angle folded into [0, pi/4]; above 0.66 use
  // atan(t) = pi/4 + atan((t - 1) / (t + 1)) = pi/4 + atan((lo - hi) / (lo + hi)): one division.
  const bool upper = lo > 0.66 * hi;
  const double num = upper ? lo - hi : lo, den = upper ? lo + hi : hi;
  const double t = den > 0.0 ? num / den : 0.0;
  const double z = t * t;
  const double p = (((kAtanP[0] * z + kAtanP[1]) * z + kAtanP[2]) * z + kAtanP[3]) * z + kAtanP[4];
  const double qq = ((((z + kAtanQ[0]) * z + kAtanQ[1]) * z + kAtanQ[2]) * z + kAtanQ[3]) * z + kAtanQ[4];
  double a = t + t * z * p / qq;
  a = upper ? (kPio4 + (a + 0.5 * kMoreBits)) : a;
  a = ay > ax ? (kPio2 - a) + kMoreBits : a;  // the angle with the axes swapped
  a = x < 0.0 ? (kPiD - a) + 2.0 * kMoreBits : a;
  return y < 0.0 ? -a : a;
}

}  // namespace fast_trig
}  // namespace stereoloc
