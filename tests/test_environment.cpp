// The environment light (kernels/shared/environment.h, host/src/scene/environment.cpp), on the host:
// χ² goodness of fit of xi_env_sample against xi_env_pdf, the pdf's normalisation and agreement
// with the sampler, Mitsuba 3's orientation and the rotation, the gain of importance sampling over
// cosine sampling, the loader's errors, and the bundled scenes/sky.hdr. Host only (no device).
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <random>
#include <string>
#include <vector>

#include <unistd.h>

#include <glm/glm.hpp>

#include "environment.h"
#include "fixtures.h"
#include "stats.h"
#include "warps.h"
#include "xi/environment.h"
#include "xi/error.h"
#include "xi/image.h"

namespace {

using namespace xi::stats;
namespace fs = std::filesystem;

constexpr double kTwoPi2 = 2.0 * M_PI * M_PI;

// ξ in [0, 1): 24 random bits (std::uniform_real_distribution<float> may round up to 1).
struct Rng {
  std::mt19937 gen;
  explicit Rng(uint32_t seed) : gen(seed) {}
  float next() { return (float)(gen() >> 8) * 0x1p-24f; }
  float2 next2() {
    float a = next();
    return float2(a, next());
  }
};

double lum(glm::vec3 c) { return 0.2126 * c.x + 0.7152 * c.y + 0.0722 * c.z; }

// The test map: a smooth gradient (brighter and bluer toward the zenith) plus a one-texel "sun" at
// 40° elevation of about 1.2e-4 sr holding 90% of the power.
constexpr int kW = 512, kH = 256;
constexpr int kSunX = 180, kSunY = 71;  // θ = π (71.5/256) ≈ 50.3°
std::vector<glm::vec4> gradient_texels() {
  std::vector<glm::vec4> t((size_t)kW * kH);
  for (int y = 0; y < kH; ++y) {
    double v = (y + 0.5) / kH;
    for (int x = 0; x < kW; ++x) {
      double u = (x + 0.5) / kW, g = 0.2 + 0.8 * (1.0 - v) + 0.1 * std::sin(2.0 * M_PI * u);
      t[(size_t)y * kW + x] = glm::vec4(0.6 * g, 0.8 * g, 1.0 * g, 0.0);
    }
  }
  return t;
}
// sun_scale: the sun's radiance relative to the 90%-share one.
xi::EnvironmentMap sun_map(double sun_scale = 1.0) {
  std::vector<glm::vec4> t = gradient_texels();
  xi::EnvironmentMap g = xi::make_environment(kW, kH, t, "gradient");
  double omega = (std::cos(M_PI * kSunY / kH) - std::cos(M_PI * (kSunY + 1) / kH)) * 2.0 * M_PI / kW;
  double sun_lum = 9.0 * g.mean_luminance * 4.0 * M_PI / omega * sun_scale;  // 9 : 1
  t[(size_t)kSunY * kW + kSunX] += glm::vec4(sun_lum, sun_lum, sun_lum, 0.0f);
  return xi::make_environment(kW, kH, std::move(t), "sun");
}
const xi::EnvironmentMap& the_sun_map() {
  static xi::EnvironmentMap m = sun_map();
  return m;
}

// A 256 × 128 sky (the gradient above, dimmed) with a small sun: the 13 texels within 2 texels of
// (200, 40), radiance 900, most of the map's power in a source a few texels wide.
xi::EnvironmentMap small_sun_map() {
  const int w = 256, h = 128, cx = 200, cy = 40;
  std::vector<glm::vec4> t((size_t)w * h);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      double u = (x + 0.5) / w, v = (y + 0.5) / h, g = 0.2 + 0.8 * (1.0 - v) + 0.1 * std::sin(2.0 * M_PI * u);
      t[(size_t)y * w + x] = glm::vec4(0.3 * g, 0.4 * g, 0.5 * g, 0.0);
      if ((x - cx) * (x - cx) + (y - cy) * (y - cy) <= 4) t[(size_t)y * w + x] = glm::vec4(900.0f, 900.0f, 900.0f, 0.0f);
    }
  return xi::make_environment(w, h, std::move(t), "small sun");
}

glm::dvec3 uv_direction(double u, double v) {  // Mitsuba 3's uv_to_direction, in double
  double phi = 2.0 * M_PI * u, theta = M_PI * v;
  return {std::sin(phi) * std::sin(theta), std::cos(theta), -std::cos(phi) * std::sin(theta)};
}
float3 to_float3(glm::dvec3 d) { return float3((float)d.x, (float)d.y, (float)d.z); }

// The probability of each bilinear patch (x, k), k ≤ H, read from the CDF as
// xi_env_patch_probability reads it, in double.
std::vector<double> patch_probabilities(const xi::EnvironmentMap& m) {
  const int w = m.width, rows = m.height + 1;
  std::vector<double> p((size_t)w * rows);
  for (int k = 0; k < rows; ++k) {
    double pk = (double)m.cdf[k] - (k ? (double)m.cdf[k - 1] : 0.0);
    const float* row = m.cdf.data() + rows + (size_t)k * w;
    for (int x = 0; x < w; ++x) p[(size_t)k * w + x] = pk * ((double)row[x] - (x ? (double)row[x - 1] : 0.0));
  }
  return p;
}

