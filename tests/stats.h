// Statistics helpers for the tests: χ² and normal distributions, multiple-testing correction, a
// pooled Pearson χ² goodness-of-fit test, correlation, and adaptive 2D quadrature for expected
// counts. Plain double-precision code with no dependencies, so any test file can use it.
#pragma once
#include <functional>
#include <span>

namespace xi::stats {

// Regularised lower and upper incomplete gamma functions P(a, x) = γ(a, x)/Γ(a) and
// Q(a, x) = 1 − P(a, x), for a > 0, x ≥ 0: the series where x < a + 1, Lentz's continued fraction
// elsewhere (the standard numerical-recipes split), to about 1e-14 relative. NaN on bad input.
double regularized_gamma_p(double a, double x);
double regularized_gamma_q(double a, double x);

// The survival function of the χ² distribution with `dof` degrees of freedom: P[X ≥ x], the
// p-value of an observed statistic x.
double chi2_sf(double x, double dof);

// The standard normal CDF and its inverse (Acklam's rational approximation refined by two Halley
// steps: about 1e-15 relative). normal_quantile(p) is −inf at 0, +inf at 1, NaN outside [0, 1].
double normal_cdf(double z);
double normal_quantile(double p);

// Šidák correction: the per-test level that keeps the chance of any false rejection among
// `tests` independent tests at `alpha`: 1 − (1 − alpha)^(1/tests).
double sidak_alpha(double alpha, int tests);

// The two-sided critical value of a z-test run `tests` times at family-wise level `alpha`,
// Šidák-corrected: Φ⁻¹(1 − α₁/2) with α₁ = sidak_alpha(alpha, tests). E.g. 2.5758 for one test at
// 0.01, 3.2595 for nine.
double sidak_critical_z(double alpha, int tests);

struct Chi2Result {
  double statistic = 0.0;  // Pearson's Σ (O − E)² / E over the bins
  int dof = 0;             // bins − 1
  double p_value = 1.0;    // chi2_sf(statistic, dof); 0 if samples fell where nothing was expected
  int bins = 0;            // bins after pooling
  int pooled_cells = 0;    // cells whose expectation was below min_expected
};

// Pearson's χ² goodness-of-fit test of observed counts against expected counts (same length, the
// expectations summing to the number of samples). Cells expecting fewer than `min_expected`
// samples are pooled into one bin; if that pool still expects fewer, it is merged into the bin with
// the smallest expectation. Observations in cells expecting exactly zero make p = 0.
Chi2Result chi2_test(std::span<const double> observed, std::span<const double> expected,
                     double min_expected = 5.0);

// Pearson's correlation coefficient of two equally long samples (NaN if either is constant).
double pearson_correlation(std::span<const double> x, std::span<const double> y);

// ∫∫ f(x, y) dx dy over [x0, x1] × [y0, y1] by adaptive 3×3-point Gauss–Legendre cubature: the
// box is split into quarters down to min_depth, then further until the quarters agree with their
// parent to abs_tol (shared out among the quarters) or max_depth is reached. Nodes are never on a
// box's edge, so integrands may jump along box edges at no cost. A jump inside a box is resolved by
// refinement, but like any sampled rule it can be missed where it only cuts a sliver off a box
// between the nodes: raise min_depth for such integrands. Exact for polynomials of degree ≤ 5.
double integrate_2d(const std::function<double(double, double)>& f, double x0, double x1, double y0,
                    double y1, double abs_tol = 1e-10, int max_depth = 12, int min_depth = 0);

// integrate_2d to within max(abs_tol, rel_tol × |I|), where I is the estimate on the uniform grid of
// min_depth (at least 1) levels, whose values the adaptive pass then reuses.
double integrate_2d_relative(const std::function<double(double, double)>& f, double x0, double x1, double y0,
                             double y1, double rel_tol, double abs_tol, int max_depth, int min_depth);

}  // namespace xi::stats
