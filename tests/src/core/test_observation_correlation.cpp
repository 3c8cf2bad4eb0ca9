#include "src/core/observation_correlation.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "test_util.h"

namespace stereoloc {
namespace {

using test::errorOf;

// A Gauss-Markov error of variance `var` with correlation exp(-dt / tau), one per key, sampled
// at the given times (sorted).
struct MarkovProcess {
  double var, tau;
  bool started = false;
  double t = 0, x = 0;
  double next(double t_new, std::mt19937_64& rng) {
    std::normal_distribution<double> n01;
    if (!started) {
      x = std::sqrt(var) * n01(rng);
      started = true;
    } else {
      const double rho = std::exp(-(t_new - t) / tau);
      x = rho * x + std::sqrt(var * (1 - rho * rho)) * n01(rng);
    }
    t = t_new;
    return x;
  }
};

// Four landmarks seen in turn at random intervals (mean 0.4 s) for `duration` seconds; each
// sighting's error: its landmark's own Markov part (a_own, tau_own), a part common to all
// landmarks (a_common, tau_common) and white noise making the variance 1.
std::vector<ErrorSample> simulateErrors(double a_own, double tau_own, double a_common, double tau_common,
                                        double duration, uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::exponential_distribution<double> gap(1.0 / 0.4);
  std::uniform_int_distribution<int> which(0, 3);
  std::normal_distribution<double> n01;
  std::vector<MarkovProcess> own(4, MarkovProcess{a_own, tau_own});
  MarkovProcess common{a_common, tau_common};
  std::vector<ErrorSample> out;
  for (double t = 0; t < duration; t += gap(rng)) {
    const int key = which(rng);
    const double e = own[static_cast<size_t>(key)].next(t, rng) + common.next(t, rng) +
                     std::sqrt(1.0 - a_own - a_common) * n01(rng);
    out.push_back({t, 10 + key, 50.0 * e});  // any unit: the fit normalises
  }
  return out;
}

TEST(ErrorCorrelationFit, RecoversEachLandmarksOwnCorrelation) {
  const std::vector<ErrorSample> s = simulateErrors(0.7, 3.0, 0.0, 1.0, 20000.0, 1);
  const ErrorCorrelationFit same = fitErrorCorrelation(s, true, 60.0);
  EXPECT_NEAR(same.correlation.at_zero, 0.7, 0.05);
  EXPECT_NEAR(same.correlation.time_constant_s, 3.0, 0.6);
  EXPECT_NEAR(same.rms, 50.0, 3.0);
  EXPECT_GT(same.pairs, 10000u);
  // The landmarks' errors are independent of each other.
  const ErrorCorrelationFit other = fitErrorCorrelation(s, false, 60.0);
  EXPECT_LT(other.correlation.at_zero, 0.05);
}

TEST(ErrorCorrelationFit, RecoversAnErrorCommonToAllLandmarks) {
  const std::vector<ErrorSample> s = simulateErrors(0.0, 1.0, 0.4, 8.0, 20000.0, 2);
  const ErrorCorrelationFit other = fitErrorCorrelation(s, false, 60.0);
  EXPECT_NEAR(other.correlation.at_zero, 0.4, 0.05);
  EXPECT_NEAR(other.correlation.time_constant_s, 8.0, 1.6);
}

TEST(ErrorCorrelationFit, GrossErrorsAreLeftOut) {
  std::vector<ErrorSample> s = simulateErrors(0.7, 3.0, 0.0, 1.0, 4000.0, 3);
  std::mt19937_64 rng(4);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  for (size_t i = 0; i < s.size(); i += 97) s[i].error = 5000.0 * (u(rng) > 0 ? 1 : -1);  // 100 sigma
  const ErrorCorrelationFit fit = fitErrorCorrelation(s, true, 60.0);
  EXPECT_NEAR(fit.correlation.at_zero, 0.7, 0.06);
  EXPECT_NEAR(fit.rms, 50.0, 3.0);
}

TEST(ErrorCorrelationFit, WhiteErrorsAndTooFewPairsGiveNoCorrelation) {
  const std::vector<ErrorSample> white = simulateErrors(0.0, 1.0, 0.0, 1.0, 2000.0, 5);
  EXPECT_LT(fitErrorCorrelation(white, true, 60.0).correlation.at_zero, 0.05);
  const std::vector<ErrorSample> few = {{0.0, 1, 1.0}, {0.5, 1, 2.0}, {1.0, 1, -1.0}};
  const ErrorCorrelationFit fit = fitErrorCorrelation(few, true, 60.0);
  EXPECT_EQ(fit.correlation.at_zero, 0.0);
  EXPECT_EQ(fit.pairs, 3u);
  EXPECT_NE(errorOf([&] { fitErrorCorrelation(few, true, 0.0); }).find("max lag"), std::string::npos);
  std::vector<ErrorSample> nan = few;
  nan[1].error = std::nan("");
  EXPECT_NE(errorOf([&] { fitErrorCorrelation(nan, true, 60.0); }).find("not finite"), std::string::npos);
}

TEST(ErrorCorrelation, VarianceFactorAndCorrelationAtLag) {
  EXPECT_DOUBLE_EQ(correlationVarianceFactor(0.0), 1.0);
  EXPECT_DOUBLE_EQ(correlationVarianceFactor(0.5), 3.0);
  EXPECT_NEAR(correlationVarianceFactor(kMaxErrorCorrelation), 39.0, 1e-9);
  EXPECT_NEAR(correlationVarianceFactor(1.0), 39.0, 1e-9);  // capped
  EXPECT_NE(errorOf([] { correlationVarianceFactor(1.01); }).find("outside"), std::string::npos);
  EXPECT_NE(errorOf([] { correlationVarianceFactor(-0.1); }).find("outside"), std::string::npos);
  const ErrorCorrelation rho{0.8, 2.0};
  EXPECT_DOUBLE_EQ(rho.at(0.0), 0.8);
  EXPECT_DOUBLE_EQ(rho.at(2.0), 0.8 * std::exp(-1.0));
  EXPECT_EQ(rho.at(-1.0), 0.0);
  EXPECT_EQ(rho.at(std::numeric_limits<double>::infinity()), 0.0);
}

// One landmark seen every dt through a Markov (exponentially correlated) range error: the
// inflated sigmas carry, summed as independent information, exactly the information the
// correlated sequence holds about a constant, and the weighted mean's stated variance matches
// its spread.
TEST(CorrelatedErrors, IndependentFusionGetsTheInformationOfAMarkovSequence) {
  const double sigma = 40.0, dt = 0.1, tau = 1.5, n = 200;
  const double rho = std::exp(-dt / tau);
  ASSERT_LE(rho, kMaxErrorCorrelation);  // below the cap, so the factor is exact
  ObservationCorrelation c;
  c.range_same = {1.0, tau};
  std::mt19937_64 rng(11);
  std::normal_distribution<double> n01;
  const double truth = 3000.0;
  double nees = 0, nees_white = 0;
  const int runs = 2000;
  for (int run = 0; run < runs; ++run) {
    std::vector<Step> steps;
    MarkovProcess markov{sigma * sigma, tau};
    for (int k = 0; k < n; ++k) {
      Step s;
      s.step = k;
      s.t = k * dt;
      const double e = markov.next(s.t, rng);
      s.observations.push_back(observationFromRangeBearing(7, LandmarkType::Point, truth + e, 0.1, sigma, 0.01));
      steps.push_back(s);
    }
    std::vector<Step> white = steps;
    inflateForCorrelatedErrors(steps, c);
    auto neesOf = [&](const std::vector<Step>& st) {
      double info = 0, sum = 0;
      for (const Step& s : st) {
        const double w = 1.0 / s.observations[0].covariance(0, 0);
        info += w;
        sum += w * s.observations[0].range;
      }
      const double err = sum / info - truth;
      return err * err * info;
    };
    nees += neesOf(steps) / runs;
    nees_white += neesOf(white) / runs;
    if (run == 0) {
      // The first sighting keeps its sigma; every later one is inflated by (1 + rho)/(1 - rho).
      EXPECT_DOUBLE_EQ(steps[0].observations[0].covariance(0, 0), sigma * sigma);
      double info = 0;
      for (const Step& s : steps) info += 1.0 / s.observations[0].covariance(0, 0);
      EXPECT_NEAR(info * sigma * sigma, 1.0 + (n - 1) * (1 - rho) / (1 + rho), 1e-9);
      // The bearing has no correlation in this model: unchanged.
      EXPECT_DOUBLE_EQ(steps[5].observations[0].covariance(1, 1), 1e-4);
    }
  }
  // Independent fusion of the inflated sigmas is honest: its stated variance is the GLS one,
  // and the weighted mean, which weighs the first sighting more than GLS would and the last
  // less, has 1.06 times that (w' Sigma w / sum w for these weights), against 1 +- 0.03 here.
  EXPECT_NEAR(nees, 1.06, 0.1);
  EXPECT_GT(nees_white, 10.0);   // of the given sigmas, overconfident
}

TEST(CorrelatedErrors, AnotherLandmarkSeenAtOnceSharesTheCommonErrorAndRKeepsItsCorrelation) {
  ObservationCorrelation c;
  c.bearing_other = {0.5, 4.0};
  c.range_same = {0.8, 2.0};
  std::vector<Step> steps(3);
  for (int i = 0; i < 3; ++i) {
    steps[i].step = i;
    steps[i].t = 1.0 * i;
  }
  Observation o = observationFromRangeBearing(1, LandmarkType::Point, 2000, 0.2, 30, 0.02);
  o.covariance(0, 1) = o.covariance(1, 0) = 0.3;  // a correlated R keeps its coefficient
  steps[0].observations = {o};
  o.landmark_id = 2;
  steps[0].observations.push_back(o);  // another landmark at the same time
  o.landmark_id = 1;
  steps[2].observations = {o};  // landmark 1 again, 2 s later; landmark 2 seen 2 s ago
  inflateForCorrelatedErrors(steps, c);
  const Eigen::Matrix2d& first = steps[0].observations[0].covariance;
  EXPECT_DOUBLE_EQ(first(0, 0), 900.0);
  EXPECT_DOUBLE_EQ(first(1, 1), 4e-4);
  const Eigen::Matrix2d& second = steps[0].observations[1].covariance;
  EXPECT_DOUBLE_EQ(second(0, 0), 900.0);                      // range: no common part
  EXPECT_NEAR(second(1, 1), 4e-4 * 3.0, 1e-15);               // bearing: rho_other(0) = 0.5
  EXPECT_NEAR(second(0, 1) / std::sqrt(second(0, 0) * second(1, 1)), 0.3 / std::sqrt(900 * 4e-4), 1e-12);
  const Eigen::Matrix2d& again = steps[2].observations[0].covariance;
  const double rr = 0.8 * std::exp(-1.0), rb = 0.5 * std::exp(-0.5);
  EXPECT_NEAR(again(0, 0), 900.0 * (1 + rr) / (1 - rr), 1e-9);
  EXPECT_NEAR(again(1, 1), 4e-4 * (1 + rb) / (1 - rb), 1e-15);
}

TEST(CorrelatedErrors, BadInputIsAnError) {
  ObservationCorrelation c;
  std::vector<Step> steps(2);
  steps[0].t = 1.0;
  steps[1].step = 1;
  steps[1].t = 0.5;
  EXPECT_NE(errorOf([&] { inflateForCorrelatedErrors(steps, c); }).find("step 1 is earlier"), std::string::npos);
  steps[1].t = 2.0;
  steps[1].observations.push_back(observationFromRangeBearing(-1, LandmarkType::Point, 100, 0, 1, 1));
  EXPECT_NE(errorOf([&] { inflateForCorrelatedErrors(steps, c); }).find("no landmark id"), std::string::npos);
  c.bearing_same.at_zero = 1.5;
  EXPECT_NE(errorOf([&] { inflateForCorrelatedErrors(steps, c); }).find("bearing_same.at_zero"), std::string::npos);
  c.bearing_same.at_zero = 0.5;
  c.range_other.time_constant_s = 0;
  EXPECT_NE(errorOf([&] { inflateForCorrelatedErrors(steps, c); }).find("range_other.time_constant_s"),
            std::string::npos);
}

}  // namespace
}  // namespace stereoloc