// The corner weights of patch (x, k) as the kernels read them: upper (a, b), lower (c, d).
std::array<double, 4> patch_corners(const xi::EnvironmentMap& m, int x, int k) {
  const float* v = m.cdf.data() + XI_ENV_WEIGHT_OFFSET((size_t)m.width, (size_t)m.height);
  const int x1 = (x + 1) % m.width;
  const float* upper = v + (size_t)k * m.width;
  const float* lower = upper + m.width;
  return {upper[x], upper[x1], lower[x], lower[x1]};
}

// ∫ of (1 − s) and of s over [s0, s1].
std::array<double, 2> linear_integrals(double s0, double s1) {
  const double half_sq = 0.5 * (s1 * s1 - s0 * s0);
  return {(s1 - s0) - half_sq, half_sq};
}

// The exact probability of the (u, v) rectangle [u0, u1] × [v0, v1] ⊂ [0, 1]² under the density
// (environment.h): each patch's probability times the share of its bilinear density inside.
double rect_probability(const xi::EnvironmentMap& m, const std::vector<double>& patches, double u0, double u1,
                        double v0, double v1) {
  const int w = m.width, h = m.height;
  double total = 0.0;
  for (int k = 0; k <= h; ++k) {
    const double top = std::max(0.0, (k - 0.5) / h), bottom = std::min(1.0, (k + 0.5) / h);
    const double t0 = std::clamp((v0 - top) / (bottom - top), 0.0, 1.0), t1 = std::clamp((v1 - top) / (bottom - top), 0.0, 1.0);
    if (t1 <= t0) continue;
    const std::array<double, 2> bt = linear_integrals(t0, t1);
    for (int x = 0; x < w; ++x) {
      const double p = patches[(size_t)k * w + x];
      if (p <= 0.0) continue;
      const std::array<double, 4> c = patch_corners(m, x, k);
      const double mean = 0.25 * (c[0] + c[1] + c[2] + c[3]);
      for (double shift : {0.0, -1.0}) {  // the last column's patch wraps around to u = 0
        const double left = (x + 0.5) / w + shift;
        const double s0 = std::clamp((u0 - left) * w, 0.0, 1.0), s1 = std::clamp((u1 - left) * w, 0.0, 1.0);
        if (s1 <= s0) continue;
        const std::array<double, 2> bs = linear_integrals(s0, s1);
        const double inside = bt[0] * (bs[0] * c[0] + bs[1] * c[1]) + bt[1] * (bs[0] * c[2] + bs[1] * c[3]);
        total += p * inside / mean;
      }
    }
  }
  return total;
}

// Samples of xi_env_sample with the map's texels and cdf (which may be another map's).
struct Samples {
  std::vector<glm::vec3> dirs;
  std::vector<float> pdfs;
  std::vector<glm::vec3> radiance;
};
Samples draw(const xi::EnvironmentMap& texels_of, const std::vector<float>& cdf, const EnvironmentData& env, int n,
             uint32_t seed) {
  Rng rng(seed);
  Samples s;
  s.dirs.reserve(n);
  s.pdfs.reserve(n);
  s.radiance.reserve(n);
  for (int i = 0; i < n; ++i) {
    float pdf;
    float3 rad;
    float3 d = xi_env_sample(texels_of.texels.data(), cdf.data(), env, rng.next2(), &pdf, &rad);
    s.dirs.push_back(d);
    s.pdfs.push_back(pdf);
    s.radiance.push_back(rad);
  }
  return s;
}

// χ² charts, both with exact expectations (rect_probability integrates the bilinear patches):
// (u, v) blocks of 16 × 16 texels, and the sphere in (cos θ, φ), whose cells are (u, v) rectangles
// with v = acos(cos θ)/π. Family: the charts of the correct sampler, on two maps, at 1%
// family-wise, Šidák-corrected; the wrong samplers must be rejected at the same per-test level.
constexpr int kUvA = 32, kUvB = 16;      // chart A: 32 × 16 blocks
constexpr int kSphZ = 16, kSphPhi = 32;  // chart B: cos θ × φ
constexpr int kChi2Samples = 1 << 20;
double chi2_alpha() { return sidak_alpha(0.01, 4); }

Chi2Result chi2_uv(const xi::EnvironmentMap& m, const Samples& s) {
  std::vector<double> patches = patch_probabilities(m), expected(kUvA * kUvB, 0.0), observed(kUvA * kUvB, 0.0);
  for (int j = 0; j < kUvB; ++j)
    for (int i = 0; i < kUvA; ++i)
      expected[j * kUvA + i] = rect_probability(m, patches, (double)i / kUvA, (i + 1.0) / kUvA, (double)j / kUvB,
                                                (j + 1.0) / kUvB) * s.dirs.size();
  for (glm::vec3 d : s.dirs) {
    float2 uv = xi_env_direction_to_uv(d);
    int i = std::min((int)(uv.x * kUvA), kUvA - 1), j = std::min((int)(uv.y * kUvB), kUvB - 1);
    observed[j * kUvA + i] += 1.0;
  }
  return chi2_test(observed, expected);
}

