// Renders with exact answers: a closed furnace (radiance Le / (1 − ρ) everywhere, whatever the
// sampler or strategy), and a diffuse plane under a square light, whose radiance follows from
// Lambert's formula for the irradiance of a polygonal luminaire (computed here, independently of
// the renderer). Scenes in tests/data/scenes/.
//
// Every statistical check runs at a family-wise significance of 0.01, Šidák-corrected over the
// checks of its test (each test is one family); seeds are fixed, so the outcome is deterministic.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <string>
#include <vector>

#include <glm/glm.hpp>

#include "analytic.h"
#include "fixtures.h"
#include "sampling.h"
#include "stats.h"
#include "xi/renderer.h"
#include "xi/scene.h"

namespace {

namespace fs = std::filesystem;
using glm::dvec3;
using namespace xi::stats;

const fs::path kTestScenes = fs::path(XI_TEST_DATA_DIR) / "scenes";

using xi::test::MeanSe;
using xi::test::Shot;

// A rectangle of pixels [x0, x1) × [y0, y1).
struct Region {
  const char* name;
  int x0, y0, x1, y1;
  int pixels() const { return (x1 - x0) * (y1 - y0); }
};

// Mean of channel 0 over the region and its standard error.
MeanSe region_stat(const Shot& r, const Region& g) { return xi::test::block_mean(r, g.x0, g.y0, g.x1, g.y1); }

// ---------------------------------------------------------------------------------------------
// Closed furnace: the camera inside a closed sphere (icosphere, 5 subdivisions) whose inside is
// diffuse with albedo ρ = 0.5 and emits Le = 1 (two_sided, as the icosphere's faces point out).
// Radiance is the same everywhere and in every direction, L = Le + ρL, so L = Le / (1 − ρ) = 2
// at every pixel; with max_depth 64 the truncation error is ρ^65 ≈ 3e-20.
//
// One deviation is allowed for, and bounded: the icosphere has vertex normals, and the renderer
// ends a path whose direction, sampled about the shading normal, falls below the face (and
// rejects such light samples alike). A cosine lobe about a normal tilted by δ loses (1 − cos δ)/2
// of its mass below the face (the lobe projects to the uniform disc, which the face cuts along an
// ellipse of semi-axis cos δ), so the effective albedo is ρ(1 − ε) with ε ≤ (1 − cos δmax)/2, and
// L ≥ Le / (1 − ρ(1 − ε)). δmax is measured on the scene below (1.37°: ε ≤ 1.4e-4, a bias of at
// most 2.9e-4, a tenth of the image mean's standard error).
//
// Each sampler is one family: the image mean and three column bands, for MIS and BSDF sampling
// alone: 8 z-tests, |mean − 2| ≤ z·SE + bias with z = 3.1352. For random and stratified sampling
// the samples of a pixel are independent given the strata, so the film's variance of the mean is
// unbiased (random) or conservative (stratified); for sobol it overstates the scrambled-QMC
// error, which makes the test conservative. The grid sampler takes cell centres: a pixel's
// estimate is a deterministic midpoint rule whose error is a bias, not noise, and the sample
// variance of the cell centres says nothing about it (e.g. with 16 samples, 4 × 4 centres and a
// Russian roulette probability of 1/8, no centre ever falls below 1/8). For grid the mean must be
// within 1% of 2 instead, a tolerance that still rejects any error in the transport itself
// (a missing emission term, a lost bounce, a wrong weight: ≥ 10%).

class AnalyticClosedFurnace : public ::testing::TestWithParam<int> {};

TEST_P(AnalyticClosedFurnace, RadianceIsLeOverOneMinusAlbedo) {
  const int sampler = GetParam();
  const xi::Scene scene = xi::load_scene(kTestScenes / "closed-furnace.json");
  const xi::Material& m = scene.materials.at(0);
  ASSERT_TRUE(m.two_sided);
  const double rho = m.albedo.x, le = m.emission.x, exact = le / (1.0 - rho);
  ASSERT_EQ(exact, 2.0);

  double cos_min = 1.0;  // the largest tilt of a vertex normal from its face's normal
  for (const xi::Triangle& t : scene.triangles) {
    ASSERT_TRUE(t.has_normals);
    const glm::vec3 &p0 = scene.position(t, 0), &p1 = scene.position(t, 1), &p2 = scene.position(t, 2);
    dvec3 ng = glm::normalize(glm::cross(dvec3(p1 - p0), dvec3(p2 - p0)));
    for (int k = 0; k < 3; ++k)
      cos_min = std::min(cos_min, std::abs(glm::dot(ng, glm::normalize(dvec3(scene.normal(t, k))))));
  }
  const double eps = (1.0 - cos_min) / 2.0, bias = exact - le / (1.0 - rho * (1.0 - eps));
  EXPECT_LT(bias, 1e-3);

  const int w = scene.width, h = scene.height;
  const Region regions[] = {{"image", 0, 0, w, h}, {"left", 0, 0, w / 3, h}, {"middle", w / 3, 0, 2 * w / 3, h},
                            {"right", 2 * w / 3, 0, w, h}};
  const double z = sidak_critical_z(0.01, 8);
  uint32_t seed = 100 + sampler * 10;
  for (xi::Strategy strategy : {xi::Strategy::Mis, xi::Strategy::Bsdf}) {
    const Shot r =
        xi::test::render_shot(scene, xi::test::render_options(64, seed++, strategy, scene.render.max_depth, sampler));
    EXPECT_EQ(r.nonfinite, 0u);
    for (const Region& g : regions) {
      MeanSe s = region_stat(r, g);
      std::printf("  %-10s %-4s %-6s %.5f ± %.5f  z = %+.2f  (shading-normal bias ≤ %.1e)\n", xi::sampler_name(sampler),
                  xi::strategy_name(strategy), g.name, s.mean, s.se, (s.mean - exact) / s.se, bias);
      if (sampler == XI_SAMPLER_GRID) {
        EXPECT_NEAR(s.mean, exact, 0.01 * exact) << g.name;
      } else {
        EXPECT_GT(s.se, 0.0);
        EXPECT_LE(std::abs(s.mean - exact), z * s.se + bias) << xi::strategy_name(strategy) << " " << g.name;
      }
    }
  }
}

INSTANTIATE_TEST_SUITE_P(Analytic, AnalyticClosedFurnace,
                         ::testing::Values(XI_SAMPLER_RANDOM, XI_SAMPLER_GRID, XI_SAMPLER_STRATIFIED, XI_SAMPLER_SOBOL),
                         [](const ::testing::TestParamInfo<int>& info) { return std::string(xi::sampler_name(info.param)); });

// ---------------------------------------------------------------------------------------------
// A diffuse plane y = 0 (albedo ρ) under a square light of radiance L (1 × 1 at height 1, facing
// down), nothing else: the plane's radiance at x is ρ/π · E(x), with E from Lambert's formula for
// a polygonal luminaire, E(x) = L/2 · |Σ_i Θ_i (n · u_i)| over the edges (v_i, v_i+1): Θ_i the
// angle the edge subtends at x, u_i the unit normal of the plane through x and the edge, n the
// plane's normal (analytic.h). The light is black and the plane cannot see itself, so there is no
// other light.

// A plane scene: the lit plane y = 0, one square light, and optionally a plane mirror z = const.
struct PlaneScene {
  xi::Scene scene;
  std::vector<dvec3> light;  // the light's corners
  double radiance = 0.0, albedo = 0.0;
  bool mirror = false;
  dvec3 mirror_min{0.0}, mirror_max{0.0};  // its bounding box (flat in z)
};

PlaneScene load_plane_scene(const char* file) {
  PlaneScene p{xi::load_scene(kTestScenes / file)};
  for (const xi::Triangle& t : p.scene.triangles) {
    const xi::Material& m = p.scene.materials[t.material];
    const dvec3 tv[3] = {dvec3(p.scene.position(t, 0)), dvec3(p.scene.position(t, 1)), dvec3(p.scene.position(t, 2))};
    if (m.type == xi::MaterialType::Mirror) {
      if (!p.mirror) p.mirror_min = p.mirror_max = tv[0];
      p.mirror = true;
      for (const dvec3& v : tv) {
        p.mirror_min = glm::min(p.mirror_min, v);
        p.mirror_max = glm::max(p.mirror_max, v);
      }
    } else if (m.is_emitter()) {  // a quad: corners v0 v1 v2, then v3 from the second triangle (v0 v2 v3)
      p.radiance = m.emission.x;
      if (p.light.empty()) p.light = {tv[0], tv[1], tv[2]};
      else p.light.push_back(tv[2]);
    } else {
      p.albedo = m.albedo.x;
    }
  }
  return p;
}

// Radiance along the camera ray (o, d): off the mirror at most once (the plane z = const within
// its bounds: the direction's z flips), then the lit plane y = 0, whose radiance is ρ/π times the
// irradiance from the light plus, with a mirror, from the light's mirror image (which every point
// used here sees whole through the mirror: the paths cross it at 0 < y < 1, |x| < 1, inside its
// bounds). NaN where the ray does not reach the plane in front of the mirror.
double host_radiance(const PlaneScene& p, dvec3 o, dvec3 d) {
  std::vector<dvec3> image = p.light;
  if (p.mirror) {
    const double mz = p.mirror_min.z;
    for (dvec3& v : image) v.z = 2.0 * mz - v.z;
    double t = (mz - o.z) / d.z;
    dvec3 m = o + t * d;
    if (t > 0.0 && m.y > 0.0 && m.y <= p.mirror_max.y && m.x >= p.mirror_min.x && m.x <= p.mirror_max.x) {
      o = m;
      d.z = -d.z;
    }
  }
  if (d.y >= 0.0) return NAN;
  dvec3 x = o + (-o.y / d.y) * d;
  if (p.mirror && x.z >= p.mirror_min.z) return NAN;
  double e = xi::test::lambert_irradiance(p.light, p.radiance, x, dvec3(0, 1, 0));
  if (p.mirror) e += xi::test::lambert_irradiance(image, p.radiance, x, dvec3(0, 1, 0));
  return p.albedo / M_PI * e;
}

// The expected value of pixel (px, py): the radiance averaged over its footprint (the box filter),
// by a 16 × 16 midpoint rule; the radiance is smooth over each footprint used, so the rule's error
// is far below 1e-4 of the value.
double expected_pixel(const PlaneScene& p, int px, int py) {
  const xi::test::View v(p.scene);
  return xi::test::footprint_mean(v, px, py, [&](dvec3 d) { return host_radiance(p, v.o, d); });
}

struct Spot {
  const char* name;
  dvec3 point;    // on the plane
  bool mirrored;  // the block is where the camera sees the point in the mirror
};

// For each spot a 3 × 3 block of pixels; per strategy and block, a z-test of the block mean
// against the exact value: 3 blocks × 3 strategies = 9 tests, z = 3.2595. The standard errors
// (printed) are small next to the values with MIS and light sampling, larger with BSDF sampling
// alone (4× the samples), so an error of a few percent in the direct light fails: a missing
// cosine at either end, a wrong area-to-solid-angle conversion, MIS weights that do not sum to 1,
// a one-sided light emitting from its back, light found through a mirror weighted as if light
// sampling could have found it.
void check_plane(const char* file, const std::vector<Spot>& spots, uint32_t seed) {
  PlaneScene p = load_plane_scene(file);
  ASSERT_EQ(p.light.size(), 4u);
  struct Block { Region region; double exact; };
  std::vector<Block> blocks;
  for (const Spot& s : spots) {
    dvec3 q = s.point;
    if (s.mirrored) q.z = 2.0 * p.mirror_min.z - q.z;
    const glm::ivec2 c = xi::test::View(p.scene).pixel(q);
    Block b{{s.name, c.x - 1, c.y - 1, c.x + 2, c.y + 2}, 0.0};
    ASSERT_TRUE(b.region.x0 >= 0 && b.region.y0 >= 0 && b.region.x1 <= p.scene.width && b.region.y1 <= p.scene.height);
    for (int y = b.region.y0; y < b.region.y1; ++y)
      for (int x = b.region.x0; x < b.region.x1; ++x) b.exact += expected_pixel(p, x, y) / b.region.pixels();
    ASSERT_TRUE(std::isfinite(b.exact)) << s.name;
    blocks.push_back(b);
  }
  const double z = sidak_critical_z(0.01, 3 * (int)blocks.size());
  for (xi::Strategy strategy : {xi::Strategy::Mis, xi::Strategy::Nee, xi::Strategy::Bsdf}) {
    int spp = strategy == xi::Strategy::Bsdf ? 1024 : 256;
    const Shot r =
        xi::test::render_shot(p.scene, xi::test::render_options(spp, seed++, strategy, p.scene.render.max_depth));
    EXPECT_EQ(r.nonfinite, 0u);
    for (const Block& b : blocks) {
      MeanSe s = region_stat(r, b.region);
      std::printf("  %-4s %-13s (%2d,%2d): %.5f ± %.5f, exact %.5f  z = %+.2f\n", xi::strategy_name(strategy),
                  b.region.name, b.region.x0 + 1, b.region.y0 + 1, s.mean, s.se, b.exact, (s.mean - b.exact) / s.se);
      EXPECT_GT(s.se, 0.0);
      EXPECT_LE(std::abs(s.mean - b.exact), z * s.se) << xi::strategy_name(strategy) << " " << b.region.name;
    }
  }
}

// Below the light's centre, just outside the projection of its edge x = 0.5, and far off axis.
const std::vector<Spot> kPlaneSpots = {
    {"centre", {0, 0, 0}, false}, {"edge", {0.56, 0, 0.1}, false}, {"off-axis", {-1.0, 0, 0.8}, false}};

TEST(AnalyticPlane, OneSidedSquareLight) { check_plane("plane-light.json", kPlaneSpots, 600); }

// The same light turned over (its front faces up, away from the plane) and marked two_sided: its
// back must light the plane exactly as the front did (the light pdf uses |cos|, the emission
// test accepts the back face).
TEST(AnalyticPlane, TwoSidedSquareLightFromBehind) { check_plane("plane-light-two-sided.json", kPlaneSpots, 700); }

// A plane mirror (albedo 1) at z = 1.2 facing the camera and the light: the plane is lit by the
// light and by its mirror image (reached only by BSDF sampling through the mirror, which every
// strategy must count with weight 1, as light sampling cannot find it), and the camera sees the
// plane both directly and in the mirror. Exact values by the same formula on the real and the
// mirrored light, along camera rays reflected on the host.
TEST(AnalyticPlane, PlaneMirrorReflectsLightAndView) {
  check_plane("plane-mirror.json",
              {{"direct", {0, 0, 0.7}, false}, {"mirrored", {0, 0, 0.6}, true}, {"mirrored-side", {0.6, 0, 0.3}, true}},
              800);
}

}  // namespace
