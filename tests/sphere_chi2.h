// Cells over the sphere of directions for χ² tests of BSDF samplers against their pdfs
// (test_microfacet.cpp, test_bsdf.cpp): the samplers' fixed-seed ξ, the grid, the cell a direction
// falls in, and each cell's integral of a density by adaptive cubature.
//
// Cells in (θ, φ) (solid angle sin θ dθ dφ) with wo at φ = 0: nt × np even cells, the horizon
// θ = π/2 on an edge, refined around the lobes' peaks (the mirror direction (θ_o, π) and the
// refracted one (π − θ_t, π)) by edges at ±0.002 · 2^k (k = 0…5) in θ and the same lengths in φ
// across the peak, so the lobes of roughness 0.05 (α = 0.0025) spread over a dozen cells each.
#pragma once
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <functional>
#include <random>
#include <vector>

#include <glm/glm.hpp>

#include "stats.h"

namespace xi::sphere_chi2 {

constexpr double kPi = M_PI;
constexpr double kTwoPi = 2.0 * M_PI;

// ξ in [0, 1) from a fixed-seed Mersenne twister: 24 random bits, so never 1.
struct Uniform {
  std::mt19937 rng;
  explicit Uniform(uint32_t seed) : rng(seed) {}
  float operator()() { return (float)(rng() >> 8) * 0x1p-24f; }
  glm::vec2 pair() {
    float a = (*this)();
    return {a, (*this)()};
  }
};

// φ of (x, y) in [0, 2π).
inline double angle(double y, double x) {
  double t = std::atan2(y, x);
  return t < 0.0 ? t + kTwoPi : t;
}
inline glm::vec3 direction(double theta, double phi) {
  double s = std::sin(theta);
  return {(float)(s * std::cos(phi)), (float)(s * std::sin(phi)), (float)std::cos(theta)};
}

struct SphereGrid {
  std::vector<double> theta, phi;  // edges
  std::vector<glm::dvec2> peaks;   // (θ, φ)
  int cells() const { return (int)((theta.size() - 1) * (phi.size() - 1)); }
};

inline void sorted_edges(std::vector<double>& e, double lo, double hi) {
  std::sort(e.begin(), e.end());
  std::vector<double> out;
  for (double x : e)
    if (x >= lo && x <= hi && (out.empty() || x - out.back() > 1e-5)) out.push_back(x);
  out.front() = lo, out.back() = hi;
  e = out;
}

// nt (even, so the horizon is an edge) × np even cells before the refinement (`levels` of the
// k = 0…5 above, none for lobes wide enough for the even cells); wo = (sin θ_o, 0, cos θ_o), eta the
// relative index of the far side.
inline SphereGrid sphere_grid(glm::vec3 wo, float eta, int nt, int np, int levels = 6) {
  SphereGrid g;
  for (int i = 0; i <= nt; ++i) g.theta.push_back(kPi * i / nt);
  for (int j = 0; j <= np; ++j) g.phi.push_back(kTwoPi * j / np);
  double to = std::acos((double)wo.z), st = std::sin(to) / eta;
  g.peaks.push_back({to, kPi});
  if (st < 1.0) g.peaks.push_back({kPi - std::asin(st), kPi});
  for (glm::dvec2 p : g.peaks)
    for (int k = 0; k < levels; ++k) {
      double d = 0.002 * (1 << k);
      g.theta.push_back(p.x - d), g.theta.push_back(p.x + d);
      if (std::sin(p.x) > 0.02) {
        double dp = std::min(d / std::sin(p.x), 0.5);
        g.phi.push_back(kPi - dp), g.phi.push_back(kPi + dp);
      }
    }
  sorted_edges(g.theta, 0.0, kPi);
  sorted_edges(g.phi, 0.0, kTwoPi);
  return g;
}

inline int cell_of(const SphereGrid& g, glm::vec3 w) {
  double t = std::acos(std::clamp((double)w.z, -1.0, 1.0)), p = angle(w.y, w.x);
  int i = std::clamp((int)(std::upper_bound(g.theta.begin(), g.theta.end(), t) - g.theta.begin()) - 1, 0,
                     (int)g.theta.size() - 2);
  int j = std::clamp((int)(std::upper_bound(g.phi.begin(), g.phi.end(), p) - g.phi.begin()) - 1, 0,
                     (int)g.phi.size() - 2);
  return i * (int)(g.phi.size() - 1) + j;
}

// ∫ f(w) dω over each cell, f in solid angle. Cubature to `rel_tol` of the cell's integral or
// `abs_tol`, whichever is larger: the defaults (1e-4, 1e-7) put at 2·10^5 samples about 1 sample
// of error in a cell that expects 10^4 against a noise of 100, 0.02 in one that expects 75 against
// 9; tighter tolerances chase the float pdf's rounding, ~1e-4 relative in a lobe of
// α = 0.0025 where a float direction moves by 6e-8 rad. At least `near_depth` levels deep in the
// cells within 0.15 rad of a peak so no lobe hides between the nodes, `far_depth` (1) elsewhere; at most
// `max_depth` (a density that jumps inside a cell, as a rough transmission lobe's where its half
// vector meets the horizon, is refined along the jump to that depth).
inline std::vector<double> cell_integrals(const SphereGrid& g, const std::function<double(glm::vec3)>& f,
                                          double rel_tol = 1e-4, double abs_tol = 1e-7, int near_depth = 3,
                                          int max_depth = 10, int far_depth = 1) {
  auto integrand = [&](double t, double p) { return f(direction(t, p)) * std::sin(t); };
  std::vector<double> out;
  out.reserve(g.cells());
  for (size_t i = 0; i + 1 < g.theta.size(); ++i)
    for (size_t j = 0; j + 1 < g.phi.size(); ++j) {
      double t0 = g.theta[i], t1 = g.theta[i + 1], p0 = g.phi[j], p1 = g.phi[j + 1];
      bool near = false;
      for (glm::dvec2 pk : g.peaks) {
        double dt = std::max({0.0, t0 - pk.x, pk.x - t1});
        double dp = std::max({0.0, p0 - pk.y, pk.y - p1});
        near = near || (dt < 0.15 && (std::sin(pk.x) < 0.2 || dp * std::sin(pk.x) < 0.15));
      }
      int depth = near ? near_depth : far_depth;
      out.push_back(xi::stats::integrate_2d_relative(integrand, t0, t1, p0, p1, rel_tol, abs_tol, max_depth, depth));
    }
  return out;
}

}  // namespace xi::sphere_chi2