Chi2Result chi2_sphere(const xi::EnvironmentMap& m, const Samples& s) {
  std::vector<double> patches = patch_probabilities(m), expected(kSphZ * kSphPhi), observed(kSphZ * kSphPhi, 0.0);
  for (int i = 0; i < kSphZ; ++i) {
    double z0 = -1.0 + 2.0 * i / kSphZ, z1 = -1.0 + 2.0 * (i + 1) / kSphZ;
    double v0 = std::acos(z1) / M_PI, v1 = std::acos(z0) / M_PI;
    for (int j = 0; j < kSphPhi; ++j)
      expected[i * kSphPhi + j] =
          rect_probability(m, patches, (double)j / kSphPhi, (j + 1.0) / kSphPhi, v0, v1) * s.dirs.size();
  }
  for (glm::vec3 d : s.dirs) {
    float2 uv = xi_env_direction_to_uv(d);  // rotation 0: world = map frame
    int i = std::clamp((int)std::floor((d.y + 1.0) * 0.5 * kSphZ), 0, kSphZ - 1);
    int j = std::min((int)(uv.x * kSphPhi), kSphPhi - 1);
    observed[i * kSphPhi + j] += 1.0;
  }
  return chi2_test(observed, expected);
}

void print(const char* what, const Chi2Result& r) {
  std::printf("[ chi2     ] %-40s X2 = %10.1f  dof = %4d  p = %.4g  (alpha %.4g)\n", what, r.statistic, r.dof,
              r.p_value, chi2_alpha());
}

TEST(EnvironmentSampling, Chi2MatchesPdf) {
  const xi::EnvironmentMap small = small_sun_map();
  for (const xi::EnvironmentMap* m : {&the_sun_map(), &small}) {
    ASSERT_TRUE(m->has_distribution());
    EnvironmentData env = xi::make_environment_data(*m, 1.0f, 0.0f, 1.0f);
    Samples s = draw(*m, m->cdf, env, kChi2Samples, 1);
    Chi2Result a = chi2_uv(*m, s), b = chi2_sphere(*m, s);
    print((m->source + ", (u, v) blocks").c_str(), a);
    print((m->source + ", sphere (cos theta, phi)").c_str(), b);
    EXPECT_GT(a.dof, 200);
    EXPECT_GT(b.dof, 200);
    EXPECT_GE(a.p_value, chi2_alpha());
    EXPECT_GE(b.p_value, chi2_alpha());
  }
}

// The test has power: samples from another map's distribution (the sun at half its radiance), and
// from a distribution that ignores sin θ (built from texels divided by sin θ, so that the weights
// are the luminance alone), are rejected against the sun map's pdf.
TEST(EnvironmentSampling, Chi2RejectsWrongSamplers) {
  const xi::EnvironmentMap& m = the_sun_map();
  EnvironmentData env = xi::make_environment_data(m, 1.0f, 0.0f, 1.0f);
  xi::EnvironmentMap dim = sun_map(0.5);
  Chi2Result r = chi2_sphere(m, draw(m, dim.cdf, env, kChi2Samples, 2));
  print("wrong: sun at half radiance", r);
  EXPECT_LT(r.p_value, chi2_alpha());

  std::vector<glm::vec4> t = m.texels;
  for (int y = 0; y < m.height; ++y)
    for (int x = 0; x < m.width; ++x) t[(size_t)y * m.width + x] /= (float)std::sin(M_PI * (y + 0.5) / m.height);
  xi::EnvironmentMap flat = xi::make_environment(m.width, m.height, std::move(t), "no sin");
  r = chi2_sphere(m, draw(m, flat.cdf, env, kChi2Samples, 3));
  print("wrong: ignoring sin theta", r);
  EXPECT_LT(r.p_value, chi2_alpha());
}

// ∫ xi_env_pdf dω = 1 at a rotation of 30° (directions go through to_world and back): 2 × 2
// Gauss–Legendre nodes in (u, v), dω = 2π² sin θ du dv, on each quarter of a texel cell (whose
// edges, at texel centres and edges, hold the patches' kinks). The density is bilinear in (u, v)
// on each quarter, which the nodes integrate exactly, so the sum is 1 but for float rounding of
// the pdf (~1e-6 relative): tolerance 1e-4.
TEST(EnvironmentSampling, PdfIntegratesToOne) {
  const xi::EnvironmentMap& m = the_sun_map();
  EnvironmentData env = xi::make_environment_data(m, 1.0f, 30.0f, 1.0f);
  const double g[2] = {0.5 - 0.5 / std::sqrt(3.0), 0.5 + 0.5 / std::sqrt(3.0)};
  const int nu = 2 * m.width, nv = 2 * m.height;
  double total = 0.0;
  for (int y = 0; y < nv; ++y)
    for (int x = 0; x < nu; ++x)
      for (double gy : g)
        for (double gx : g) {
          double u = (x + gx) / nu, v = (y + gy) / nv;
          float3 d = xi_env_to_world(env, to_float3(uv_direction(u, v)));
          total += xi_env_pdf(m.cdf.data(), env, d) * kTwoPi2 * std::sin(M_PI * v) * 0.25 / ((double)nu * nv);
        }
  std::printf("[ pdf      ] integral over the sphere: %.8f\n", total);
  EXPECT_NEAR(total, 1.0, 1e-4);
}

