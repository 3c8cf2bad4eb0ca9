#include "src/core/gaussian.h"

#include <cmath>
#include <limits>

namespace stereoloc {
namespace {

// Series for P(a, x), converges quickly for x < a + 1.
double gammaPSeries(double a, double x) {
  double term = 1.0 / a, sum = term;
  for (int n = 1; n < 100000; ++n) {
    term *= x / (a + n);
    sum += term;
    if (std::fabs(term) < std::fabs(sum) * 1e-16) break;
  }
  return sum * std::exp(-x + a * std::log(x) - std::lgamma(a));
}

// Continued fraction (modified Lentz) for Q(a, x) = 1 - P(a, x), for x >= a + 1.
double gammaQContinuedFraction(double a, double x) {
  constexpr double tiny = 1e-300;
  double b = x + 1.0 - a, c = 1.0 / tiny, d = 1.0 / b, h = d;
  for (int i = 1; i < 100000; ++i) {
    const double an = -i * (i - a);
    b += 2.0;
    d = an * d + b;
    if (std::fabs(d) < tiny) d = tiny;
    c = b + an / c;
    if (std::fabs(c) < tiny) c = tiny;
    d = 1.0 / d;
    const double delta = d * c;
    h *= delta;
    if (std::fabs(delta - 1.0) < 1e-16) break;
  }
  return std::exp(-x + a * std::log(x) - std::lgamma(a)) * h;
}

void checkDof(int dof) {
  if (dof < 1) throw Error("chi-square: degrees of freedom must be >= 1, got " + std::to_string(dof));
}

}  // namespace

double regularizedGammaP(double a, double x) {
  if (!(a > 0.0) || !(x >= 0.0)) throw Error("regularizedGammaP: needs a > 0 and x >= 0");
  if (x == 0.0) return 0.0;
  if (x < a + 1.0) return gammaPSeries(a, x);
  return 1.0 - gammaQContinuedFraction(a, x);
}

double chi2Cdf(double x, int dof) {
  checkDof(dof);
  if (std::isnan(x)) throw Error("chi2Cdf: x is NaN");
  if (x <= 0.0) return 0.0;
  if (std::isinf(x)) return 1.0;
  return regularizedGammaP(0.5 * dof, 0.5 * x);
}

double chi2Quantile(double p, int dof) {
  checkDof(dof);
  if (!(p > 0.0 && p < 1.0)) throw Error("chi2Quantile: probability must be in (0, 1)");
  if (dof == 2) return -2.0 * std::log1p(-p);  // CDF 1 - exp(-x/2) inverts in closed form.
  // Bracket, then bisection refined by Newton steps on the CDF (the density is cheap).
  double lo = 0.0, hi = std::max(1.0, static_cast<double>(dof));
  while (chi2Cdf(hi, dof) < p) hi *= 2.0;
  double x = 0.5 * (lo + hi);
  const double k2 = 0.5 * dof;
  for (int it = 0; it < 200; ++it) {
    const double f = chi2Cdf(x, dof) - p;
    if (f > 0) hi = x; else lo = x;
    const double log_pdf = (k2 - 1.0) * std::log(x) - 0.5 * x - k2 * std::log(2.0) - std::lgamma(k2);
    double next = x - f / std::exp(log_pdf);
    if (!(next > lo && next < hi)) next = 0.5 * (lo + hi);
    if (std::fabs(next - x) <= 1e-14 * std::max(1.0, x)) return next;
    x = next;
  }
  return x;
}

}  // namespace stereoloc
