#include "stats.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

namespace xi::stats {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr double kEps = 1e-15;
constexpr int kMaxIterations = 100000;  // the series needs O(√a) terms; a ~ 1e6 is still fine

// e^-x x^a / Γ(a), the prefactor of both expansions, in logs to avoid overflow.
double prefactor(double a, double x) { return std::exp(-x + a * std::log(x) - std::lgamma(a)); }

// P(a, x) = e^-x x^a / Γ(a) · Σ_n x^n / (a (a+1) … (a+n)), for x < a + 1.
double gamma_p_series(double a, double x) {
  double term = 1.0 / a, sum = term;
  for (int n = 1; n < kMaxIterations; ++n) {
    term *= x / (a + n);
    sum += term;
    if (std::fabs(term) < std::fabs(sum) * kEps) return sum * prefactor(a, x);
  }
  return kNaN;
}

// Q(a, x) = e^-x x^a / Γ(a) · 1/(x+1−a− 1·(1−a)/(x+3−a− 2·(2−a)/(x+5−a− …))), for x ≥ a + 1,
// evaluated by the modified Lentz method.
double gamma_q_fraction(double a, double x) {
  constexpr double tiny = 1e-300;
  double b = x + 1.0 - a, c = 1.0 / tiny, d = 1.0 / b, h = d;
  for (int i = 1; i < kMaxIterations; ++i) {
    double an = -i * (i - a);
    b += 2.0;
    d = an * d + b;
    if (std::fabs(d) < tiny) d = tiny;
    c = b + an / c;
    if (std::fabs(c) < tiny) c = tiny;
    d = 1.0 / d;
    double delta = d * c;
    h *= delta;
    if (std::fabs(delta - 1.0) < kEps) return h * prefactor(a, x);
  }
  return kNaN;
}

double gauss3(const std::function<double(double, double)>& f, double x0, double x1, double y0, double y1) {
  static const double node[3] = {-std::sqrt(0.6), 0.0, std::sqrt(0.6)};
  static const double weight[3] = {5.0 / 9.0, 8.0 / 9.0, 5.0 / 9.0};
  double cx = 0.5 * (x0 + x1), hx = 0.5 * (x1 - x0), cy = 0.5 * (y0 + y1), hy = 0.5 * (y1 - y0);
  double sum = 0.0;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) sum += weight[i] * weight[j] * f(cx + hx * node[i], cy + hy * node[j]);
  return sum * hx * hy;
}

// The 3×3-point values adapt asks for, in the order it asks for them. Those of the boxes down to
// `replayed_levels` (the root is level 0) can be recorded on one pass and replayed on the next, which
// visits them in the same order.
struct Cells {
  const std::function<double(double, double)>& f;
  int replayed_levels = -1;
  bool recording = false;
  std::vector<double> recorded;
  size_t next = 0;

  double at(double x0, double x1, double y0, double y1, int level) {
    if (level > replayed_levels) return gauss3(f, x0, x1, y0, y1);
    if (!recording) return recorded[next++];
    recorded.push_back(gauss3(f, x0, x1, y0, y1));
    return recorded.back();
  }
};

double adapt(Cells& cells, double x0, double x1, double y0, double y1, int level, double whole, double tol, int depth,
             int min_depth) {
  double xm = 0.5 * (x0 + x1), ym = 0.5 * (y0 + y1);
  const int below = level + 1;
  double q[4] = {cells.at(x0, xm, y0, ym, below), cells.at(xm, x1, y0, ym, below), cells.at(x0, xm, ym, y1, below),
                 cells.at(xm, x1, ym, y1, below)};
  double parts = q[0] + q[1] + q[2] + q[3];
  if (depth <= 0 || (min_depth <= 0 && std::fabs(parts - whole) <= tol)) return parts;
  tol *= 0.25;
  --depth, --min_depth;
  return adapt(cells, x0, xm, y0, ym, below, q[0], tol, depth, min_depth) +
         adapt(cells, xm, x1, y0, ym, below, q[1], tol, depth, min_depth) +
         adapt(cells, x0, xm, ym, y1, below, q[2], tol, depth, min_depth) +
         adapt(cells, xm, x1, ym, y1, below, q[3], tol, depth, min_depth);
}

double integrate(Cells& cells, double x0, double x1, double y0, double y1, double abs_tol, int max_depth,
                 int min_depth) {
  const double whole = cells.at(x0, x1, y0, y1, 0);
  return adapt(cells, x0, x1, y0, y1, 0, whole, abs_tol, max_depth - 1, min_depth - 1);
}

}  // namespace

double regularized_gamma_p(double a, double x) {
  if (!(a > 0.0) || !(x >= 0.0)) return kNaN;
  if (x == 0.0) return 0.0;
  if (std::isinf(x)) return 1.0;
  return x < a + 1.0 ? gamma_p_series(a, x) : 1.0 - gamma_q_fraction(a, x);
}

double regularized_gamma_q(double a, double x) {
  if (!(a > 0.0) || !(x >= 0.0)) return kNaN;
  if (x == 0.0) return 1.0;
  if (std::isinf(x)) return 0.0;
  return x < a + 1.0 ? 1.0 - gamma_p_series(a, x) : gamma_q_fraction(a, x);
}

double chi2_sf(double x, double dof) { return x <= 0.0 ? 1.0 : regularized_gamma_q(0.5 * dof, 0.5 * x); }

double normal_cdf(double z) { return 0.5 * std::erfc(-z / std::sqrt(2.0)); }