// Each sample's returned pdf is xi_env_pdf of its direction, its radiance xi_env_radiance's, and
// direction → (u, v) → direction comes back (rotation 30°). Radiance: to 1e-3 relative plus
// 2e-4 of the brightest texel, since the round trip moves (u, v) by ~1e-7 and the bilinear
// lookup's slope beside the sun is up to W = 512 times the sun's radiance per unit of u. Pdfs agree to 1e-3 relative (the
// direction's sin θ from two routes; near the poles a few ulps of x and z are more of sin θ, hence
// the 1e-6/sin θ term) plus 2e-4 of the largest, since the density is bilinear like the radiance and
// as steep beside the sun; a sample that rounds onto the neighbouring cell across a texel edge is let
// off if it lies within 1e-5 of that edge (counted and printed, at most 1 in 10^4); patch edges lie
// on texel centres.
TEST(EnvironmentSampling, PdfOfSampleAndRoundTrips) {
  const xi::EnvironmentMap& m = the_sun_map();
  EnvironmentData env = xi::make_environment_data(m, 2.0f, 30.0f, 1.0f);
  const int n = 1 << 17;
  Samples s = draw(m, m.cdf, env, n, 4);
  float max_texel = 0.0f;
  for (glm::vec4 t : m.texels) max_texel = std::max(max_texel, 2.0f * glm::length(glm::vec3(t)));  // strength 2
  const float max_pdf = *std::max_element(s.pdfs.begin(), s.pdfs.end());
  int on_edge = 0, bad_pdf = 0, bad_trip = 0, bad_rad = 0;
  for (int i = 0; i < n; ++i) {
    float3 d = s.dirs[i];
    ASSERT_NEAR(glm::length(d), 1.0f, 1e-5f);
    ASSERT_GT(s.pdfs[i], 0.0f);
    float pdf = xi_env_pdf(m.cdf.data(), env, d);
    float3 l = xi_env_to_local(env, d);
    float2 uv = xi_env_direction_to_uv(l);
    float sin_theta;
    float3 back = xi_env_uv_to_direction(uv, &sin_theta);
    bad_trip += glm::length(back - l) > 2e-5f;
    float3 rad = xi_env_radiance(m.texels.data(), env, d);
    bad_rad += glm::length(rad - s.radiance[i]) > 1e-3f * glm::length(s.radiance[i]) + 2e-4f * max_texel;
    if (std::fabs(pdf - s.pdfs[i]) > (1e-3 + 1e-6 / std::max(sin_theta, 1e-6f)) * s.pdfs[i] + 2e-4 * max_pdf) {
      double fu = uv.x * m.width - 0.5, fv = uv.y * m.height - 0.5;
      if (std::fabs(fu - std::round(fu)) < 1e-5 * m.width || std::fabs(fv - std::round(fv)) < 1e-5 * m.height)
        ++on_edge;
      else
        ++bad_pdf;
    }
  }
  std::printf("[ pdf      ] %d samples: %d on a cell edge\n", n, on_edge);
  EXPECT_EQ(bad_pdf, 0);
  EXPECT_LE(on_edge, n / 10000);
  EXPECT_EQ(bad_trip, 0);
  EXPECT_EQ(bad_rad, 0);
}

// Mitsuba 3's orientation: a 2 × 1 map's texel centres lie at u = 1/4 and 3/4, v = 1/2, which
// d(u, v) = (sin φ sin θ, cos θ, −cos φ sin θ) puts at +x and −x. Rotating by +90° about +y (as
// Mitsuba's to_world rotate(y, 90)) turns +x to −z and +z to +x.
TEST(EnvironmentOrientation, MitsubaConvention) {
  xi::EnvironmentMap m = xi::make_environment(2, 1, {glm::vec4(1, 0, 0, 0), glm::vec4(0, 0, 1, 0)}, "2x1");
  EnvironmentData env = xi::make_environment_data(m, 1.0f, 0.0f, 1.0f);
  auto at = [&](float3 d) { return xi_env_radiance(m.texels.data(), env, d); };
  EXPECT_NEAR(at(float3(1, 0, 0)).x, 1.0f, 1e-5f);   // column 0 along +x
  EXPECT_NEAR(at(float3(1, 0, 0)).z, 0.0f, 1e-5f);
  EXPECT_NEAR(at(float3(-1, 0, 0)).z, 1.0f, 1e-5f);  // column 1 along −x
  EXPECT_NEAR(at(float3(0, 0, -1)).x, 0.5f, 1e-5f);  // u = 0 (−z): halfway between the columns
  env = xi::make_environment_data(m, 1.0f, 90.0f, 1.0f);
  EXPECT_NEAR(at(float3(0, 0, -1)).x, 1.0f, 1e-5f);  // +x turned to −z
  EXPECT_NEAR(at(float3(0, 0, 1)).z, 1.0f, 1e-5f);   // −x turned to +z
  EXPECT_NEAR(at(float3(1, 0, 0)).x, 0.5f, 1e-5f);   // and the map's +z (u = 1/2) is seen along +x
  // The direction/uv maps themselves: u = 1/4 → +x, u = 1/2 → +z, v = 0 → +y.
  float st;
  float3 d = xi_env_uv_to_direction(float2(0.25f, 0.5f), &st);
  EXPECT_NEAR(d.x, 1.0f, 1e-6f);
  d = xi_env_uv_to_direction(float2(0.5f, 0.5f), &st);
  EXPECT_NEAR(d.z, 1.0f, 1e-6f);
  d = xi_env_uv_to_direction(float2(0.3f, 0.0f), &st);
  EXPECT_NEAR(d.y, 1.0f, 1e-6f);
}

