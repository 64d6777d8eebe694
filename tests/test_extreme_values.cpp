// Extreme values: lights 1e-10 and 1e3 times the scene's size, a radiance of 1e6, and an albedo of
// exactly 1 at the deepest depth.
//
// Every case has an exact or a statistical expectation; each statistical test states its
// significance next to the assertion, Šidák-corrected over its own family (one test = one family),
// and uses fixed seeds and the random sampler (whose per-pixel variance of the mean is unbiased, so
// a z-test with the film's variance layer is exact in the large-sample limit). Scenes are built in
// C++ (scene_builder.h), so that each expectation can be derived from the very geometry.
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <string>
#include <vector>

#include <glm/glm.hpp>

#include "analytic.h"
#include "fixtures.h"
#include "scene_builder.h"
#include "stats.h"
#include "xi/renderer.h"
#include "xi/scene.h"

namespace fs = std::filesystem;

namespace {

using namespace xi::test;  // fixtures.h, analytic.h, scene_builder.h (its vector types too)

// Lights 1e-10, 1e-6 and 1e3 times the scene's size: a diffuse plane y = 0 (albedo 1/2,
// half-width 20) under a square light centred 1 above it (the scene's unit), facing down, of side
// 1e-10 or 1e-6 (radiance 1/side², so that it delivers about as much light as a unit light of
// radiance 1) or 1e3 (radiance 1; the plane then sees a light filling all but 0.1° of its sky). The
// plane's radiance is ρ/π · E with Lambert's polygon formula (in long double; for the 1e-6 light it
// is checked against the point-source limit L·A·cos²θ/d², exact to (side/d)² = 1e-12, which is the
// reference for the 1e-10 light: its solid-angle pdf, about 1e20, squared to infinity in the power
// heuristic, which dropped every light sample as NaN). Three 3 × 3 pixel blocks per light: 9 z-tests
// at family-wise α = 0.01 (Šidák).
TEST(ExtremeValues, TinyAndHugeLightsMatchLambertsFormula) {
  const double z_max = xi::stats::sidak_critical_z(0.01, 9);
  uint32_t seed = 51;
  for (double side : {1e-10, 1e-6, 1e3}) {
    SCOPED_TRACE("light side " + std::to_string(side));
    const double radiance = side < 1.0 ? 1.0 / (side * side) : 1.0;
    xi::Scene s;
    s.width = 64, s.height = 48;
    add_floor(s, add_material(s, "plane", vec3(0.5f)), 0.0f, 20.0f);
    const float h = (float)(side / 2);
    add_quad(s, add_material(s, "light", vec3(0.0f), vec3((float)radiance)), vec3(h, 1, -h), vec3(h, 1, h),
             vec3(-h, 1, h), vec3(-h, 1, -h));
    set_camera(s, vec3(0.0f, 0.8f, -2.5f), vec3(0.0f, 0.0f, 0.2f), 50.0f);
    const std::vector<dvec3> polygon = {dvec3(s.position(s.triangles[2], 0)), dvec3(s.position(s.triangles[2], 1)),
                                        dvec3(s.position(s.triangles[2], 2)), dvec3(s.position(s.triangles[3], 2))};
    const View v(s);
    // The point-source limit of the irradiance: for the light of side 1e-6 it equals Lambert's
    // formula to 1e-6 (checked below); for side 1e-10 it is the reference, as the formula's sums of
    // angles between vertices 1e-10 apart lose their digits even in long double.
    auto point_irradiance = [&](dvec3 p) {
      const dvec3 d = dvec3(0, 1, 0) - p;
      const double cos2 = (d.y / glm::length(d)) * (d.y / glm::length(d));
      return radiance * side * side * cos2 / glm::dot(d, d);
    };
    auto plane_radiance = [&](dvec3 d) {
      if (d.y >= 0.0) return (double)NAN;
      const dvec3 p = v.o + (-v.o.y / d.y) * d;
      return 0.5 / M_PI * (side < 1e-8 ? point_irradiance(p) : lambert_irradiance(polygon, radiance, p, dvec3(0, 1, 0)));
    };
    const dvec3 spots[] = {{0, 0, 0}, {0.56, 0, 0.1}, {-1.0, 0, 0.8}};
    if (side == 1e-6)
      for (const dvec3& p : spots)  // the reference itself, against the point-source limit
        EXPECT_NEAR(lambert_irradiance(polygon, radiance, p, dvec3(0, 1, 0)) / point_irradiance(p), 1.0, 1e-6);
    const Shot shot = render_shot(s, render_options(256, seed++, xi::Strategy::Mis, 4));
    EXPECT_EQ(shot.nonfinite, 0u);
    for (const dvec3& p : spots) {
      const dvec2 f = v.film(p);
      const int cx = (int)std::floor(f.x), cy = (int)std::floor(f.y);
      ASSERT_TRUE(cx >= 1 && cy >= 1 && cx + 1 < s.width && cy + 1 < s.height);
      double exact = 0.0;
      for (int y = cy - 1; y <= cy + 1; ++y)
        for (int x = cx - 1; x <= cx + 1; ++x) exact += footprint_mean(v, x, y, plane_radiance) / 9.0;
      ASSERT_TRUE(std::isfinite(exact));
      const MeanSe m = block_mean(shot, cx - 1, cy - 1, cx + 2, cy + 2);
      std::printf("[ light  ] side %-6g at (%5.2f, %4.2f): %.5f ± %.5f, exact %.5f, z = %+.2f\n", side, p.x, p.z,
                  m.mean, m.se, exact, (m.mean - exact) / m.se);
      EXPECT_GT(m.se, 0.0);
      EXPECT_LE(std::abs(m.mean - exact), z_max * m.se) << "spot " << p.x << ", " << p.z;
    }
  }
}

// Radiance 1e6: the Cornell box with its light 1e6 times brighter. Nothing in the transport
// depends on the radiance (light choice by relative power, MIS weights and Russian roulette by
// throughput), so with the same seed every sample is the radiance-1 sample times 1e6 up to float
// rounding: each pixel within 1e-5 relative (the rounding of a few dozen operations and of the sum,
// ~1e-6). With another seed, the scaled render matches the radiance-1 render within noise: per
// 8 × 8 block and channel, a z-test with both variance layers (the 1e6 one scaled by 1e-12) at
// family-wise α = 0.01 (Šidák over 16 blocks × 3 channels). Every sample finite.
TEST(ExtremeValues, Radiance1e6IsFiniteAndLinear) {
  xi::Scene base = xi::load_scene(fs::path(XI_SCENE_DIR) / "cornell-box.json");
  base.width = base.height = 32;
  xi::Scene bright = base;
  int lights = 0;
  for (xi::Material& m : bright.materials)
    if (m.is_emitter()) m.emission *= 1e6f, lights++;
  ASSERT_EQ(lights, 1);
  const int depth = base.render.max_depth;
  const Shot a = render_shot(base, render_options(64, 61, xi::Strategy::Mis, depth));
  const Shot b = render_shot(bright, render_options(64, 61, xi::Strategy::Mis, depth));
  const Shot c = render_shot(bright, render_options(64, 62, xi::Strategy::Mis, depth));
  EXPECT_EQ(a.nonfinite + b.nonfinite + c.nonfinite, 0u);
  double worst_rel = 0.0;
  for (int y = 0; y < 32; ++y)
    for (int x = 0; x < 32; ++x)
      for (int ch = 0; ch < 3; ++ch) {
        const double one = a.mean.at(x, y)[ch], big = b.mean.at(x, y)[ch];
        ASSERT_TRUE(std::isfinite(big) && std::isfinite(c.mean.at(x, y)[ch]) && std::isfinite(c.variance.at(x, y)[ch]));
        ASSERT_GT(one, 0.0);
        worst_rel = std::max(worst_rel, std::abs(big / 1e6 - one) / one);
      }
  EXPECT_LT(worst_rel, 1e-5);  // same seed: linear to float rounding
  const double z_max = xi::stats::sidak_critical_z(0.01, 16 * 3);
  double worst_z = 0.0;
  for (int by = 0; by < 32; by += 8)
    for (int bx = 0; bx < 32; bx += 8)
      for (int ch = 0; ch < 3; ++ch) {
        const MeanSe m1 = block_mean(a, bx, by, bx + 8, by + 8, ch), m6 = block_mean(c, bx, by, bx + 8, by + 8, ch);
        const double z = (m6.mean / 1e6 - m1.mean) / std::hypot(m6.se / 1e6, m1.se);
        worst_z = std::max(worst_z, std::abs(z));
        EXPECT_LE(std::abs(z), z_max) << "block " << bx << ", " << by << " channel " << ch;
      }
  std::printf("[ 1e6    ] same seed: worst relative difference %.2e; other seed: worst |z| %.2f of %.2f\n", worst_rel,
              worst_z, z_max);
}

// Albedo exactly 1 in a closed furnace at the deepest depth, 64. A cube (12 triangles, no vertex
// normals, so no shading-normal loss) with albedo 1 and two-sided emission Le = 1, the camera
// inside. Radiance arriving after k bounces is Le for every k, and the renderer counts emission at
// path vertices 0..max_depth (shade adds a vertex's emission, then stops a path whose depth is
// max_depth; light sampling from vertex 63 supplies vertex 64's emission, MIS-weighted against the
// BSDF ray that reaches it), so the truncated series is Σ_{k=0}^{64} Le = 65 exactly. Russian
// roulette (from bounce 5, survival q = min(max throughput, 0.95) = 0.95, throughput divided by q)
// keeps it unbiased: its 60 decisions give 5 + Σ_{j=1}^{60} 0.95^j · 0.95^−j = 65, with a
// per-sample standard deviation of ~100 (20 (0.95^−N − 1) for the N ≤ 60 survivals). Image mean
// against 65, MIS (256 spp) and BSDF sampling alone (1024 spp): 2 z-tests at family-wise α = 0.01
// (Šidák, z = 2.81). MIS must tell 65 from 64 or 66 (one bounce lost or gained), BSDF sampling a
// bias of 0.5, each with a power of at least 90%: enough to catch a random sampler whose hash
// correlates the roulette's decisions across bounces (a bias of about 0.5).
TEST(ExtremeValues, AlbedoOneFurnaceAtDepth64SumsExactly65Terms) {
  xi::Scene s;
  s.width = s.height = 32;
  add_box(s, add_material(s, "shell", vec3(1.0f), vec3(1.0f), true), vec3(-1.0f), vec3(1.0f));
  set_camera(s, vec3(0.1f, 0.2f, -0.3f), vec3(0.4f, 0.25f, 0.7f), 90.0f);
  const double exact = 65.0, z_max = xi::stats::sidak_critical_z(0.01, 2);
  uint32_t seed = 71;
  for (xi::Strategy strategy : {xi::Strategy::Mis, xi::Strategy::Bsdf}) {
    const bool mis = strategy == xi::Strategy::Mis;
    const Shot shot = render_shot(s, render_options(mis ? 256 : 1024, seed++, strategy, 64));
    EXPECT_EQ(shot.nonfinite, 0u);
    const MeanSe m = block_mean(shot, 0, 0, 32, 32);
    std::printf("[ furnace] %-4s %.3f ± %.3f, exact 65, z = %+.2f (against 64: %+.2f, 66: %+.2f)\n",
                xi::strategy_name(strategy), m.mean, m.se, (m.mean - exact) / m.se, (m.mean - 64.0) / m.se,
                (m.mean - 66.0) / m.se);
    EXPECT_LE(std::abs(m.mean - exact), z_max * m.se) << xi::strategy_name(strategy);
    // Power: a bias of 1 (MIS) or 0.5 (BSDF) is rejected with probability ≥ 90% (z_max + Φ⁻¹(0.9)
    // standard errors from it).
    EXPECT_LT((z_max + 1.2816) * m.se, mis ? 1.0 : 0.5) << "too noisy for the biases it must find";
  }
}


}  // namespace