double normal_quantile(double p) {
  if (!(p >= 0.0 && p <= 1.0)) return kNaN;
  if (p == 0.0) return -std::numeric_limits<double>::infinity();
  if (p == 1.0) return std::numeric_limits<double>::infinity();
  // P. J. Acklam's approximation (relative error < 1.2e-9): a rational function of p − ½ in the
  // centre, of √(−2 ln p) in the tails.
  static const double a[6] = {-3.969683028665376e+01, 2.209460984245205e+02, -2.759285104469687e+02,
                              1.383577518672690e+02,  -3.066479806614716e+01, 2.506628277459239e+00};
  static const double b[5] = {-5.447609879822406e+01, 1.615858368580409e+02, -1.556989798598866e+02,
                              6.680131188771972e+01,  -1.328068155288572e+01};
  static const double c[6] = {-7.784894002430293e-03, -3.223964580411365e-01, -2.400758277161838e+00,
                              -2.549732539343734e+00, 4.374664141464968e+00,  2.938163982698783e+00};
  static const double d[4] = {7.784695709041462e-03, 3.224671290700398e-01, 2.445134137142996e+00,
                              3.754408661907416e+00};
  const double low = 0.02425;
  double z;
  if (p < low || p > 1.0 - low) {
    double q = std::sqrt(-2.0 * std::log(p < low ? p : 1.0 - p));
    z = (((((c[0] * q + c[1]) * q + c[2]) * q + c[3]) * q + c[4]) * q + c[5]) /
        ((((d[0] * q + d[1]) * q + d[2]) * q + d[3]) * q + 1.0);
    if (p > low) z = -z;
  } else {
    double q = p - 0.5, r = q * q;
    z = (((((a[0] * r + a[1]) * r + a[2]) * r + a[3]) * r + a[4]) * r + a[5]) * q /
        (((((b[0] * r + b[1]) * r + b[2]) * r + b[3]) * r + b[4]) * r + 1.0);
  }
  // Halley steps on normal_cdf(z) − p (the tail form keeps the residual accurate for small p).
  for (int step = 0; step < 2; ++step) {
    double e = z < 0.0 ? normal_cdf(z) - p : (1.0 - p) - normal_cdf(-z);
    double u = e * std::sqrt(2.0 * M_PI) * std::exp(0.5 * z * z);
    z -= u / (1.0 + 0.5 * z * u);
  }
  return z;
}

double sidak_alpha(double alpha, int tests) { return -std::expm1(std::log1p(-alpha) / tests); }

double sidak_critical_z(double alpha, int tests) { return -normal_quantile(0.5 * sidak_alpha(alpha, tests)); }

Chi2Result chi2_test(std::span<const double> observed, std::span<const double> expected, double min_expected) {
  Chi2Result r;
  std::vector<double> obs, exp;
  double pool_obs = 0.0, pool_exp = 0.0;
  bool impossible = false;  // samples where the density says there can be none
  for (size_t i = 0; i < expected.size(); ++i) {
    if (expected[i] <= 0.0 && observed[i] > 0.0) impossible = true;
    if (expected[i] < min_expected) {
      pool_obs += observed[i];
      pool_exp += expected[i];
      ++r.pooled_cells;
    } else {
      obs.push_back(observed[i]);
      exp.push_back(expected[i]);
    }
  }
  if (pool_exp >= min_expected || (exp.empty() && pool_exp > 0.0)) {
    obs.push_back(pool_obs);
    exp.push_back(pool_exp);
  } else if (pool_exp > 0.0) {
    size_t k = std::min_element(exp.begin(), exp.end()) - exp.begin();
    obs[k] += pool_obs;
    exp[k] += pool_exp;
  }
  r.bins = (int)exp.size();
  r.dof = r.bins - 1;
  if (impossible) {
    r.statistic = std::numeric_limits<double>::infinity();
    r.p_value = 0.0;
    return r;
  }
  for (size_t i = 0; i < exp.size(); ++i) r.statistic += (obs[i] - exp[i]) * (obs[i] - exp[i]) / exp[i];
  r.p_value = r.dof > 0 ? chi2_sf(r.statistic, r.dof) : 1.0;
  return r;
}

double pearson_correlation(std::span<const double> x, std::span<const double> y) {
  size_t n = std::min(x.size(), y.size());
  double mx = 0.0, my = 0.0;
  for (size_t i = 0; i < n; ++i) mx += x[i], my += y[i];
  mx /= n, my /= n;
  double sxy = 0.0, sxx = 0.0, syy = 0.0;
  for (size_t i = 0; i < n; ++i) {
    sxy += (x[i] - mx) * (y[i] - my);
    sxx += (x[i] - mx) * (x[i] - mx);
    syy += (y[i] - my) * (y[i] - my);
  }
  return sxy / std::sqrt(sxx * syy);
}

double integrate_2d(const std::function<double(double, double)>& f, double x0, double x1, double y0, double y1,
                    double abs_tol, int max_depth, int min_depth) {
  Cells cells{f};
  return integrate(cells, x0, x1, y0, y1, abs_tol, max_depth, min_depth);
}

double integrate_2d_relative(const std::function<double(double, double)>& f, double x0, double x1, double y0,
                             double y1, double rel_tol, double abs_tol, int max_depth, int min_depth) {
  min_depth = std::max(min_depth, 1);
  Cells cells{f, min_depth, true};
  const double rough = integrate(cells, x0, x1, y0, y1, 0.0, min_depth, min_depth);
  cells.recording = false;
  return integrate(cells, x0, x1, y0, y1, std::max(abs_tol, rel_tol * std::fabs(rough)), max_depth, min_depth);
}

}  // namespace xi::stats