// A map whose only bright texel is at (column 37, row 11) of 64 × 32 shows it in the direction
// d(u, v) of its centre, u = 37.5/64, v = 11.5/32, exactly its value there; rotated by +90° it is
// seen along R_y(90°) d = (d.z, d.y, −d.x); and its samples land within its 3 × 3 cells.
TEST(EnvironmentOrientation, BrightTexelSeenWhereMitsubaPutsIt) {
  const int w = 64, h = 32, cx = 37, cy = 11;
  std::vector<glm::vec4> t((size_t)w * h, glm::vec4(0.0f));
  t[(size_t)cy * w + cx] = glm::vec4(5, 6, 7, 0);
  xi::EnvironmentMap m = xi::make_environment(w, h, std::move(t), "one texel");
  glm::dvec3 d = uv_direction((cx + 0.5) / w, (cy + 0.5) / h);
  for (float degrees : {0.0f, 90.0f}) {
    EnvironmentData env = xi::make_environment_data(m, 1.0f, degrees, 1.0f);
    glm::dvec3 world = degrees == 0.0f ? d : glm::dvec3(d.z, d.y, -d.x);
    float3 l = xi_env_radiance(m.texels.data(), env, to_float3(world));
    EXPECT_NEAR(l.x, 5.0f, 1e-3f) << degrees;
    EXPECT_NEAR(l.z, 7.0f, 1e-3f) << degrees;
    Samples s = draw(m, m.cdf, env, 4096, 5);
    int outside = 0;
    for (glm::vec3 sd : s.dirs) {
      float2 uv = xi_env_direction_to_uv(xi_env_to_local(env, sd));
      outside += std::abs((int)(uv.x * w) - cx) > 1 || std::abs((int)(uv.y * h) - cy) > 1;
    }
    EXPECT_EQ(outside, 0) << degrees;
  }
}

// Importance sampling pays: irradiance on an upward plane, E = ∫ Y(L) cos⁺θ dω, under the sun map,
// by environment sampling and by cosine-hemisphere sampling, 32 batches of 2^14 samples each,
// fixed seeds. relMSE of a batch against a reference (the bilinear radiance integrated by the
// midpoint rule on 4 × 4 sub-cells per texel, whose edges hold the bilinear kinks: ~1e-6): env
// sampling's at least 10× lower. The two means over all samples agree by a two-sided z-test at 1%.
TEST(EnvironmentSampling, ImportanceSamplingBeatsCosineSampling) {
  const xi::EnvironmentMap& m = the_sun_map();
  EnvironmentData env = xi::make_environment_data(m, 1.0f, 0.0f, 1.0f);
  double ref = 0.0;
  const int sub = 4;
  for (int y = 0; y < m.height * sub; ++y) {
    double v = (y + 0.5) / (m.height * sub);
    if (v >= 0.5) break;
    double jac = kTwoPi2 * std::sin(M_PI * v) * std::cos(M_PI * v);
    for (int x = 0; x < m.width * sub; ++x) {
      double u = (x + 0.5) / (m.width * sub);
      ref += lum(xi_env_lookup(m.texels.data(), env, (float)u, (float)v)) * jac;
    }
  }
  ref /= (double)m.width * sub * m.height * sub;

  const int batches = 32, n = 1 << 14;
  double se_env = 0.0, se_cos = 0.0, sum_env = 0.0, sum_cos = 0.0, sq_env = 0.0, sq_cos = 0.0;
  Rng rng_env(6), rng_cos(7);
  for (int b = 0; b < batches; ++b) {
    double be = 0.0, bc = 0.0;
    for (int i = 0; i < n; ++i) {
      float pdf;
      float3 rad;
      float3 d = xi_env_sample(m.texels.data(), m.cdf.data(), env, rng_env.next2(), &pdf, &rad);
      double f = pdf > 0.0f ? lum(rad) * std::max(d.y, 0.0f) / pdf : 0.0;
      be += f;
      sq_env += f * f;
      float3 h = xi_square_to_cosine_hemisphere(rng_cos.next2());
      float3 dc = xi_to_world(h, float3(0, 1, 0));
      double fc = dc.y > 0.0f ? lum(xi_env_radiance(m.texels.data(), env, dc)) * M_PI : 0.0;  // L cos / (cos/π)
      bc += fc;
      sq_cos += fc * fc;
    }
    be /= n;
    bc /= n;
    sum_env += be;
    sum_cos += bc;
    se_env += (be - ref) * (be - ref);
    se_cos += (bc - ref) * (bc - ref);
  }
  const double total = (double)batches * n;
  double rel_env = se_env / batches / (ref * ref), rel_cos = se_cos / batches / (ref * ref);
  double mean_env = sum_env / batches, mean_cos = sum_cos / batches;
  double var_env = (sq_env / total - mean_env * mean_env) / total, var_cos = (sq_cos / total - mean_cos * mean_cos) / total;
  double z = (mean_env - mean_cos) / std::sqrt(var_env + var_cos);
  std::printf("[ irradiance] reference %.6f; env sampling mean %.6f relMSE %.3g; cosine sampling mean %.6f relMSE %.3g; "
              "ratio %.1f; z = %.2f\n", ref, mean_env, rel_env, mean_cos, rel_cos, rel_cos / rel_env, z);
  EXPECT_LE(rel_env * 10.0, rel_cos);
  EXPECT_LT(std::fabs(z), sidak_critical_z(0.01, 1));
  EXPECT_NEAR(mean_env, ref, 5.0 * std::sqrt(var_env));  // and env sampling hits the reference
}

