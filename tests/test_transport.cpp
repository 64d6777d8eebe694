// Light transport: the renderer's own sampling routines (kernels/tools.cl) against densities and
// Fresnel equations written independently here, and whole renders that must agree with each other
// (MIS vs light sampling vs BSDF sampling, specialised vs all-features builds) or with an exact
// answer (white furnaces), plus a smoke test of every bundled scene.
//
// Every statistical check runs at a family-wise significance of 0.01, Šidák-corrected over the
// checks of its test (each test is one family); seeds are fixed, so the outcome is deterministic.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <string>
#include <vector>

#include <glm/glm.hpp>

#include "layout.h"
#include "sampling.h"
#include "stats.h"
#include "xi/compiled_scene.h"
#include "xi/device.h"
#include "xi/error.h"
#include "xi/kernel_config.h"
#include "xi/renderer.h"
#include "xi/scene.h"
#include "analytic.h"
#include "fixtures.h"

namespace {

namespace fs = std::filesystem;
using glm::dvec3;
using glm::vec3;
using glm::vec4;
using namespace xi::stats;

const fs::path kScenes = XI_SCENE_DIR;
const fs::path kTestScenes = fs::path(XI_TEST_DATA_DIR) / "scenes";
constexpr double kTwoPi = 2.0 * M_PI;

using xi::test::device;  // fixtures.h

// ---------------------------------------------------------------------------------------------
// Tool kernels

const xi::Program& tools() {
  static xi::Program p = xi::build_program(device(), {"tools.cl"}, {});
  return p;
}

template <class T, class A>
cl::Buffer upload(const std::vector<T, A>& v) {
  return cl::Buffer(device().context(), CL_MEM_READ_ONLY | CL_MEM_COPY_HOST_PTR, sizeof(T) * v.size(),
                    const_cast<T*>(v.data()));
}

// Runs `k` over n items (rounded up to the renderer's work-group size) and reads back out[0, n).
std::vector<vec4> run(cl::Kernel& k, const cl::Buffer& out, uint32_t n) {
  const size_t local = 64;
  device().queue().enqueueNDRangeKernel(k, cl::NullRange, cl::NDRange((n + local - 1) / local * local),
                                        cl::NDRange(local));
  std::vector<vec4> v(n);
  device().queue().enqueueReadBuffer(out, CL_TRUE, 0, sizeof(vec4) * n, v.data());
  return v;
}

// sample_lights from `org`: (wi, solid-angle pdf) per sample.
std::vector<vec4> sample_lights(const xi::CompiledScene& cs, dvec3 org, uint32_t n, uint32_t seed) {
  cl::Kernel k(tools().program, "sample_lights");
  cl::Buffer out(device().context(), CL_MEM_WRITE_ONLY, sizeof(vec4) * n);
  cl::Buffer cdf = upload(cs.light_cdf), tri = upload(cs.light_tri), pdf = upload(cs.tri_light_pdf),
             corners = upload(cs.tri_vertices), verts = upload(cs.vertices), mat = upload(cs.tri_material),
             mats = upload(cs.materials);
  int a = 0;
  for (cl::Buffer* b : {&out, &cdf, &tri, &pdf, &corners, &verts, &mat, &mats}) k.setArg(a++, *b);
  k.setArg(a++, (uint32_t)cs.light_tri.size());
  k.setArg(a++, vec4(vec3(org), 0.0f));
  k.setArg(a++, xi_make_sampler_params(seed, n));
  k.setArg(a++, n);
  return run(k, out, n);
}

// sample_bsdf: (wi, pdf) for diffuse, (wi, 1 if reflected else 0) for glass.
std::vector<vec4> sample_bsdf(uint32_t material, dvec3 n, dvec3 wo, float ior, bool entering, uint32_t count,
                              uint32_t seed) {
  cl::Kernel k(tools().program, "sample_bsdf");
  cl::Buffer out(device().context(), CL_MEM_WRITE_ONLY, sizeof(vec4) * count);
  int a = 0;
  k.setArg(a++, out);
  k.setArg(a++, material);
  k.setArg(a++, vec4(vec3(n), 0.0f));
  k.setArg(a++, vec4(vec3(wo), 0.0f));
  k.setArg(a++, ior);
  k.setArg(a++, (int)entering);
  k.setArg(a++, xi_make_sampler_params(seed, count));
  k.setArg(a++, count);
  return run(k, out, count);
}

// ---------------------------------------------------------------------------------------------
// Directions charted by (cos θ, φ) about an axis: solid angle = d cos θ dφ.

struct Frame {
  dvec3 t, b, n;
  explicit Frame(dvec3 axis) : n(glm::normalize(axis)) {
    t = glm::normalize(glm::cross(std::abs(n.x) < 0.9 ? dvec3(1, 0, 0) : dvec3(0, 1, 0), n));
    b = glm::cross(n, t);
  }
  dvec3 direction(double z, double phi) const {
    double r = std::sqrt(std::max(0.0, 1.0 - z * z));
    return r * std::cos(phi) * t + r * std::sin(phi) * b + z * n;
  }
  double phi(dvec3 w) const {
    double p = std::atan2(glm::dot(w, b), glm::dot(w, t));
    return p < 0.0 ? p + kTwoPi : p;
  }
};

// Cell of (z, φ) on an nz × nphi grid over [z0, 1] × [0, 2π); values a hair outside are clamped.
int cell(double z, double phi, double z0, int nz, int nphi) {
  int i = std::clamp((int)std::floor((z - z0) / (1.0 - z0) * nz), 0, nz - 1);
  int j = std::clamp((int)std::floor(phi / kTwoPi * nphi), 0, nphi - 1);
  return i * nphi + j;
}

// ---------------------------------------------------------------------------------------------
// Reference light sampling density, from the scene description alone (not CompiledScene): each
// emissive triangle k is picked with probability power_k / Σ power, power = luminance · area · π
// (× 2 when both faces emit), then a point uniform on its area, so the density of a direction ω
// from o is Σ over emissive triangles crossed by the ray (o, ω) at any distance of
// P(k) / area_k · d² / |cos θ_l| — one-sided lights only where their front faces o.

struct HostLight {
  dvec3 v0, e1, e2, n;  // n: unit front normal (from the winding)
  double p_over_area;   // P(pick) / area
  bool two_sided;
};

std::vector<HostLight> host_lights(const xi::Scene& s) {
  std::vector<HostLight> lights;
  std::vector<double> power;
  double total = 0.0;
  for (const xi::Triangle& t : s.triangles) {
    const xi::Material& m = s.materials[t.material];
    dvec3 l = dvec3(m.emission);
    double lum = 0.2126 * l.x + 0.7152 * l.y + 0.0722 * l.z;
    if (lum <= 0.0) continue;
    HostLight h;
    h.v0 = dvec3(s.position(t, 0));
    h.e1 = dvec3(s.position(t, 1)) - h.v0;
    h.e2 = dvec3(s.position(t, 2)) - h.v0;
    dvec3 c = glm::cross(h.e1, h.e2);
    double area = 0.5 * glm::length(c);
    h.n = c / (2.0 * area);
    h.two_sided = m.two_sided;
    h.p_over_area = 1.0 / area;  // × power / total below
    power.push_back(lum * area * M_PI * (m.two_sided ? 2.0 : 1.0));
    total += power.back();
    lights.push_back(h);
  }
  for (size_t k = 0; k < lights.size(); ++k) lights[k].p_over_area *= power[k] / total;
  return lights;
}

// Ray (o, unit d) against a light, barycentrics allowed `eps` outside the triangle. Returns the
// solid-angle density term, 0 on a miss, and -1 where the ray reaches a one-sided light's back.
double light_term(const HostLight& l, dvec3 o, dvec3 d, double eps = 0.0) {
  dvec3 p = glm::cross(d, l.e2);
  double det = glm::dot(l.e1, p);
  if (std::abs(det) < 1e-300) return 0.0;
  dvec3 s = o - l.v0, q = glm::cross(s, l.e1);
  double u = glm::dot(s, p) / det, v = glm::dot(d, q) / det, t = glm::dot(l.e2, q) / det;
  if (t <= 0.0 || u < -eps || v < -eps || u + v > 1.0 + eps) return 0.0;
  double cos_l = -glm::dot(l.n, d);
  if (!l.two_sided && cos_l <= 0.0) return -1.0;
  return l.p_over_area * t * t / std::abs(cos_l);
}

double light_pdf(const std::vector<HostLight>& lights, dvec3 o, dvec3 d) {
  double sum = 0.0;
  for (const HostLight& l : lights) sum += std::max(0.0, light_term(l, o, d));
  return sum;
}

// Probabilities of the nz × nphi cells of (cos θ, φ) over the sphere under a solid-angle density:
// adaptive cubature per cell (1e-9 absolute), then, in every cell next to the edge of the
// density's support (a 3 × 3 neighbourhood holding both zero and non-zero cells), again with at
// least 4^5 sub-boxes: a light's edge can cut a sliver off a cell between the coarse nodes.
std::vector<double> cell_probabilities(const std::function<double(double, double)>& pdf, int nz, int nphi) {
  const double dz = 2.0 / nz, dphi = kTwoPi / nphi;
  auto integrate = [&](int i, int j, int min_depth) {
    return integrate_2d(pdf, -1.0 + i * dz, -1.0 + (i + 1) * dz, j * dphi, (j + 1) * dphi, 1e-9, 10, min_depth);
  };
  std::vector<double> p(nz * nphi);
  for (int i = 0; i < nz; ++i)
    for (int j = 0; j < nphi; ++j) p[i * nphi + j] = integrate(i, j, 2);
  std::vector<double> refined = p;
  for (int i = 0; i < nz; ++i)
    for (int j = 0; j < nphi; ++j) {
      bool zero = false, nonzero = false;
      for (int di = -1; di <= 1; ++di)
        for (int dj = -1; dj <= 1; ++dj) {
          int ii = i + di, jj = (j + dj + nphi) % nphi;
          if (ii < 0 || ii >= nz) continue;
          (p[ii * nphi + jj] > 0.0 ? nonzero : zero) = true;
        }
      if (zero && nonzero) refined[i * nphi + j] = integrate(i, j, 5);
    }
  return refined;
}

struct LightCase {
  const char* name;
  fs::path scene;
  dvec3 origin;
  dvec3 axis;  // polar axis of the chart, toward the bulk of the lights for resolution
};

// χ² of the directions sample_lights draws from each origin against the host density integrated
// over 50 × 100 cells in (cos θ, φ) covering the whole sphere (cell_probabilities: 1e-9 per cell
// = 1e-3 samples at n = 2^20, refined along the lights' edges), cells expecting < 5 pooled. Samples the kernel returns with pdf 0 (a
// one-sided light picked from behind) form one more bin expecting n · Σ P(pick) over the lights
// the origin sees from behind. One χ² per origin: 4 tests, Šidák α = 1 − 0.99^(1/4) = 0.00251 each.
// The kernel's pdf must also match the host's for every sample (relative 1e-4; float rounding of
// d² and cos θ_l is ~1e-6 at the angles used here): it is the term of the triangle it sampled,
// so it is matched against each triangle the ray crosses (barycentric slack 1e-5: the kernel aims
// at the light point moved off the light by its rounding-error bound, ~3e-5 units here, which at
// grazing angles moves where the direction crosses the light by a few times that).
TEST(TransportLightSampling, DirectionsFollowPdf) {
  const LightCase cases[] = {
      {"cornell centre", kScenes / "cornell-box.json", {278, 500, 280}, {0, 1, 0}},
      {"cornell corner", kScenes / "cornell-box.json", {180, 500, 380}, {0.3, 1, -0.3}},
      {"lights origin", kTestScenes / "lights.json", {0, 0, 0}, {0, 1, 0}},
      {"lights offset", kTestScenes / "lights.json", {0.3, -0.2, 0.1}, {0.3, 1, 0}},
  };
  const uint32_t n = 1u << 20;
  const int nz = 50, nphi = 100;
  const double alpha = sidak_alpha(0.01, 4);
  uint32_t seed = 1000;
  for (const LightCase& c : cases) {
    SCOPED_TRACE(c.name);
    xi::Scene scene = xi::load_scene(c.scene);
    std::vector<HostLight> lights = host_lights(scene);
    std::vector<vec4> samples = sample_lights(xi::compile_scene(scene), c.origin, n, seed++);
    Frame f(c.axis);

    double p_back = 0.0;  // P(picking a one-sided light whose back faces the origin)
    for (const HostLight& l : lights)
      if (!l.two_sided && glm::dot(l.n, c.origin - l.v0) < 0.0) p_back += l.p_over_area * 0.5 * glm::length(glm::cross(l.e1, l.e2));

    std::vector<double> expected = cell_probabilities(
        [&](double z, double phi) { return light_pdf(lights, c.origin, f.direction(z, phi)); }, nz, nphi);
    double total = 0.0;
    for (double& e : expected) total += e *= n;
    expected.push_back(n * p_back);
    std::vector<double> observed(expected.size(), 0.0);
    EXPECT_NEAR((total + expected.back()) / n, 1.0, 1e-4) << "host density does not integrate to 1";

    size_t bad_pdf = 0, bad_zero = 0;
    for (const vec4& s : samples) {
      dvec3 w = glm::normalize(dvec3(s));
      if (s.w == 0.0f) {  // must be a one-sided light seen from behind
        observed.back() += 1.0;
        bool back = false;
        for (const HostLight& l : lights) back |= light_term(l, c.origin, w, 1e-5) < 0.0;
        if (!back && ++bad_zero <= 5) ADD_FAILURE() << "pdf 0 toward a light seen from the front, wi " << w.x << " " << w.y << " " << w.z;
        continue;
      }
      observed[cell(glm::dot(w, f.n), f.phi(w), -1.0, nz, nphi)] += 1.0;
      bool match = false;
      for (const HostLight& l : lights) {
        double t = light_term(l, c.origin, w, 1e-5);
        match |= t > 0.0 && std::abs(s.w - t) <= 1e-4 * t;
      }
      if (!match && ++bad_pdf <= 5)
        ADD_FAILURE() << "kernel pdf " << s.w << " matches no light crossed (host total " << light_pdf(lights, c.origin, w) << ")";
    }
    EXPECT_EQ(bad_pdf, 0u);
    EXPECT_EQ(bad_zero, 0u);
    Chi2Result r = chi2_test(observed, expected);
    std::printf("  %-15s chi2 %.1f dof %d (pooled %d cells) p = %.4f; pdf-0 samples %.0f (expect %.0f)\n", c.name,
                r.statistic, r.dof, r.pooled_cells, r.p_value, observed.back(), expected.back());
    EXPECT_GT(r.dof, 100) << "too few cells to resolve the lights";
    EXPECT_GE(r.p_value, alpha);
  }
}

// Cosine-weighted BSDF sampling about normals in every octant, including exactly ±z and just off
// −z (the branch of the tangent frame): the histogram over 25 × 50 cells of (cos θ, φ) in a frame
// built here must follow cos θ / π (cell probability (z1² − z0²) Δφ / 2π, exact); no direction
// may fall below the surface (beyond float rounding, 1e-6); each pdf must equal cos θ / π
// (relative 1e-4, plus 1e-6 absolute for directions grazing the horizon). 7 normals: Šidák
// α = 1 − 0.99^(1/7) = 0.00143 per χ².
TEST(TransportBsdfSampling, LambertFollowsCosine) {
  const dvec3 normals[] = {{0, 0, 1}, {0, 0, -1}, {1, 0, 0}, {0, -1, 0}, {1, 2, -3}, {-0.3, 0.2, -0.93},
                           {1e-4, -2e-4, -1}};
  const uint32_t n = 1u << 20;
  const int nz = 25, nphi = 50;
  const double alpha = sidak_alpha(0.01, 7);
  std::vector<double> expected(nz * nphi);
  for (int i = 0; i < nz; ++i)
    for (int j = 0; j < nphi; ++j)
      expected[i * nphi + j] = n * ((i + 1.0) * (i + 1.0) - (double)i * i) / (nz * nz) / nphi;
  uint32_t seed = 2000;
  for (dvec3 normal : normals) {
    Frame f(normal);
    SCOPED_TRACE(testing::Message() << "n = (" << f.n.x << ", " << f.n.y << ", " << f.n.z << ")");
    std::vector<vec4> samples = sample_bsdf(XI_MATERIAL_DIFFUSE, f.n, f.n, 1.0f, true, n, seed++);
    std::vector<double> observed(nz * nphi, 0.0);
    size_t below = 0, bad_pdf = 0, not_unit = 0;
    for (const vec4& s : samples) {
      dvec3 w(s);
      double z = glm::dot(w, f.n);
      below += z < -1e-6;
      not_unit += std::abs(glm::length(w) - 1.0) > 1e-5;
      bad_pdf += !(std::abs(s.w - z / M_PI) <= 1e-4 * z / M_PI + 1e-6);
      observed[cell(z, f.phi(w), 0.0, nz, nphi)] += 1.0;
    }
    EXPECT_EQ(below, 0u);
    EXPECT_EQ(not_unit, 0u);
    EXPECT_EQ(bad_pdf, 0u);
    Chi2Result r = chi2_test(observed, expected);
    std::printf("  n = (%+.3f %+.3f %+.3f): chi2 %.1f dof %d p = %.4f\n", f.n.x, f.n.y, f.n.z, r.statistic, r.dof,
                r.p_value);
    EXPECT_GE(r.p_value, alpha);
  }
}

// Fresnel reflectance of unpolarised light from medium n1 into n2 at incidence cos θ1 (1 under
// total internal reflection), from Snell's law and the s and p amplitude coefficients.
double fresnel(double cos1, double n1, double n2) {
  double sin2 = n1 / n2 * std::sqrt(std::max(0.0, 1.0 - cos1 * cos1));
  if (sin2 >= 1.0) return 1.0;
  double cos2 = std::sqrt(1.0 - sin2 * sin2);
  double rs = (n1 * cos1 - n2 * cos2) / (n1 * cos1 + n2 * cos2);
  double rp = (n2 * cos1 - n1 * cos2) / (n2 * cos1 + n1 * cos2);
  return 0.5 * (rs * rs + rp * rp);
}

// Smooth glass (ior 1.5) about a tilted normal, entering (wo outside) and leaving (wo inside:
// critical angle asin(1/1.5) = 41.81°). The fraction of 2^20 samples that reflect must match
// the Fresnel reflectance R computed above: a binomial z-test, |k − nR| ≤ z √(nR(1 − R)) with
// z = 3.0226 (0.01 Šidák over the 8 cases where 0 < R < 1); where R = 1 (45° and 70° leaving,
// beyond the critical angle) every sample must reflect. A reflected direction must be the mirror
// direction (1e-5); a refracted one must leave on the other side, in the plane of incidence, on
// the far side of the normal, and obey n1 sin θ1 = n2 sin θ2 to 1e-4.
TEST(TransportBsdfSampling, GlassFollowsFresnelAndSnell) {
  struct Case { double degrees; bool entering; };
  const Case cases[] = {{0, true},  {30, true},  {60, true},  {80, true}, {89, true},
                        {20, false}, {35, false}, {41, false}, {45, false}, {70, false}};
  const double ior = 1.5;
  const uint32_t n = 1u << 20;
  const double z = sidak_critical_z(0.01, 8);
  const Frame f(dvec3(0.3, -0.5, 0.8));
  uint32_t seed = 3000;
  for (const Case& c : cases) {
    SCOPED_TRACE(testing::Message() << c.degrees << "° " << (c.entering ? "entering" : "leaving"));
    const double th = glm::radians(c.degrees);
    const dvec3 wo = std::cos(th) * f.n + std::sin(th) * f.t;  // n is on wo's side in both cases
    const double n1 = c.entering ? 1.0 : ior, n2 = c.entering ? ior : 1.0;
    const double R = fresnel(std::cos(th), n1, n2);
    std::vector<vec4> samples = sample_bsdf(XI_MATERIAL_DIELECTRIC, f.n, wo, (float)ior, c.entering, n, seed++);
    const dvec3 mirror = 2.0 * glm::dot(wo, f.n) * f.n - wo;
    size_t reflected = 0, bad_reflect = 0, bad_refract = 0;
    for (const vec4& s : samples) {
      dvec3 w(s);
      if (s.w == 1.0f) {
        ++reflected;
        bad_reflect += glm::length(w - mirror) > 1e-5;
        continue;
      }
      double cos2 = -glm::dot(w, f.n);
      double sin2 = glm::length(w + cos2 * f.n);  // the tangential part
      bool ok = cos2 > 0.0 && std::abs(glm::length(w) - 1.0) < 1e-5 &&
                std::abs(n1 * std::sin(th) - n2 * sin2) < 1e-4 && std::abs(glm::dot(w, f.b)) < 1e-5 &&
                (th == 0.0 || glm::dot(w, f.t) < 0.0);
      bad_refract += !ok;
    }
    EXPECT_EQ(bad_reflect, 0u);
    EXPECT_EQ(bad_refract, 0u);
    const double frac = (double)reflected / n;
    if (R == 1.0) {
      std::printf("  %4.0f° leaving: TIR, reflected %zu of %u\n", c.degrees, reflected, n);
      EXPECT_EQ(reflected, n) << "total internal reflection must always reflect";
    } else {
      double zs = (reflected - n * R) / std::sqrt(n * R * (1.0 - R));
      std::printf("  %4.0f° %-8s: R = %.6f, reflected %.6f, z = %+.2f\n", c.degrees,
                  c.entering ? "entering" : "leaving", R, frac, zs);
      EXPECT_LE(std::abs(zs), z) << "fraction reflected " << frac << " vs Fresnel " << R;
    }
  }
}

// ---------------------------------------------------------------------------------------------
// Renders

using Render = xi::test::Shot;
using xi::test::MeanSe;
using xi::test::render_options;
using xi::test::render_shot;

// A rectangle of pixels [x0, x1) × [y0, y1) that sees one material of albedo `albedo` only.
struct Region {
  const char* name;
  int x0, y0, x1, y1;
  vec3 albedo;
};

// The region's mean of channel c and the standard error of that mean.
MeanSe region_stat(const Render& r, const Region& g, int c) {
  return xi::test::block_mean(r, g.x0, g.y0, g.x1, g.y1, c);
}

// Every pixel of the region saw only the intended surface (first-hit albedo), so the region is
// where it is meant to be.
void expect_region_sees(const Render& r, const Region& g) {
  for (int y = g.y0; y < g.y1; ++y)
    for (int x = g.x0; x < g.x1; ++x)
      ASSERT_LT(glm::length(r.albedo.at(x, y) - g.albedo), 1e-4f) << g.name << " pixel " << x << "," << y;
}

Region block_at(const char* name, const xi::Scene& s, int w, int h, dvec3 p, int size, vec3 albedo) {
  const glm::dvec2 q = xi::test::View(s, w, h).film(p);  // analytic.h
  int x0 = (int)std::lround(q.x) - size / 2, y0 = (int)std::lround(q.y) - size / 2;
  return {name, x0, y0, x0 + size, y0 + size, albedo};
}

// The regions of two renders agree: per region and channel, |m_a − m_b| ≤ z √(se_a² + se_b²).
void expect_same_means(const Render& a, const Render& b, const std::vector<Region>& regions, double z,
                       const char* label) {
  for (const Region& g : regions)
    for (int c = 0; c < 3; ++c) {
      MeanSe sa = region_stat(a, g, c), sb = region_stat(b, g, c);
      double se = std::hypot(sa.se, sb.se), zs = (sa.mean - sb.mean) / se;
      std::printf("  %-12s %-10s %c: %.5f ± %.5f vs %.5f ± %.5f  z = %+.2f\n", label, g.name, "RGB"[c], sa.mean, sa.se,
                  sb.mean, sb.se, zs);
      EXPECT_GT(sa.se, 0.0);
      EXPECT_LE(std::abs(zs), z) << label << " " << g.name << " channel " << "RGB"[c];
    }
}

// MIS, light sampling alone and BSDF sampling alone are three unbiased estimators of the same
// image: region means must agree pairwise. Regions × 3 pairs × 3 channels z-tests per scene.
// A wrong MIS weight (not summing to 1), a missing cosine or a wrong light pdf biases one
// strategy against the others by far more than the standard errors printed. BSDF sampling alone is noisier (it must hit the light by chance), hence 4× the samples.
TEST(TransportMis, StrategiesAgreeCornellBox) {
  const xi::Scene scene = xi::load_scene(kScenes / "cornell-box.json");
  const int res = 48;
  // Scaled from test_end_to_end.cpp's 64 × 64 regions and checked by the first-hit albedo.
  const vec3 white(0.725f, 0.71f, 0.68f);
  const std::vector<Region> regions = {{"back_wall", 15, 12, 33, 18, white},
                                       {"floor", 8, 43, 21, 46, white},
                                       {"light", 21, 6, 27, 7, vec3(0.78f)},
                                       {"red_wall", 2, 18, 7, 30, vec3(0.63f, 0.065f, 0.05f)}};
  Render mis = render_shot(scene, res, res, render_options(256, 11, xi::Strategy::Mis));
  Render nee = render_shot(scene, res, res, render_options(256, 12, xi::Strategy::Nee));
  Render bsdf = render_shot(scene, res, res, render_options(1024, 13, xi::Strategy::Bsdf));
  for (const Region& g : regions) expect_region_sees(mis, g);
  // 4 regions × 3 pairs × 3 channels = 36 tests: z = 3.6637.
  const double z = sidak_critical_z(0.01, 36);
  expect_same_means(mis, nee, regions, z, "mis-nee");
  expect_same_means(mis, bsdf, regions, z, "mis-bsdf");
  expect_same_means(nee, bsdf, regions, z, "nee-bsdf");
}

// The same on scenes/soft-shadows.json (a 70 × 70 light at height 90 over a 30 × 30 occluder at
// height 30): on the floor, |x| or |z| > 40 is fully lit, the penumbra is 5 < |z| < 40 at x = 0.
// 3 regions (4 × 4 pixel blocks at world points) × 3 pairs × 3 channels = 27 tests: z = 3.5853.
TEST(TransportMis, StrategiesAgreeSoftShadows) {
  const xi::Scene scene = xi::load_scene(kScenes / "soft-shadows.json");
  const int res = 48;
  const std::vector<Region> regions = {block_at("lit_floor", scene, res, res, {0, 0, -75}, 4, vec3(0.7f)),
                                       block_at("penumbra", scene, res, res, {0, 0, -25}, 4, vec3(0.7f)),
                                       block_at("occluder", scene, res, res, {0, 30.5, 0}, 4, vec3(0.6f, 0.3f, 0.2f))};
  const int depth = scene.render.max_depth;
  Render mis = render_shot(scene, res, res, render_options(256, 21, xi::Strategy::Mis, depth));
  Render nee = render_shot(scene, res, res, render_options(256, 22, xi::Strategy::Nee, depth));
  Render bsdf = render_shot(scene, res, res, render_options(1024, 23, xi::Strategy::Bsdf, depth));
  for (const Region& g : regions) expect_region_sees(mis, g);
  const double z = sidak_critical_z(0.01, 27);
  expect_same_means(mis, nee, regions, z, "mis-nee");
  expect_same_means(mis, bsdf, regions, z, "mis-bsdf");
  expect_same_means(nee, bsdf, regions, z, "nee-bsdf");
}

// ---------------------------------------------------------------------------------------------
// White furnace: a sphere of albedo 1 in a uniform background of radiance 1, no emitters. Nothing
// absorbs, so every pixel's expected value is exactly 1, on the sphere or not.

struct FurnaceStats {
  size_t sphere = 0, background = 0, edge = 0;  // pixels by first-hit albedo: 1, 0, in between
  double worst = 0.0;                           // max |pixel mean − 1| over all pixels and channels
  MeanSe sphere_mean;                           // over the sphere's pixels, channel 0
};

FurnaceStats furnace_stats(const Render& r) {
  FurnaceStats s;
  double var = 0.0;
  for (size_t i = 0; i < r.mean.pixels.size(); ++i) {
    float a = r.albedo.pixels[i].x;
    for (int c = 0; c < 3; ++c) s.worst = std::max(s.worst, std::abs((double)r.mean.pixels[i][c] - 1.0));
    if (a == 0.0f) {
      ++s.background;
    } else if (std::abs(a - 1.0f) < 1e-6f) {
      ++s.sphere;
      s.sphere_mean.mean += r.mean.pixels[i].x;
      var += r.variance.pixels[i].x;
    } else {
      ++s.edge;
    }
  }
  s.sphere_mean.mean /= s.sphere;
  s.sphere_mean.se = std::sqrt(var) / s.sphere;
  return s;
}

// (a) Diffuse and (c) mirror: a flat-shaded convex polyhedron (tests/data/scenes/flat-sphere.obj,
// an icosphere without vertex normals). A path hits it at most once, scatters with weight
// albedo = 1 into the open hemisphere of the face and escapes to the background: every sample is
// exactly 1 (the product 1 · 1 in float), so the estimator has zero variance and the z-test
// degenerates; instead every pixel (sphere, background and silhouette) must be 1 to 1e-4 — far
// below any absorption, lost path (self-intersection, a direction sampled below the face, Russian
// roulette firing) or double counting, each of which moves whole samples by O(1).
TEST(TransportFurnace, DiffuseAndMirrorSpheresAreExact) {
  for (const char* file : {"furnace-diffuse.json", "furnace-mirror.json"}) {
    SCOPED_TRACE(file);
    xi::Scene scene = xi::load_scene(kTestScenes / file);
    for (const xi::Triangle& t : scene.triangles) ASSERT_FALSE(t.has_normals);
    Render r = render_shot(scene, 32, 32, render_options(16, 31, xi::Strategy::Mis, 8));
    FurnaceStats s = furnace_stats(r);
    std::printf("  %s: sphere %zu px, background %zu px, edge %zu px; max |pixel − 1| = %.3g\n", file, s.sphere,
                s.background, s.edge, s.worst);
    EXPECT_EQ(r.nonfinite, 0u);
    EXPECT_GT(s.sphere, 300u);
    EXPECT_GT(s.background, 100u);
    EXPECT_LT(s.worst, 1e-4);
  }
}

// (a') The same diffuse sphere as the smooth icosphere (5 subdivisions, vertex normals). The
// renderer samples the cosine lobe about the interpolated shading normal and ends a path whose
// direction falls below the face; a lobe tilted by δ from the face normal loses (1 − cos δ)/2 of
// its mass there (it projects to the uniform disc, which the face cuts along an ellipse of
// semi-axis cos δ). So each sphere pixel's expected value lies in [1 − ε, 1] with
// ε = (1 − cos δmax)/2, δmax the largest tilt of a vertex normal from its face (measured below,
// 1.37°, ε = 1.4e-4). Over the sphere's pixels: mean ∈ [1 − ε − z·SE, 1 + z·SE], z = 2.5758 (one
// test at 0.01); the kills make the variance non-zero, so the z-test is valid. Background: 1.
TEST(TransportFurnace, SmoothDiffuseSphereLosesOnlyBelowTheFace) {
  xi::Scene scene = xi::load_scene(kTestScenes / "furnace-diffuse-smooth.json");
  double cos_min = 1.0;
  for (const xi::Triangle& t : scene.triangles) {
    ASSERT_TRUE(t.has_normals);
    const glm::vec3 &p0 = scene.position(t, 0), &p1 = scene.position(t, 1), &p2 = scene.position(t, 2);
    dvec3 ng = glm::normalize(glm::cross(dvec3(p1 - p0), dvec3(p2 - p0)));
    for (int k = 0; k < 3; ++k) cos_min = std::min(cos_min, glm::dot(ng, glm::normalize(dvec3(scene.normal(t, k)))));
  }
  const double eps = (1.0 - cos_min) / 2.0, z = sidak_critical_z(0.01, 1);
  Render r = render_shot(scene, 32, 32, render_options(256, 35, xi::Strategy::Mis, 8));
  FurnaceStats s = furnace_stats(r);
  double background_worst = 0.0;
  for (size_t i = 0; i < r.mean.pixels.size(); ++i)
    if (r.albedo.pixels[i].x == 0.0f) background_worst = std::max(background_worst, std::abs(r.mean.pixels[i].x - 1.0));
  std::printf("  smooth diffuse: sphere %zu px mean %.6f ± %.6f (loss %.2g), bound ε = %.2g (δmax = %.2f°)\n", s.sphere,
              s.sphere_mean.mean, s.sphere_mean.se, 1.0 - s.sphere_mean.mean, eps, glm::degrees(std::acos(cos_min)));
  EXPECT_EQ(r.nonfinite, 0u);
  EXPECT_LT(eps, 1e-3);
  EXPECT_LT(background_worst, 1e-6);
  EXPECT_GE(s.sphere_mean.mean, 1.0 - eps - z * s.sphere_mean.se);
  EXPECT_LE(s.sphere_mean.mean, 1.0 + z * s.sphere_mean.se);
}

// (b) Glass sphere (ior 1.5, the smooth icosphere with vertex normals): each scattering picks
// reflection or refraction with weight 1, so every path that escapes carries exactly 1 (times
// the unbiased Russian roulette factor); only the depth cap (64) loses energy. For a sphere a
// refracted path meets every internal hit at the same angle, reflecting with the same Fresnel R
// as at entry, so it is lost with probability (1 − R) R^63; averaged over the sphere's disc
// (uniform in impact parameter², computed below) this is < 1e-5, far below the standard error.
// Background pixels see only the background: exactly 1. The sphere's pixels: a z-test that
// allows that loss, mean ∈ [1 − loss − z·SE, 1 + z·SE] with z = 2.5758 (one test at 0.01); all
// samples are independent (random sampler).
TEST(TransportFurnace, GlassSphereConservesEnergy) {
  xi::Scene scene = xi::load_scene(kTestScenes / "furnace-glass.json");
  double loss = 0.0;
  const int steps = 100000;
  for (int i = 0; i < steps; ++i) {  // midpoint rule in b² = sin² θ
    double b2 = (i + 0.5) / steps, R = fresnel(std::sqrt(1.0 - b2), 1.0, 1.5);
    loss += (1.0 - R) * std::pow(R, 63) / steps;
  }
  Render r = render_shot(scene, 32, 32, render_options(256, 41, xi::Strategy::Mis, 64));
  FurnaceStats s = furnace_stats(r);
  const double z = sidak_critical_z(0.01, 1);
  double background_worst = 0.0;
  for (size_t i = 0; i < r.mean.pixels.size(); ++i)
    if (r.albedo.pixels[i].x == 0.0f) background_worst = std::max(background_worst, std::abs(r.mean.pixels[i].x - 1.0));
  std::printf("  glass: sphere %zu px mean %.5f ± %.5f (z = %+.2f), depth-cap loss bound %.2g; background max "
              "|px − 1| = %.3g\n",
              s.sphere, s.sphere_mean.mean, s.sphere_mean.se, (s.sphere_mean.mean - 1.0) / s.sphere_mean.se, loss,
              background_worst);
  EXPECT_EQ(r.nonfinite, 0u);
  EXPECT_GT(s.sphere, 300u);
  EXPECT_LT(loss, 1e-4);
  EXPECT_LT(background_worst, 1e-6);
  EXPECT_GT(s.sphere_mean.se, 0.0);
  EXPECT_LE(std::abs(s.sphere_mean.mean - 1.0 + loss / 2), z * s.sphere_mean.se + loss / 2);
}

// ---------------------------------------------------------------------------------------------
// Every bundled scene renders at 16 spp at 48 × 48 (the scene's own depth and sampler) without a
// non-finite value or a dropped sample, and is not black: at least a quarter of the pixels lit.
TEST(TransportScenes, BundledScenesRenderFinite) {
  for (const char* name : {"cornell-box", "soft-shadows", "caustics", "depth-of-field", "mirror"}) {
    SCOPED_TRACE(name);
    xi::Scene scene = xi::load_scene(kScenes / (std::string(name) + ".json"));
    Render r = render_shot(scene, 48, 48,
                      render_options(16, 51, xi::Strategy::Mis, scene.render.max_depth, xi::parse_sampler(scene.render.sampler)));
    EXPECT_EQ(r.nonfinite, 0u);
    size_t bad = 0, lit = 0;
    for (size_t i = 0; i < r.mean.pixels.size(); ++i) {
      for (int c = 0; c < 3; ++c) bad += !std::isfinite(r.mean.pixels[i][c]) || !std::isfinite(r.variance.pixels[i][c]);
      lit += r.mean.pixels[i].x + r.mean.pixels[i].y + r.mean.pixels[i].z > 0.0f;
    }
    std::printf("  %-15s lit %zu of %zu pixels\n", name, lit, r.mean.pixels.size());
    EXPECT_EQ(bad, 0u);
    EXPECT_GT(lit, r.mean.pixels.size() / 4);
  }
}

// ---------------------------------------------------------------------------------------------
// Feature specialisation

bool has(const std::vector<std::string>& defines, const std::string& d) {
  return std::find(defines.begin(), defines.end(), d) != defines.end();
}

TEST(TransportFeatures, KernelDefinesFollowTheScene) {
  auto word = [](const char* name, xi::Strategy s = xi::Strategy::Mis) {
    xi::KernelConfig c;
    c.features = xi::compile_scene(xi::load_scene(kScenes / name)).features;
    c.strategy = s;
    EXPECT_TRUE(has(c.shading_defines(), "XI_SHADING=" + std::to_string(c.shading_word())));
    EXPECT_FALSE(has(c.as_generic().shading_defines(), "XI_SHADING=" + std::to_string(c.shading_word())));
    EXPECT_TRUE(has(c.as_generic().shading_defines(), "XI_GENERIC"));
    return c.shading_word();
  };
  const uint32_t cornell = word("cornell-box.json");
  EXPECT_FALSE(xi_uses(cornell, XI_USE_DIELECTRIC));
  EXPECT_FALSE(xi_uses(cornell, XI_USE_MIRROR));
  EXPECT_FALSE(xi_uses(cornell, XI_USE_LENS));
  EXPECT_FALSE(xi_uses(cornell, XI_USE_NORMALS));
  EXPECT_TRUE(xi_uses(cornell, XI_USE_EMITTERS));
  EXPECT_TRUE(xi_uses(cornell, XI_USE_NEE));
  EXPECT_TRUE(xi_uses(cornell, XI_USE_MIS));
  EXPECT_EQ(xi_sampler_of(cornell), XI_SAMPLER_SOBOL);
  EXPECT_TRUE(xi_uses(word("caustics.json"), XI_USE_DIELECTRIC));
  EXPECT_TRUE(xi_uses(word("caustics.json"), XI_USE_NORMALS));
  EXPECT_TRUE(xi_uses(word("mirror.json"), XI_USE_MIRROR));
  EXPECT_TRUE(xi_uses(word("depth-of-field.json"), XI_USE_LENS));
  const uint32_t nee = word("cornell-box.json", xi::Strategy::Nee);
  EXPECT_TRUE(xi_uses(nee, XI_USE_NEE));
  EXPECT_FALSE(xi_uses(nee, XI_USE_MIS));
  const uint32_t bsdf = word("cornell-box.json", xi::Strategy::Bsdf);
  EXPECT_FALSE(xi_uses(bsdf, XI_USE_NEE));
  EXPECT_FALSE(xi_uses(bsdf, XI_USE_MIS));
  EXPECT_TRUE(xi_uses(bsdf, XI_USE_EMITTERS));
}

// KernelConfig::make chooses for the device where the options leave it open, and follows the options
// where they do not; a tree too large for packets of bounce rays gets none under Auto.
TEST(TransportFeatures, KernelConfigFollowsDeviceSceneAndOptions) {
  xi::DeviceInfo cpu, gpu;
  cpu.type = "CPU";
  gpu.type = "GPU";
  const xi::Scene cornell = xi::load_scene(kScenes / "cornell-box.json");
  xi::RenderOptions opt;
  ASSERT_EQ(xi::KernelConfig::bvh_width_for(cpu, opt), 8);
  ASSERT_EQ(xi::KernelConfig::bvh_width_for(gpu, opt), 4);
  const xi::CompiledScene wide = xi::compile_scene(cornell, 8), narrow = xi::compile_scene(cornell, 4);
  // A CPU device's lanes and packets follow its CPU's vectors: 16 lanes with AVX2 or AVX-512, packets
  // of 16 rays with 512-bit vectors, else 8; a GPU's do not.
  struct Widths {
    xi::CpuVectors cpu;
    int lanes, packet_width;
  };
  for (const Widths& w : {Widths{{false, false}, 8, 8}, Widths{{true, false}, 16, 8}, Widths{{true, true}, 16, 16}}) {
    SCOPED_TRACE(testing::Message() << "avx2 " << w.cpu.avx2 << ", avx512 " << w.cpu.avx512);
    const xi::KernelConfig for_cpu = xi::KernelConfig::make(cpu, wide, opt, w.cpu),
                           for_gpu = xi::KernelConfig::make(gpu, narrow, opt, w.cpu);
    EXPECT_EQ(for_cpu.lanes, w.lanes);
    EXPECT_EQ(for_cpu.packet_width, w.packet_width);
    EXPECT_EQ(for_gpu.lanes, 1);
    EXPECT_EQ(for_gpu.packet_width, 8);
  }
  // By default the CPU this runs on, whose AVX2 needs FMA too.
  const xi::KernelConfig on_cpu = xi::KernelConfig::make(cpu, wide, opt);
#if defined(__x86_64__) || defined(__i386__)
  const bool avx512 = __builtin_cpu_supports("avx512f");
  const int cpu_lanes = avx512 || (__builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma")) ? 16 : 8;
  const int cpu_width = avx512 ? 16 : 8;
#else
  const int cpu_lanes = 8, cpu_width = 8;
#endif
  EXPECT_EQ(on_cpu.lanes, cpu_lanes);
  EXPECT_EQ(on_cpu.bvh_width, 8);
  EXPECT_TRUE(on_cpu.cpu_device);
  EXPECT_TRUE(on_cpu.ray_packets);  // the Cornell box's tree is one or two nodes
  EXPECT_FALSE(on_cpu.hybrid_packets);
  EXPECT_EQ(on_cpu.packet_width, cpu_width);
  EXPECT_EQ(on_cpu.features, wide.features);
  const xi::KernelConfig on_gpu = xi::KernelConfig::make(gpu, narrow, opt);
  EXPECT_EQ(on_gpu.lanes, 1);
  EXPECT_EQ(on_gpu.bvh_width, 4);
  EXPECT_FALSE(on_gpu.cpu_device);
  EXPECT_FALSE(on_gpu.ray_packets);  // packets need an 8-wide tree
  EXPECT_FALSE(on_gpu.hybrid_packets);
  EXPECT_EQ(on_gpu.packet_width, 8);

  opt.lanes = 1;
  opt.bvh_width = 4;
  opt.ray_packets = xi::RenderOptions::RayPackets::Off;
  opt.all_features = true;
  opt.sampler = XI_SAMPLER_STRATIFIED;
  opt.strategy = xi::Strategy::Nee;
  const xi::KernelConfig chosen = xi::KernelConfig::make(cpu, narrow, opt);
  EXPECT_EQ(chosen.lanes, 1);
  EXPECT_EQ(chosen.bvh_width, 4);
  EXPECT_FALSE(chosen.ray_packets);
  EXPECT_FALSE(chosen.hybrid_packets);
  EXPECT_EQ(chosen.features, xi::Features::everything());
  EXPECT_EQ(chosen.sampler, XI_SAMPLER_STRATIFIED);
  EXPECT_EQ(chosen.strategy, xi::Strategy::Nee);

  const xi::Scene engine = xi::load_scene(fs::path(XI_SCENE_DIR).parent_path() / "bench/scenes/engine.json");
  // A large tree: the rays leaving the camera rays' hits in hybrid packets, unless told otherwise;
  // the Cornell box's small one in hybrid packets when told so; none with cut-outs or a 4-wide tree.
  const xi::CompiledScene engine8 = xi::compile_scene(engine, 8);
  using RayPackets = xi::RenderOptions::RayPackets;
  struct Case {
    const xi::CompiledScene& scene;
    RayPackets choice;
    bool packets, hybrid;
  };
  for (const Case& c : {Case{engine8, RayPackets::Auto, false, true}, Case{engine8, RayPackets::On, true, false},
                        Case{engine8, RayPackets::Hybrid, false, true}, Case{engine8, RayPackets::Off, false, false},
                        Case{wide, RayPackets::Hybrid, false, true}, Case{wide, RayPackets::Off, false, false},
                        Case{narrow, RayPackets::Hybrid, false, false}}) {
    opt = xi::RenderOptions{};
    opt.ray_packets = c.choice;
    const xi::KernelConfig k = xi::KernelConfig::make(cpu, c.scene, opt);
    EXPECT_EQ(k.ray_packets, c.packets) << (int)c.choice << ", " << c.scene.bvh.width << "-wide";
    EXPECT_EQ(k.hybrid_packets, c.hybrid) << (int)c.choice << ", " << c.scene.bvh.width << "-wide";
  }
  xi::CompiledScene cutouts = engine8;
  cutouts.features.alpha = true;
  opt = xi::RenderOptions{};
  EXPECT_FALSE(xi::KernelConfig::make(cpu, cutouts, opt).hybrid_packets);

  for (int width : {8, 16}) {
    opt = xi::RenderOptions{};
    opt.packet_width = width;
    EXPECT_EQ(xi::KernelConfig::make(cpu, wide, opt).packet_width, width);
    EXPECT_EQ(xi::KernelConfig::make(gpu, narrow, opt).packet_width, width);
  }
  opt.packet_width = 4;
  EXPECT_THROW(xi::KernelConfig::make(cpu, wide, opt), xi::Error);

  opt = xi::RenderOptions{};
  opt.lanes = 4;
  EXPECT_THROW(xi::KernelConfig::make(cpu, wide, opt), xi::Error);
  opt = xi::RenderOptions{};
  opt.bvh_width = 2;
  EXPECT_THROW(xi::KernelConfig::bvh_width_for(cpu, opt), xi::Error);
}

// Every field of the configuration reaches the flags, so that no two configurations share a cached
// binary (build_program hashes the flags), and describe() names every field's value.
TEST(TransportFeatures, EveryKernelOptionChangesTheFlags) {
  const xi::KernelConfig base;
  std::vector<xi::KernelConfig> variants(11, base);
  variants[0].features.mirror = true;
  variants[1].features.lens = true;
  variants[2].sampler = XI_SAMPLER_RANDOM;
  variants[3].strategy = xi::Strategy::Bsdf;
  variants[3].features.emitters = variants[4].features.emitters = true;  // strategies matter with lights
  variants[5].lanes = 8;
  variants[6].bvh_width = 8;
  variants[7].ray_packets = true;
  variants[8].generic = true;
  variants[9].packet_width = 16;
  variants[10].hybrid_packets = true;
  std::vector<std::vector<std::string>> flags{base.defines()};
  for (const xi::KernelConfig& v : variants) flags.push_back(v.defines());
  for (size_t i = 0; i < flags.size(); ++i)
    for (size_t j = i + 1; j < flags.size(); ++j) EXPECT_NE(flags[i], flags[j]) << i << " and " << j;
  xi::KernelConfig cpu = base;
  cpu.cpu_device = true;
  EXPECT_TRUE(has(cpu.defines(), "XI_CPU_DEVICE"));
  EXPECT_FALSE(has(base.defines(), "XI_CPU_DEVICE"));
  EXPECT_EQ(variants[7].describe(), "diffuse; sampler sobol; strategy mis; lanes 1; bvh 4-wide; ray packets on");
  EXPECT_EQ(variants[8].describe(),
            "generic shading; lanes 1; bvh 4-wide; ray packets off");
  EXPECT_EQ(variants[10].describe(), "diffuse; sampler sobol; strategy mis; lanes 1; bvh 4-wide; ray packets hybrid");
  // The tracing stages' flags do not depend on the scene's materials, sampler or strategy.
  for (int k : {0, 1, 2, 3, 4, 8}) EXPECT_EQ(variants[k].trace_defines(), base.trace_defines()) << k;
  EXPECT_EQ(cpu.describe(), "diffuse; sampler sobol; strategy mis; lanes 1; bvh 4-wide; ray packets off; cpu device");
  xi::KernelConfig wide = variants[9];
  wide.bvh_width = 8;
  EXPECT_EQ(wide.describe(),
            "diffuse; sampler sobol; strategy mis; lanes 1; bvh 8-wide; packets of 16 rays; ray packets off");
}

// Features a scene does not use must change nothing: the Cornell box built with every feature
// (mirror, glass, vertex normals, lens with radius 0) converges to the same region means as the
// specialised build. 4 regions × 3 channels = 12 z-tests: z = 3.3382.
TEST(TransportFeatures, AllFeaturesBuildMatchesSpecialised) {
  const xi::Scene scene = xi::load_scene(kScenes / "cornell-box.json");
  const vec3 white(0.725f, 0.71f, 0.68f);
  const std::vector<Region> regions = {{"back_wall", 15, 12, 33, 18, white},
                                       {"floor", 8, 43, 21, 46, white},
                                       {"light", 21, 6, 27, 7, vec3(0.78f)},
                                       {"red_wall", 2, 18, 7, 30, vec3(0.63f, 0.065f, 0.05f)}};
  xi::RenderOptions all = render_options(256, 62);
  all.all_features = true;
  Render a = render_shot(scene, 48, 48, all), b = render_shot(scene, 48, 48, render_options(256, 61));
  for (const Region& g : regions) expect_region_sees(a, g);
  EXPECT_EQ(a.nonfinite, 0u);
  expect_same_means(a, b, regions, sidak_critical_z(0.01, 12), "all-special");
}

}  // namespace