TEST(EnvironmentSampling, BlackMapHasNoDistribution) {
  xi::EnvironmentMap m = xi::make_environment(4, 2, std::vector<glm::vec4>(8, glm::vec4(0.0f)), "black");
  EXPECT_FALSE(m.has_distribution());
  EXPECT_EQ(xi::make_environment_data(m, 1.0f, 0.0f, 0.5f).scale.w, 0.0f);
  EXPECT_EQ(xi::make_environment_data(the_sun_map(), 0.0f, 0.0f, 0.5f).scale.w, 0.0f);
  EXPECT_EQ(xi::make_environment_data(the_sun_map(), 1.0f, 0.0f, 0.5f).scale.w, 0.5f);
}

// Distribution rules: CDFs end at exactly 1, and a patch has a positive probability exactly where
// the bilinear radiance inside it can be nonzero (one of the texels at its corners is), even for a
// texel 1e-30 as bright as the sun.
TEST(EnvironmentSampling, DistributionCoversEveryLitPatch) {
  const int w = 32, h = 16, rows = h + 1;
  std::vector<glm::vec4> t((size_t)w * h, glm::vec4(0.0f));
  t[3 * w + 0] = glm::vec4(1e6f);       // on the wrap-around column
  t[15 * w + 20] = glm::vec4(1e-24f);   // the last row, very dim
  t[0 * w + 9] = glm::vec4(1.0f);       // the first row, beside the zenith's patch row
  xi::EnvironmentMap m = xi::make_environment(w, h, std::move(t), "sparse");
  ASSERT_TRUE(m.has_distribution());
  EXPECT_EQ(m.cdf[rows - 1], 1.0f);
  for (int k = 0; k < rows; ++k) EXPECT_EQ(m.cdf[rows + (size_t)k * w + w - 1], 1.0f);
  std::vector<double> p = patch_probabilities(m);
  auto texel_lit = [&](int x, int y) { return y >= 0 && y < h && m.texels[(size_t)y * w + (x % w)].x > 0.0f; };
  int lit_patches = 0;
  for (int k = 0; k < rows; ++k)
    for (int x = 0; x < w; ++x) {
      const bool lit = texel_lit(x, k - 1) || texel_lit(x + 1, k - 1) || texel_lit(x, k) || texel_lit(x + 1, k);
      lit_patches += lit;
      EXPECT_EQ(p[(size_t)k * w + x] > 0.0, lit) << x << ", " << k;
    }
  EXPECT_EQ(lit_patches, 3 * 4);
}

// The guided search finds exactly the entry a binary search finds (the first CDF value above u),
// with its interval: on sizes that are not powers of two (there ⌊u n⌋ in float can round up, and
// the search must step back), rows with long runs of zero-probability cells and one cell holding
// nearly all (several steps forward), a uniform map (its CDF values fall exactly on k / n), and u
// at and next to every k / n.
TEST(EnvironmentSampling, GuidedSearchMatchesBinarySearch) {
  for (int size : {0, 1, 2, 3}) {
    const int w = std::array<int, 4>{37, 100, 513, 37}[size], h = std::array<int, 4>{13, 51, 255, 19}[size];
    const bool uniform = size == 3;
    std::vector<glm::vec4> t((size_t)w * h, glm::vec4(uniform ? 1.0f : 0.0f));
    Rng rng(11 + size);
    for (size_t i = 0; i < t.size() && !uniform; ++i)
      if (rng.next() < 0.3f) t[i] = glm::vec4(std::pow(10.0f, 6.0f * rng.next() - 3.0f));
    if (!uniform) t[(size_t)(h / 3) * w + w / 2] = glm::vec4(1e7f);
    xi::EnvironmentMap m = xi::make_environment(w, h, std::move(t), "search");
    ASSERT_TRUE(m.has_distribution());
    const uint guides = XI_ENV_GUIDE_OFFSET((uint)w, (uint)h) / 4u;
    std::vector<float> us;
    for (int n : {w, h + 1})
      for (int k = 0; k <= n; ++k) {
        float at = (float)k / (float)n;
        for (float u : {std::nextafter(at, 0.0f), at, std::nextafter(at, 1.0f)})
          if (u >= 0.0f && u < 1.0f) us.push_back(u);
      }
    for (int i = 0; i < 20000; ++i) us.push_back(rng.next());
    size_t checked = 0;
    for (int row = -1; row <= h; row += 7) {  // -1: the marginal over the h + 1 patch rows
      const uint base = row < 0 ? 0u : (uint)(h + 1 + row * w), n = row < 0 ? (uint)h + 1u : (uint)w;
      const float* cdf = m.cdf.data() + base;
      for (float u : us) {
        const uint expect = (uint)std::min<ptrdiff_t>(std::upper_bound(cdf, cdf + n, u) - cdf, n - 1);
        float stretched = u, p = 0.0f;
        const uint got = xi_env_search(m.cdf.data(), base, guides + base, n, &stretched, &p);
        ASSERT_EQ(got, expect) << w << "x" << h << " row " << row << " u " << u;
        const float below = expect ? cdf[expect - 1] : 0.0f;
        ASSERT_EQ(p, cdf[expect] - below);
        ASSERT_GE(stretched, 0.0f);
        ASSERT_LT(stretched, 1.0f);
        ++checked;
      }
    }
    EXPECT_GT(checked, 20000u);
  }
}

// ---------------------------------------------------------------------------------------------
// Files

// A file of `bytes` in the test's folder (fixtures.h's fresh_test_dir).
fs::path write_bytes(const fs::path& dir, const std::string& name, const std::string& bytes) {
  fs::path p = dir / name;
  std::ofstream(p, std::ios::binary) << bytes;
  return p;
}

// The load error's message, which must name the file; "" if it loaded.
std::string load_error(const fs::path& p) {
  try {
    xi::load_environment(p);
  } catch (const xi::Error& e) {
    EXPECT_NE(std::string(e.what()).find(p.filename().string()), std::string::npos) << e.what();
    std::printf("[ error    ] %s\n", e.what());
    return e.what();
  }
  return "";
}

xi::Image tiny_image(int w, int h) {
  xi::Image img(w, h);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) img.at(x, y) = glm::vec3(0.1f * x, 0.2f, 0.05f * y);
  return img;
}

TEST(EnvironmentFiles, LoadsHdrAndExr) {
  const fs::path dir = xi::test::fresh_test_dir("xi_env_");
  xi::Image img = tiny_image(6, 3);
  fs::path exr = dir / "tiny.exr";
  xi::write_exr(exr, {{"", &img}});
  xi::EnvironmentMap m = xi::load_environment(exr);
  ASSERT_EQ(m.width, 6);
  ASSERT_EQ(m.height, 3);
  EXPECT_FLOAT_EQ(m.texels[2 * 6 + 4].x, 0.4f);
  EXPECT_FLOAT_EQ(m.texels[2 * 6 + 4].z, 0.1f);
  EXPECT_TRUE(m.has_distribution());
  // A flat RGBE file: mantissas (128, 64, 255), exponent byte 129: (128, 64, 255)·2^(129−136).
  std::string hdr = "#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 1 +X 2\n";
  hdr += std::string("\x80\x40\xff\x81\x00\x00\x00\x00", 8);
  xi::EnvironmentMap h = xi::load_environment(write_bytes(dir, "tiny.hdr", hdr));
  ASSERT_EQ(h.width, 2);
  ASSERT_EQ(h.height, 1);
  EXPECT_FLOAT_EQ(h.texels[0].x, 1.0f);
  EXPECT_FLOAT_EQ(h.texels[0].y, 0.5f);
  EXPECT_FLOAT_EQ(h.texels[0].z, 255.0f / 128.0f);
  EXPECT_EQ(h.texels[1].y, 0.0f);
  // Run-length encoded, 16 × 2: per line the marker, then each channel as runs (a run of 10 and a
  // literal run of 6 for red, one run of 16 for the others); all texels (1, 0.5, 0.25).
  std::string rle = "#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 2 +X 16\n";
  for (int y = 0; y < 2; ++y) {
    rle += std::string("\x02\x02\x00\x10", 4);
    rle += std::string("\x8a\x80\x06", 3) + std::string(6, '\x80');
    rle += std::string("\x90\x40\x90\x20\x90\x81", 6);
  }
  h = xi::load_environment(write_bytes(dir, "rle.hdr", rle));
  ASSERT_EQ(h.width, 16);
  ASSERT_EQ(h.height, 2);
  for (const glm::vec4& t : h.texels) EXPECT_EQ(glm::vec3(t), glm::vec3(1.0f, 0.5f, 0.25f));
  fs::remove_all(dir);
}

TEST(EnvironmentFiles, BadInputGivesErrors) {
  const fs::path dir = xi::test::fresh_test_dir("xi_env_");
  auto expect = [](const std::string& msg, const std::string& part) {
    EXPECT_NE(msg.find(part), std::string::npos) << "'" << msg << "' lacks '" << part << "'";
  };
  expect(load_error(dir / "missing.hdr"), "no such");
  expect(load_error(dir / "missing.exr"), "no such");
  expect(load_error(write_bytes(dir, "garbage.hdr", "this is not an image at all")), "not a Radiance HDR");
  expect(load_error(write_bytes(dir, "badsize.hdr", "#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y x +X 8\n")), "corrupt");
  expect(load_error(write_bytes(dir, "garbage.exr", std::string(200, 'x'))), "corrupt");
  // Truncated RGBE files: flat (the bundled sky cut short) and run-length encoded (a 16-wide line
  // whose red channel is one run of 16 and the rest missing), and a zero-length literal run.
  {
    std::ifstream sky(fs::path(XI_SCENE_DIR) / "sky.hdr", std::ios::binary);
    std::string bytes((std::istreambuf_iterator<char>(sky)), std::istreambuf_iterator<char>());
    expect(load_error(write_bytes(dir, "cut_flat.hdr", bytes.substr(0, 300000))), "row 146 of 256 is missing");
  }
  std::string rle = "#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 2 +X 16\n";
  rle += std::string("\x02\x02\x00\x10\x90\x80", 6);
  expect(load_error(write_bytes(dir, "cut_rle.hdr", rle)), "row 0 of 2 is missing or malformed");
  expect(load_error(write_bytes(dir, "zero_run.hdr", rle.substr(0, rle.size() - 2) + std::string(20, '\0'))), "row 0 of 2");
  expect(load_error(write_bytes(dir, "empty.hdr", "")), "empty");
  expect(load_error(write_bytes(dir, "sky.txt", "x")), "unknown environment map format");

  xi::Image img = tiny_image(4, 2);
  fs::path png = dir / "eight.png";
  xi::write_png(png, img);
  expect(load_error(png), "must be high dynamic range (.hdr or .exr), not an 8-bit image");
  expect(load_error(write_bytes(dir, "photo.JPG", "\xff\xd8\xff")), "not an 8-bit image");
  fs::path png_as_hdr = dir / "png_inside.hdr";
  fs::copy_file(png, png_as_hdr);
  expect(load_error(png_as_hdr), "not a Radiance HDR");

  const char* kinds[] = {"NaN", "infinite", "negative"};
  const float values[] = {NAN, INFINITY, -1.0f};
  for (int k = 0; k < 3; ++k) {
    xi::Image bad = tiny_image(4, 2);
    bad.at(3, 1).y = values[k];
    fs::path p = dir / (std::string("bad_") + kinds[k] + ".exr");
    xi::write_exr(p, {{"", &bad}});
    std::string msg = load_error(p);
    expect(msg, "x 3, y 1");
    expect(msg, kinds[k]);
  }

  xi::Image wide(xi::kEnvironmentMaxWidth + 1, 1);
  fs::path big = dir / "too_wide.exr";
  xi::write_exr(big, {{"", &wide}});
  expect(load_error(big), "larger than");

  EXPECT_THROW(xi::make_environment(0, 0, {}), xi::Error);
  EXPECT_THROW(xi::make_environment(2, 2, std::vector<glm::vec4>(3)), xi::Error);
  fs::remove_all(dir);
}

// The bundled sky (scripts/make-sky.py): 512 × 256, finite; the sun is the brightest texel, at 40°
// elevation (±1°), and the texels within 3° of it hold 55–70% of the power (the script prints
// 0.61); its irradiance on a horizontal plane is about 3× the rest's (2.5–3.5).
TEST(EnvironmentFiles, BundledSky) {
  xi::EnvironmentMap m = xi::load_environment(fs::path(XI_SCENE_DIR) / "sky.hdr");
  ASSERT_EQ(m.width, 512);
  ASSERT_EQ(m.height, 256);
  ASSERT_TRUE(m.has_distribution());
  size_t brightest = 0;
  for (size_t i = 0; i < m.texels.size(); ++i)
    if (lum(m.texels[i]) > lum(m.texels[brightest])) brightest = i;
  glm::dvec3 sun = uv_direction((brightest % m.width + 0.5) / m.width, (brightest / m.width + 0.5) / m.height);
  EXPECT_NEAR(std::asin(sun.y) * 180.0 / M_PI, 40.0, 1.0);
  double near = std::cos(3.0 * M_PI / 180.0), power = 0.0, sun_power = 0.0, e_sun = 0.0, e_sky = 0.0;
  for (int y = 0; y < m.height; ++y) {
    double omega = (std::cos(M_PI * y / m.height) - std::cos(M_PI * (y + 1) / m.height)) * 2.0 * M_PI / m.width;
    for (int x = 0; x < m.width; ++x) {
      glm::dvec3 d = uv_direction((x + 0.5) / m.width, (y + 0.5) / m.height);
      double l = lum(m.texels[(size_t)y * m.width + x]) * omega;
      bool in_sun = glm::dot(d, sun) > near;
      power += l;
      if (in_sun) sun_power += l;
      (in_sun ? e_sun : e_sky) += l * std::max(d.y, 0.0);
    }
  }
  std::printf("[ sky      ] sun share of power %.4f, horizontal irradiance sun %.4f sky %.4f (ratio %.2f), mean luminance %.4f\n",
              sun_power / power, e_sun, e_sky, e_sun / e_sky, m.mean_luminance);
  EXPECT_GT(sun_power / power, 0.55);
  EXPECT_LT(sun_power / power, 0.70);
  EXPECT_GT(e_sun / e_sky, 2.5);
  EXPECT_LT(e_sun / e_sky, 3.5);
}

}  // namespace
