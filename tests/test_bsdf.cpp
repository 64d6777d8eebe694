// The BSDF interface (kernels/shared/material.h) on the host, through xi_bsdf_eval, xi_bsdf_sample
// and xi_bsdf_has_non_delta only: one table of materials and incident directions, and every check
// over all of it. χ² of the sampled directions against eval's pdf (and the power of that test),
// sample weights against eval / pdf, reciprocity, the white furnace, delta lobes and lobe kinds,
// valid samples on their lobe's side of both normals, lanes off the surface. The metallic-roughness
// lobes alone are tested in depth in test_microfacet.cpp.
//
// Significance: the χ² tests of the table are judged at family-wise level 1%, Šidák-corrected over
// its cases (sidak_alpha(0.01, cases)); the must-fail samplers must fall below 1e-6. The furnace's
// z-tests use the Šidák critical value at 1% over its cases and channels. Seeds are fixed: one
// stream per check and case.
//
// Run time, about 2.5 s for the file on one core, nearly all of it χ²: 20000 samples per case on
// 12 × 16 cells, refined around the peaks for roughness 0.05 only; cubature to 1e-3 of a cell or
// 1e-6, at most 7 levels deep (well under a sample of error per cell against a noise of at least
// √5); a few thousand samples per case for the other checks.
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <functional>
#include <string>
#include <vector>

#include <glm/glm.hpp>

#include "material.h"
#include "sphere_chi2.h"
#include "stats.h"

namespace {

using namespace xi::sphere_chi2;
using namespace xi::stats;

const glm::vec3 kUp(0.0f, 0.0f, 1.0f);
const glm::vec3 kColour(0.8f, 0.55f, 0.3f), kWhite(1.0f);
// A shading normal 32° off +z, its frame along no axis (the geometric normal alike); and a bumped
// normal 23° off the geometric normal +z, tilted away from wo, so that lobes cross the geometric
// horizon (the mirror direction of wo at 85° among them).
const glm::vec3 kTilted = glm::normalize(glm::vec3(0.3f, -0.4f, 0.8f));
const glm::vec3 kBumped = glm::normalize(glm::vec3(-0.3f, 0.3f, 1.0f));
// A coat's own normal, 16° off the base's in the shading frame (wo stays above it at every angle).
const glm::vec3 kCoatNormal = glm::normalize(glm::vec3(0.25f, -0.15f, 1.0f));
constexpr float kIor = 1.5f;

enum class Kind { Diffuse, Mirror, Glass, Pbr };

struct Case {
  Kind kind;
  glm::vec3 tint;
  float roughness = 0.0f, metallic = 0.0f, transmission = 0.0f;
  bool multiple_scattering = false;
  bool albedo_scaling = true;  // false: the Fresnel mix (microfacet.h's layering)
  float coat = 0.0f, coat_roughness = 0.0f;           // KHR_materials_clearcoat
  glm::vec3 coat_normal = kUp;                        // the coat's own normal, in the shading frame
  glm::vec3 diffuse_normal = kUp;                     // the Lambertian base's own (a turned normal map's)
  float specular = 1.0f;                              // KHR_materials_specular
  glm::vec3 sheen = glm::vec3(0.0f);                  // KHR_materials_sheen
  float sheen_roughness = 0.0f;
  glm::vec3 specular_color = glm::vec3(1.0f);
  float anisotropy = 0.0f;       // KHR_materials_anisotropy's strength
  float anisotropy_turn = 0.0f;  // degrees from wo's azimuth to the anisotropy direction
  float iridescence = 0.0f, film_thickness = 400.0f;  // KHR_materials_iridescence (film ior 1.3)
  bool entering = true;  // glass and PBR transmission: wo outside
  glm::vec3 n = kUp, n_geo = kUp;
  bool white = false;  // the furnace expects a mean weight of 1
  float degrees = 0.0f;
};

// Whether the case has a lobe that is not a delta: the Lambertian, rough PBR, a smooth dielectric's
// diffuse base (a smooth metal's multiple scattering is 0, a transmissive one has no base), a
// rough coat, a sheen.
bool non_delta(const Case& c) {
  return c.kind == Kind::Diffuse ||
         (c.kind == Kind::Pbr && (c.roughness > 0.0f || c.anisotropy > 0.0f || (c.metallic < 1.0f && c.transmission < 1.0f) ||
                                  (c.coat > 0.0f && c.coat_roughness > 0.0f) || c.sheen != glm::vec3(0.0f)));
}

std::string describe(const Case& c) {
  static const char* kinds[] = {"diffuse", "mirror", "glass", "pbr"};
  char buf[200];
  int k = std::snprintf(buf, sizeof buf, "%s tint %.2g %s", kinds[(int)c.kind], c.tint.y,
                        c.entering ? "entering" : "leaving");
  if (c.kind == Kind::Pbr)
    k += std::snprintf(buf + k, sizeof buf - k, " r %.2f m %.1f t %.0f%s%s", c.roughness, c.metallic, c.transmission,
                       c.multiple_scattering ? " ms" : "", c.albedo_scaling ? "" : " mix");
  if (c.coat > 0.0f)
    k += std::snprintf(buf + k, sizeof buf - k, " coat r %.2f%s", c.coat_roughness, c.coat_normal != kUp ? " own n" : "");
  if (c.diffuse_normal != kUp) k += std::snprintf(buf + k, sizeof buf - k, " base n");
  if (c.sheen != glm::vec3(0.0f))
    k += std::snprintf(buf + k, sizeof buf - k, " sheen %.2g r %.2f", c.sheen.x, c.sheen_roughness);
  if (c.anisotropy > 0.0f) k += std::snprintf(buf + k, sizeof buf - k, " aniso %.1f at %.0f", c.anisotropy, c.anisotropy_turn);
  if (c.iridescence > 0.0f) k += std::snprintf(buf + k, sizeof buf - k, " film %.1f %.0f nm", c.iridescence, c.film_thickness);
  if (c.specular != 1.0f || c.specular_color != glm::vec3(1.0f))
    k += std::snprintf(buf + k, sizeof buf - k, " specular %.2g (%.2g %.2g %.2g)", c.specular, c.specular_color.x,
                       c.specular_color.y, c.specular_color.z);
  if (c.n != kUp) k += std::snprintf(buf + k, sizeof buf - k, c.n_geo == c.n ? " tilted n" : " bumped n");
  std::snprintf(buf + k, sizeof buf - k, " %2.0f deg", c.degrees);
  return buf;
}

Case diffuse(glm::vec3 tint) {
  Case c;
  c.kind = Kind::Diffuse, c.tint = tint;
  return c;
}
Case mirror(glm::vec3 tint) {
  Case c;
  c.kind = Kind::Mirror, c.tint = tint;
  return c;
}
Case glass(glm::vec3 tint, bool entering) {
  Case c;
  c.kind = Kind::Glass, c.tint = tint, c.entering = entering;
  return c;
}
Case pbr(glm::vec3 tint, float roughness, float metallic, float transmission, bool multiple_scattering,
         bool entering = true) {
  Case c;
  c.kind = Kind::Pbr, c.tint = tint, c.roughness = roughness, c.metallic = metallic, c.transmission = transmission;
  c.multiple_scattering = multiple_scattering, c.entering = entering;
  return c;
}
Case coated(Case c, float roughness) {
  c.coat = 1.0f, c.coat_roughness = roughness;
  return c;
}
Case diffuse_normal(Case c, glm::vec3 n) {
  c.diffuse_normal = n;
  return c;
}
Case coat_normal(Case c, glm::vec3 n) {
  c.coat_normal = n;
  return c;
}
Case specular(Case c, float strength, glm::vec3 colour) {
  c.specular = strength, c.specular_color = colour;
  return c;
}
Case sheened(Case c, glm::vec3 colour, float roughness) {
  c.sheen = colour, c.sheen_roughness = roughness;
  return c;
}
Case anisotropic(Case c, float strength, float turn_degrees) {
  c.anisotropy = strength, c.anisotropy_turn = turn_degrees;
  return c;
}
Case iridescent(Case c, float weight, float thickness) {
  c.iridescence = weight, c.film_thickness = thickness;
  return c;
}
Case fresnel_mix(Case c) {
  c.albedo_scaling = false;
  return c;
}
Case white(Case c) {
  c.white = true;
  return c;
}
Case normals(Case c, glm::vec3 n, glm::vec3 n_geo) {
  c.n = n, c.n_geo = n_geo;
  return c;
}

std::vector<Case> all_cases() {
  std::vector<Case> m = {diffuse(kColour), white(diffuse(kWhite)), mirror(kColour), white(mirror(kWhite)),
                         white(glass(kWhite, true)), white(glass(kWhite, false)), glass(kColour, true)};
  for (bool ms : {false, true}) {
    for (float r : {0.05f, 0.3f, 1.0f})
      for (float mt : {0.0f, 0.5f, 1.0f})
        for (float t : {0.0f, 1.0f})
          if (mt < 1.0f || t == 0.0f) m.push_back(pbr(kColour, r, mt, t, ms));  // a metal has no transmission
    // Smooth: a metal, an opaque dielectric (a mirror over a diffuse base) and a transmissive one.
    m.push_back(pbr(kColour, 0.0f, 1.0f, 0.0f, ms));
    m.push_back(pbr(kColour, 0.0f, 0.0f, 0.0f, ms));
    m.push_back(pbr(kColour, 0.0f, 0.0f, 1.0f, ms));
  }
  // White metals that reflect everything they receive once multiple scattering is restored, and
  // white dielectrics whose base gets all the layer leaves (albedo scaling).
  for (float r : {0.3f, 1.0f}) m.push_back(white(pbr(kWhite, r, 1.0f, 0.0f, true)));
  for (float r : {0.0f, 0.05f, 0.3f, 1.0f}) m.push_back(white(pbr(kWhite, r, 0.0f, 0.0f, true)));
  // The Fresnel mix, reciprocal.
  for (float r : {0.0f, 0.05f, 0.3f, 1.0f}) m.push_back(fresnel_mix(pbr(kColour, r, 0.0f, 0.0f, true)));
  // A clear coat, smooth and rough, over a rough dielectric, a metal and glass; white under a white
  // coat reflects all; and both layerings.
  for (float cr : {0.0f, 0.3f}) {
    m.push_back(coated(pbr(kColour, 0.3f, 0.0f, 0.0f, true), cr));
    m.push_back(coated(pbr(kColour, 0.05f, 1.0f, 0.0f, true), cr));
    m.push_back(coated(pbr(kColour, 0.3f, 0.0f, 1.0f, true), cr));
    m.push_back(coated(pbr(kColour, 0.0f, 0.0f, 0.0f, true), cr));
    m.push_back(white(coated(pbr(kWhite, 1.0f, 0.0f, 0.0f, true), cr)));
    m.push_back(fresnel_mix(coated(pbr(kColour, 0.3f, 0.0f, 0.0f, true), cr)));
    // The coat's own normal (glTF's: not the base's normal map, or the coat's own map).
    m.push_back(coat_normal(coated(pbr(kColour, 0.3f, 0.0f, 0.0f, true), cr), kCoatNormal));
    m.push_back(coat_normal(coated(pbr(kColour, 0.0f, 1.0f, 0.0f, true), cr), kCoatNormal));
  }
  // KHR_materials_specular: a tinted, weakened layer over a base and over glass; a weakened white
  // one over a white base reflects all.
  for (float r : {0.0f, 0.3f}) {
    m.push_back(specular(pbr(kColour, r, 0.0f, 0.0f, true), 0.5f, glm::vec3(1.0f, 0.5f, 2.0f)));
    m.push_back(specular(pbr(kColour, r, 0.0f, 1.0f, true), 0.5f, glm::vec3(1.0f, 0.5f, 2.0f)));
    m.push_back(white(specular(pbr(kWhite, r, 0.0f, 0.0f, true), 0.5f, glm::vec3(1.0f))));
  }
  m.push_back(fresnel_mix(specular(pbr(kColour, 0.3f, 0.0f, 0.0f, true), 0.5f, glm::vec3(1.0f, 0.5f, 2.0f))));
  // KHR_materials_sheen over a dielectric, a smooth metal and glass, under a coat; white over white
  // reflects all (roughness 0.3 passes 1 at grazing angles before its normalisation).
  for (float sr : {0.3f, 0.8f}) {
    m.push_back(sheened(pbr(kColour, 0.5f, 0.0f, 0.0f, true), glm::vec3(1.0f, 0.6f, 0.2f), sr));
    // (Over a smooth metal only the sheen is sampled by density: at 0.3 too little of it at 0°.)
    if (sr > 0.5f) m.push_back(sheened(pbr(kColour, 0.0f, 1.0f, 0.0f, true), glm::vec3(1.0f, 0.6f, 0.2f), sr));
    m.push_back(sheened(pbr(kColour, 0.3f, 0.0f, 1.0f, true), glm::vec3(1.0f, 0.6f, 0.2f), sr));
    m.push_back(coated(sheened(pbr(kColour, 0.5f, 0.0f, 0.0f, true), glm::vec3(0.5f), sr), 0.1f));
    m.push_back(white(sheened(pbr(kWhite, 0.5f, 0.0f, 0.0f, true), glm::vec3(1.0f), sr)));
  }
  m.push_back(pbr(kColour, 0.3f, 0.0f, 1.0f, true, false));
  // KHR_materials_anisotropy: a metal, a dielectric and glass, along wo's azimuth and turned from it;
  // a nearly smooth metal made rough along one direction; the reciprocal Fresnel mix; white ones
  // (whose approximate compensation is not expected to reflect exactly all).
  m.push_back(anisotropic(pbr(kColour, 0.3f, 1.0f, 0.0f, true), 0.5f, 0.0f));
  m.push_back(anisotropic(pbr(kColour, 0.3f, 1.0f, 0.0f, false), 0.9f, 30.0f));
  m.push_back(anisotropic(pbr(kColour, 0.2f, 0.0f, 0.0f, true), 0.9f, 90.0f));
  m.push_back(anisotropic(pbr(kColour, 0.3f, 0.0f, 1.0f, true), 0.6f, 45.0f));
  m.push_back(anisotropic(pbr(kColour, 0.3f, 0.0f, 1.0f, true, false), 0.6f, 120.0f));
  m.push_back(anisotropic(pbr(kColour, 0.15f, 1.0f, 0.0f, true), 0.8f, 60.0f));
  m.push_back(anisotropic(fresnel_mix(pbr(kColour, 0.3f, 0.0f, 0.0f, true)), 0.7f, 20.0f));
  m.push_back(anisotropic(pbr(kWhite, 0.3f, 1.0f, 0.0f, true), 0.7f, 30.0f));
  m.push_back(anisotropic(pbr(kWhite, 0.3f, 0.0f, 0.0f, true), 0.7f, 30.0f));
  // A turned normal map's base keeps the map's normal: under a rough layer, a half metal.
  m.push_back(diffuse_normal(pbr(kColour, 0.3f, 0.0f, 0.0f, true), kCoatNormal));
  m.push_back(diffuse_normal(pbr(kColour, 0.5f, 0.5f, 0.0f, true), kCoatNormal));
  // KHR_materials_iridescence: a film over a rough and a smooth dielectric, a metal, glass from
  // outside and inside (where it has none), and the reciprocal Fresnel mix.
  m.push_back(iridescent(pbr(kColour, 0.3f, 0.0f, 0.0f, true), 1.0f, 400.0f));
  m.push_back(iridescent(pbr(kColour, 0.0f, 0.0f, 0.0f, true), 0.8f, 250.0f));
  m.push_back(iridescent(pbr(kColour, 0.3f, 1.0f, 0.0f, true), 0.7f, 300.0f));
  m.push_back(iridescent(pbr(kColour, 0.0f, 1.0f, 0.0f, true), 1.0f, 500.0f));
  m.push_back(iridescent(pbr(kColour, 0.3f, 0.0f, 1.0f, true), 1.0f, 400.0f));
  m.push_back(iridescent(pbr(kColour, 0.3f, 0.0f, 1.0f, true, false), 1.0f, 400.0f));
  m.push_back(iridescent(fresnel_mix(pbr(kColour, 0.3f, 0.0f, 0.0f, true)), 1.0f, 600.0f));
  m.push_back(iridescent(pbr(kWhite, 0.3f, 0.0f, 0.0f, true), 1.0f, 400.0f));
  // A shading normal with its own frame (the geometric normal alike), and a bumped one.
  for (Case c : {diffuse(kColour), mirror(kColour), glass(kColour, true), pbr(kColour, 0.3f, 0.5f, 1.0f, true)})
    m.push_back(normals(c, kTilted, kTilted));
  for (Case c : {diffuse(kColour), mirror(kColour), glass(kColour, true), pbr(kColour, 0.3f, 0.0f, 1.0f, false)})
    m.push_back(normals(c, kBumped, kUp));
  std::vector<Case> out;
  for (const Case& c : m)
    for (float d : {0.0f, 60.0f, 85.0f}) {
      out.push_back(c);
      out.back().degrees = d;
    }
  return out;
}

// The material as shade builds it (n and n_geo on wo's side, the frame from xi_basis), with wo at
// c.degrees from n towards x of the frame (t, b, n) the tests bin in. The lobes' frame is that one
// turned by c.anisotropy_turn about n: an anisotropic lobe's direction is its x.
struct Surface {
  Bsdf b;
  uint shading;
  glm::vec3 wo, wo_local;
  float eta;
  glm::vec3 t, bt;  // the test's frame (t, bt, b.n)
  glm::vec3 to_world(glm::vec3 l) const { return t * l.x + bt * l.y + b.n * l.z; }
  glm::vec3 to_local(glm::vec3 w) const { return {glm::dot(w, t), glm::dot(w, bt), glm::dot(w, b.n)}; }
};

Surface surface(const Case& c, bool at_surface = true) {
  static const uint types[] = {XI_MATERIAL_DIFFUSE, XI_MATERIAL_MIRROR, XI_MATERIAL_DIELECTRIC, XI_MATERIAL_PBR};
  Surface s;
  Bsdf& b = s.b;
  b.at_surface = at_surface;
  b.type = types[(int)c.kind];
  b.tint = c.tint;
  b.ior = kIor;
  b.entering = c.entering;
  b.n = c.n;
  b.n_geo = c.n_geo;
  xi_basis(b.n, &s.t, &s.bt);
  const double turn = c.anisotropy_turn * kPi / 180.0;
  b.frame_t = s.t * (float)std::cos(turn) + s.bt * (float)std::sin(turn);
  b.frame_b = s.bt * (float)std::cos(turn) - s.t * (float)std::sin(turn);
  s.eta = c.entering ? kIor : 1.0f / kIor;
  b.pbr = xi_plain_pbr_lobes(c.tint);
  b.pbr.metallic = c.metallic;
  b.pbr.alpha = c.roughness * c.roughness;
  b.pbr.eta = s.eta;
  b.pbr.transmission = c.transmission;
  b.pbr.multiple_scattering = c.multiple_scattering ? 1.0f : 0.0f;
  b.pbr.albedo_scaling = c.albedo_scaling ? 1.0f : 0.0f;
  b.pbr.coat = c.coat;
  b.pbr.coat_alpha = c.coat_roughness * c.coat_roughness;
  b.pbr.coat_normal = c.coat_normal;
  b.pbr.diffuse_normal = c.diffuse_normal;
  b.pbr.specular = c.specular;
  b.pbr.specular_color = c.specular_color;
  b.pbr.sheen_color = c.sheen;
  b.pbr.sheen_alpha = c.sheen_roughness * c.sheen_roughness;
  xi_set_anisotropy(&b.pbr, c.anisotropy);
  b.pbr.iridescence = c.iridescence;
  b.pbr.iridescence_thickness = c.film_thickness;
  s.shading = XI_USE_MIRROR | XI_USE_DIELECTRIC | XI_USE_PBR | (c.multiple_scattering ? XI_USE_MULTIPLE_SCATTERING : 0u) |
              (c.albedo_scaling ? XI_USE_ALBEDO_SCALING : 0u) | XI_USE_SPECULAR | XI_USE_CLEARCOAT | XI_USE_SHEEN |
              XI_USE_ANISOTROPY | XI_USE_IRIDESCENCE;
  double t = c.degrees * kPi / 180.0;
  s.wo_local = glm::vec3((float)std::sin(t), 0.0f, (float)std::cos(t));
  s.wo = glm::normalize(s.to_world(s.wo_local));
  b.pbr_at = xi_bsdf_at_wo(b, s.wo);
  return s;
}

BsdfSample draw(const Surface& s, Uniform& xi) {
  float ul = xi();
  return xi_bsdf_sample(s.b, s.shading, s.wo, ul, xi.pair());
}
glm::vec3 f_of(const BsdfValue& v) { return v.colour * v.scale; }
// A direction above the shading normal.
glm::vec3 random_above(const Surface& s, Uniform& xi) {
  glm::vec3 d = xi_square_to_hemisphere(xi.pair());
  d.z = std::max(d.z, 1e-3f);
  return glm::normalize(s.to_world(d));
}

bool finite(glm::vec3 v) { return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z); }
bool close(float a, float b, float rel, float abs = 0.0f) {
  return std::fabs(a - b) <= rel * std::max(std::fabs(a), std::fabs(b)) + abs;
}
bool close(glm::vec3 a, glm::vec3 b, float rel, float abs = 0.0f) {
  return close(a.x, b.x, rel, abs) && close(a.y, b.y, rel, abs) && close(a.z, b.z, rel, abs);
}
std::string str(glm::vec3 v) {
  char buf[96];
  std::snprintf(buf, sizeof buf, "(%.7g, %.7g, %.7g)", v.x, v.y, v.z);
  return buf;
}

// ---------------------------------------------------------------------------------------------
// χ² of the sampled directions, binned in the shading frame (wo at φ = 0, as the grid wants),
// against a density in solid angle integrated over the cells. A direction across the geometric
// normal's horizon from the shading normal's side makes an invalid sample, so the density counts
// there as 0; invalid samples and delta ones (pdf 0) go to one more bin expecting 1 − ∫ density.

constexpr int kChi2Samples = 20000;
constexpr int kCellsTheta = 12, kCellsPhi = 16;

struct Chi2Run {
  Chi2Result r;
  double total;                        // ∫ density over the valid directions
  double off_grid, off_grid_expected;  // the extra bin
};

// narrow: a lobe of roughness 0.05, whose peaks need the grid's refinement; the others spread over
// the even cells. A coat with its own normal ends at its own horizon, across the cells: the
// cubature starts deeper everywhere so that no cell's sliver of it is missed.
// Where a valid sample may leave: on the same side of the shading and geometric normals, or, from
// an opaque metallic-roughness surface (whose coat has its own normal), above the geometric one.
bool may_leave(const Surface& s, glm::vec3 w) {
  const float sn = glm::dot(w, s.b.n), sg = glm::dot(w, s.b.n_geo);
  return s.b.type == XI_MATERIAL_PBR && s.b.pbr.transmission <= 0.0f ? sg > 0.0f : sn * sg > 0.0f;
}

Chi2Run chi2_run(const Surface& s, const std::function<double(glm::vec3)>& density, uint32_t seed, bool narrow,
                 bool own_coat_normal = false) {
  SphereGrid g = sphere_grid(s.wo_local, s.eta, kCellsTheta, kCellsPhi, narrow ? 6 : 0);
  std::vector<double> expected = cell_integrals(
      g,
      [&](glm::vec3 l) {
        glm::vec3 w = s.to_world(l);
        return may_leave(s, w) ? density(w) : 0.0;
      },
      1e-3, 1e-6, narrow ? 1 : 2, 7, own_coat_normal ? 4 : 1);
  Chi2Run run;
  run.total = 0.0;
  for (double e : expected) run.total += e;
  expected.push_back(std::max(1.0 - run.total, 1e-12));
  for (double& e : expected) e *= kChi2Samples;
  std::vector<double> observed(expected.size(), 0.0);
  Uniform xi(seed);
  for (int k = 0; k < kChi2Samples; ++k) {
    BsdfSample smp = draw(s, xi);
    bool off = !smp.valid || smp.pdf == 0.0f;
    observed[off ? g.cells() : cell_of(g, s.to_local(smp.wi))] += 1.0;
  }
  run.off_grid = observed.back();
  run.off_grid_expected = expected.back();
  run.r = chi2_test(observed, expected);
  return run;
}

double eval_pdf(const Surface& s, glm::vec3 w) { return xi_bsdf_eval(s.b, s.shading, s.wo, w).pdf; }
// The density of valid samples: eval's pdf where f > 0 (a sample of weight 0 ends its path: a
// turned normal map's base, whose own normal faces away from some directions the cosine lobe
// about +z draws).
double valid_density(const Surface& s, glm::vec3 w) {
  BsdfValue v = xi_bsdf_eval(s.b, s.shading, s.wo, w);
  glm::vec3 f = f_of(v);
  return std::max(f.x, std::max(f.y, f.z)) > 0.0f ? v.pdf : 0.0;
}

TEST(BsdfChi2, SamplesMatchEvalPdf) {
  std::vector<Case> cases;
  for (const Case& c : all_cases())
    if (non_delta(c)) cases.push_back(c);
  const double level = sidak_alpha(0.01, (int)cases.size());
  auto start = std::chrono::steady_clock::now();
  for (size_t i = 0; i < cases.size(); ++i) {
    const Case& c = cases[i];
    Surface s = surface(c);
    Chi2Run run = chi2_run(s, [&](glm::vec3 w) { return valid_density(s, w); }, 0xb5d0u + (uint32_t)i,
                           c.kind == Kind::Pbr && c.roughness > 0.0f && c.roughness < 0.1f, c.coat_normal != kUp);
    std::printf("[ chi2     ] %-52s X2 = %7.1f dof = %3d p = %.4f off-grid %5.0f (expected %7.1f)\n",
                describe(c).c_str(), run.r.statistic, run.r.dof, run.r.p_value, run.off_grid, run.off_grid_expected);
    EXPECT_LE(run.total, 1.0 + 1e-3) << describe(c);
    EXPECT_GT(run.total, 0.0) << describe(c);
    EXPECT_GE(run.r.dof, 20) << describe(c);
    EXPECT_GE(run.r.p_value, level) << describe(c) << ": X2 = " << run.r.statistic << ", dof = " << run.r.dof;
  }
  std::printf("[ chi2     ] %zu cases in %.2f s\n", cases.size(),
              std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count());
}

// The same harness rejects samples whose density is not the one tested: cosine-weighted samples
// against the normalised cos² density, and roughness 0.3 metal samples against the pdf of
// roughness 0.36.
TEST(BsdfChi2Power, WrongDensitiesAreRejected) {
  const double must_fail = 1e-6;
  Case lambert = diffuse(kColour);
  lambert.degrees = 60.0f;
  Surface s = surface(lambert);
  Chi2Run run = chi2_run(
      s,
      [&](glm::vec3 w) {
        double c = std::max(glm::dot(w, s.b.n), 0.0f);
        return 3.0 * c * c / kTwoPi;
      },
      0x5a11u, false);
  std::printf("[ chi2     ] diffuse against cos^2: X2 = %.1f dof = %d p = %.3g\n", run.r.statistic, run.r.dof,
              run.r.p_value);
  EXPECT_NEAR(run.total, 1.0, 1e-3);  // the wrong density is a density
  EXPECT_LT(run.r.p_value, must_fail);

  for (float degrees : {0.0f, 60.0f}) {
    Case metal = pbr(kColour, 0.3f, 1.0f, 0.0f, false);
    metal.degrees = degrees;
    Case other = metal;
    other.roughness = 0.36f;
    Surface sm = surface(metal), so = surface(other);
    run = chi2_run(sm, [&](glm::vec3 w) { return eval_pdf(so, w); }, 0x5a12u + (uint32_t)degrees, false);
    std::printf("[ chi2     ] metal r 0.30 %2.0f deg against r 0.36: X2 = %.1f dof = %d p = %.3g\n", degrees,
                run.r.statistic, run.r.dof, run.r.p_value);
    EXPECT_LT(run.r.p_value, must_fail) << degrees << " deg";
  }

  // The layers: a coat sampled at roughness 0.3 against the density of one at 0.45; a sheen's and
  // a weakened specular layer's samples against the density of the material without them (their
  // albedos change how often each lobe is chosen); an anisotropic metal's against the isotropic
  // density and against the density of its direction turned 90°.
  struct Wrong {
    const char* what;
    Case sampled, density;
  };
  Case coat = coated(pbr(kColour, 0.5f, 0.0f, 0.0f, true), 0.3f), rougher_coat = coated(coat, 0.45f);
  Case base = pbr(kColour, 0.5f, 0.0f, 0.0f, true);
  Case metal = pbr(kColour, 0.3f, 1.0f, 0.0f, false);
  const Wrong wrong[] = {{"coat r 0.30 against r 0.45", coat, rougher_coat},
                         {"coat with its own normal against the base's", coat_normal(coat, kCoatNormal), coat},
                         {"sheen against none", sheened(base, glm::vec3(1.0f), 0.8f), base},
                         {"specular 0.2 against 1", specular(pbr(kColour, 0.2f, 0.0f, 0.0f, true), 0.2f, glm::vec3(1.0f)),
                          pbr(kColour, 0.2f, 0.0f, 0.0f, true)},
                         {"anisotropic metal against the isotropic one", anisotropic(metal, 0.6f, 30.0f), metal},
                         {"anisotropy at 30 deg against at 120 deg", anisotropic(metal, 0.6f, 30.0f),
                          anisotropic(metal, 0.6f, 120.0f)}};
  for (const Wrong& w : wrong) {
    Case a = w.sampled, b = w.density;
    a.degrees = b.degrees = 60.0f;
    Surface sa = surface(a), sb = surface(b);
    run = chi2_run(sa, [&](glm::vec3 d) { return eval_pdf(sb, d); }, 0x5a20u, false);
    std::printf("[ chi2     ] %s: X2 = %.1f dof = %d p = %.3g\n", w.what, run.r.statistic, run.r.dof, run.r.p_value);
    EXPECT_LT(run.r.p_value, must_fail) << w.what;
  }
}

// ---------------------------------------------------------------------------------------------
// A non-delta sample's weight is colour · scale · |cos θi| / pdf of eval at its wi, and eval's pdf
// there is the sample's.

TEST(BsdfConsistency, WeightIsEvalCosOverPdf) {
  const std::vector<Case> cases = all_cases();
  for (size_t i = 0; i < cases.size(); ++i) {
    const Case& c = cases[i];
    Surface s = surface(c);
    Uniform xi(0xc0d0u + (uint32_t)i);
    int checked = 0;
    for (int k = 0; k < 2000; ++k) {
      BsdfSample smp = draw(s, xi);
      ASSERT_TRUE(finite(smp.wi) && finite(smp.weight) && std::isfinite(smp.pdf)) << describe(c);
      if (!smp.valid || smp.pdf == 0.0f) continue;
      BsdfValue v = xi_bsdf_eval(s.b, s.shading, s.wo, smp.wi);
      float cos_i = std::fabs(glm::dot(smp.wi, s.b.n));
      glm::vec3 expect = f_of(v) * cos_i / v.pdf;
      // wi crosses between the shading frame and the world in float: its cosine carries an absolute
      // error of a few 1e-8, a relative one that grows at grazing angles.
      const float rel = 1e-4f + 3e-7f / cos_i;
      ASSERT_TRUE(close(v.pdf, smp.pdf, rel)) << describe(c) << ": eval pdf " << v.pdf << ", sample pdf "
                                                 << smp.pdf << " at " << str(smp.wi);
      ASSERT_TRUE(close(smp.weight, expect, rel))
          << describe(c) << ": weight " << str(smp.weight) << ", eval " << str(expect) << " at " << str(smp.wi);
      ++checked;
    }
    // Every material with a non-delta lobe produces such samples: at least half of them where it
    // is rough (single-scattering GGX at roughness 1 sends ~40% below the horizon), a smooth
    // dielectric's base a few percent.
    if (non_delta(c)) {
      EXPECT_GT(checked, c.roughness > 0.0f || c.kind == Kind::Diffuse ? 500 : 20) << describe(c);
    } else {
      EXPECT_EQ(checked, 0) << describe(c);
    }
  }
}

// Whether f(wo, wi) = f(wi, wo): every case but a dielectric base under albedo scaling, rough glass
// compensated with it and a clear coat, which weigh by wo alone (test_microfacet.cpp's
// MicrofacetLayering and MicrofacetGlass check those instead).
bool reciprocal(const Case& c) {
  return !(c.kind == Kind::Pbr &&
           ((c.albedo_scaling && c.metallic < 1.0f && (c.transmission < 1.0f || c.roughness > 0.0f)) ||
            c.coat > 0.0f || c.sheen != glm::vec3(0.0f) || c.diffuse_normal != kUp));
}

// f(wo, wi) = f(wi, wo) for both above the shading normal, for every reciprocal case (0 for the
// delta-only ones: eval reaches no delta lobe).
TEST(BsdfReciprocity, ReflectionIsSymmetric) {
  const std::vector<Case> cases = all_cases();
  int checked = 0;
  for (size_t i = 0; i < cases.size(); ++i) {
    const Case& c = cases[i];
    if (!reciprocal(c)) continue;
    ++checked;
    Surface s = surface(c);
    Uniform xi(0x5ee0u + (uint32_t)i);
    for (int k = 0; k < 500; ++k) {
      glm::vec3 a = random_above(s, xi), b = random_above(s, xi);
      // The BSDF as shade builds it at a hit seen from a, and at one seen from b.
      Bsdf from_a = s.b, from_b = s.b;
      from_a.pbr_at = xi_bsdf_at_wo(s.b, a);
      from_b.pbr_at = xi_bsdf_at_wo(s.b, b);
      glm::vec3 fab = f_of(xi_bsdf_eval(from_a, s.shading, a, b)), fba = f_of(xi_bsdf_eval(from_b, s.shading, b, a));
      ASSERT_TRUE(finite(fab) && finite(fba)) << describe(c);
      ASSERT_TRUE(close(fab, fba, 1e-4f, 1e-6f))
          << describe(c) << ": f(a, b) " << str(fab) << ", f(b, a) " << str(fba) << ", a " << str(a) << ", b "
          << str(b);
      if (!non_delta(c)) {
        ASSERT_EQ(fab, glm::vec3(0.0f)) << describe(c);
      }
    }
  }
  EXPECT_GE(checked, 3 * 30);  // the Fresnel mix among them
}

// ---------------------------------------------------------------------------------------------
// White furnace: the mean weight (0 where a sample is invalid) is 1 for the white materials (40000
// samples), and at most 1 for every case (4000), within the Šidák critical z (1% over the cases'
// channels) standard errors plus 1e-4 for rounding, 0.01 for a metal with its multiple scattering
// and a rough dielectric layer's albedo scaling (interpolated tables, test_microfacet.cpp's furnace). The same white metal at roughness 1 with
// single scattering alone must come out darker than 0.9: the furnace sees energy lost.

struct Furnace {
  glm::dvec3 mean, se;
};

Furnace furnace(const Surface& s, uint32_t seed, int n) {
  Uniform xi(seed);
  glm::dvec3 sum(0.0), sum2(0.0);
  for (int k = 0; k < n; ++k) {
    BsdfSample smp = draw(s, xi);
    glm::dvec3 w = smp.valid ? glm::dvec3(smp.weight) : glm::dvec3(0.0);
    sum += w, sum2 += w * w;
  }
  Furnace f;
  f.mean = sum / (double)n;
  f.se = glm::sqrt(glm::max(sum2 / (double)n - f.mean * f.mean, glm::dvec3(0.0)) / (double)(n - 1));
  return f;
}

TEST(BsdfFurnace, WhiteReflectsAllAndNoneGains) {
  const std::vector<Case> cases = all_cases();
  const double z = sidak_critical_z(0.01, 3 * (int)cases.size());
  int white = 0;
  for (size_t i = 0; i < cases.size(); ++i) {
    const Case& c = cases[i];
    Furnace f = furnace(surface(c), 0xf000u + (uint32_t)i, c.white ? 40000 : 4000);
    // Interpolated tables: a metal's multiple scattering, a rough layer's albedo scaling.
    const bool tables = c.kind == Kind::Pbr && ((c.metallic > 0.0f && c.multiple_scattering) ||
                                                ((c.roughness > 0.0f || c.coat_roughness > 0.0f || c.sheen != glm::vec3(0.0f)) &&
                                                 !reciprocal(c)));
    double slack = tables ? 0.01 : 1e-4;
    if (c.white || c.anisotropy > 0.0f || c.iridescence > 0.0f)
      std::printf("[ furnace  ] %-52s %.5f ± %.1e\n", describe(c).c_str(), f.mean.x, f.se.x);
    white += c.white;
    for (int ch = 0; ch < 3; ++ch) {
      double tol = z * f.se[ch] + slack;
      EXPECT_LE(f.mean[ch], 1.0 + tol) << describe(c) << " channel " << ch << ": " << f.mean[ch] << " ± " << f.se[ch];
      if (c.white) {
        EXPECT_NEAR(f.mean[ch], 1.0, tol) << describe(c) << " channel " << ch << " ± " << f.se[ch];
      }
    }
  }
  EXPECT_EQ(white, 3 * 16);
  Case single = pbr(kWhite, 1.0f, 1.0f, 0.0f, false);
  for (float d : {0.0f, 60.0f, 85.0f}) {
    single.degrees = d;
    Furnace f = furnace(surface(single), 0xf100u + (uint32_t)d, 4000);
    std::printf("[ furnace  ] %-52s %.5f ± %.1e (single scattering)\n", describe(single).c_str(), f.mean.x, f.se.x);
    EXPECT_LT(f.mean.x, 0.9) << describe(single);
  }
}

// ---------------------------------------------------------------------------------------------
// Delta lobes and the kinds of lobe samples report.

TEST(BsdfLobes, DeltaLobesAndKinds) {
  const std::vector<Case> cases = all_cases();
  const uint kinds = XI_LOBE_DIFFUSE | XI_LOBE_GLOSSY | XI_LOBE_SPECULAR;
  for (size_t i = 0; i < cases.size(); ++i) {
    const Case& c = cases[i];
    Surface s = surface(c);
    const bool has_non_delta = xi_bsdf_has_non_delta(s.b, s.shading);
    // Mirror, glass and smooth metal have only delta lobes; the Lambertian and rough PBR do not. (A
    // smooth transmissive dielectric has only delta lobes too, but the interface may answer true
    // there: a light sample then finds f = 0. Only a false answer must be right.)
    if (!(c.kind == Kind::Pbr && c.roughness == 0.0f && c.transmission > 0.0f)) {
      EXPECT_EQ(has_non_delta, non_delta(c)) << describe(c);
    }
    Uniform xi(0x10b0u + (uint32_t)i);
    int reflected = 0, transmitted = 0, specular = 0, valid = 0;
    for (int k = 0; k < 2000; ++k) {
      BsdfSample smp = draw(s, xi);
      if (!smp.valid) continue;
      ++valid;
      const uint kind = smp.lobe & kinds;
      // (An opaque metallic-roughness surface only reflects, its coat's reflections perhaps below n.)
      const bool opaque = s.b.type == XI_MATERIAL_PBR && s.b.pbr.transmission <= 0.0f;
      const bool below = glm::dot(smp.wi, opaque ? s.b.n_geo : s.b.n) < 0.0f;
      ASSERT_TRUE(kind == XI_LOBE_DIFFUSE || kind == XI_LOBE_GLOSSY || kind == XI_LOBE_SPECULAR)
          << describe(c) << ": lobe " << smp.lobe;
      ASSERT_TRUE((smp.lobe & (XI_LOBE_REFLECTION | XI_LOBE_TRANSMISSION)) ==
                  (below ? XI_LOBE_TRANSMISSION : XI_LOBE_REFLECTION))
          << describe(c) << ": lobe " << smp.lobe << ", wi " << str(smp.wi);
      ASSERT_EQ(smp.lobe & ~(kinds | XI_LOBE_REFLECTION | XI_LOBE_TRANSMISSION), 0u) << describe(c);
      below ? ++transmitted : ++reflected;
      if (!has_non_delta) {
        ASSERT_EQ(kind, XI_LOBE_SPECULAR) << describe(c);
      }
      switch (c.kind) {
        case Kind::Diffuse:
          ASSERT_EQ(smp.lobe, XI_LOBE_REFLECTION | XI_LOBE_DIFFUSE) << describe(c);
          break;
        case Kind::Mirror:
          ASSERT_EQ(smp.lobe, XI_LOBE_REFLECTION | XI_LOBE_SPECULAR) << describe(c);
          break;
        case Kind::Glass:
          ASSERT_EQ(kind, XI_LOBE_SPECULAR) << describe(c);
          break;
        case Kind::Pbr: {
          // A smooth base or coat gives delta lobes; a rough one glossy lobes.
          const bool coat = c.coat > 0.0f;
          if (c.roughness > 0.0f && !(coat && c.coat_roughness == 0.0f)) {
            ASSERT_NE(kind, XI_LOBE_SPECULAR) << describe(c);
          }
          if (c.roughness == 0.0f && !(coat && c.coat_roughness > 0.0f)) {
            ASSERT_NE(kind, XI_LOBE_GLOSSY) << describe(c);
          }
          break;
        }
      }
      if (kind != XI_LOBE_SPECULAR) {
        ASSERT_GT(smp.pdf, 0.0f) << describe(c);
        continue;
      }
      ++specular;
      ASSERT_EQ(smp.pdf, 0.0f) << describe(c);
      BsdfValue v = xi_bsdf_eval(s.b, s.shading, s.wo, smp.wi);
      if (!non_delta(c)) {
        // Eval reaches no delta lobe.
        ASSERT_EQ(v.pdf, 0.0f) << describe(c);
        ASSERT_EQ(f_of(v), glm::vec3(0.0f)) << describe(c);
      } else if (c.roughness == 0.0f && !(c.coat > 0.0f && c.coat_roughness > 0.0f)) {
        // A smooth dielectric's base: eval's pdf is the cosine lobe's alone, the same about n. (A
        // rough base or coat beside a smooth one peaks there instead: the χ² test covers those.)
        glm::vec3 l = s.to_local(smp.wi);
        float cs = std::cos(0.01f), sn = std::sin(0.01f);
        glm::vec3 turned = s.to_world({cs * l.x - sn * l.y, sn * l.x + cs * l.y, l.z});
        ASSERT_TRUE(close(v.pdf, (float)eval_pdf(s, turned), 1e-4f, 1e-6f))
            << describe(c) << ": pdf " << v.pdf << " at the delta direction, " << eval_pdf(s, turned) << " beside it";
      }
      // The mirror direction about n (or about the coat's own normal), or Snell's refraction.
      if (!below) {
        auto mirror = [&](glm::vec3 n) { return n * (2.0f * glm::dot(s.wo, n)) - s.wo; };
        const glm::vec3 coat_n = glm::normalize(s.to_world(c.coat_normal));
        ASSERT_TRUE(glm::length(smp.wi - mirror(s.b.n)) < 1e-5f ||
                    (c.coat > 0.0f && glm::length(smp.wi - mirror(coat_n)) < 1e-5f))
            << describe(c) << ": " << str(smp.wi);
      } else {
        float sin_o = glm::length(glm::cross(s.wo, s.b.n)), sin_i = glm::length(glm::cross(smp.wi, s.b.n));
        ASSERT_NEAR(sin_i, sin_o / s.eta, 1e-5f) << describe(c);
      }
    }
    if (c.n_geo == c.n) {
      EXPECT_GT(valid, 500) << describe(c);
    }
    if (!non_delta(c)) {
      EXPECT_EQ(specular, valid) << describe(c);
    }
    // Glass entering at 0° reflects ~4% and refracts the rest; leaving past 41.8° it only reflects.
    if (c.kind == Kind::Glass && c.degrees == 0.0f) {
      EXPECT_GT(reflected, 20) << describe(c);
      EXPECT_GT(transmitted, 1500) << describe(c);
    }
    if (c.kind == Kind::Glass && !c.entering && c.degrees > 45.0f) {
      EXPECT_EQ(transmitted, 0) << describe(c);
    }
    if (c.kind == Kind::Pbr && c.transmission > 0.0f && c.degrees == 0.0f) {
      EXPECT_GT(transmitted, 100) << describe(c);
    }
  }
}

// A valid sample leaves on its lobe's side of both normals (material.h's contract): reflection
// above the shading and the geometric normal, transmission below both, or light would leak through
// the surface where a shading normal departs from the geometric one; an opaque metallic-roughness
// surface's reflections above the geometric normal alone (its coat's own normal may send them below
// the base's). A sample that would cross is invalid (the mirror's at 85° on the bumped normal).
TEST(BsdfLobes, ValidSamplesKeepToBothSides) {
  const std::vector<Case> cases = all_cases();
  for (size_t i = 0; i < cases.size(); ++i) {
    const Case& c = cases[i];
    Surface s = surface(c);
    Uniform xi(0x51d0u + (uint32_t)i);
    int crossing = 0, valid = 0;
    std::string example;
    for (int k = 0; k < 2000; ++k) {
      BsdfSample smp = draw(s, xi);
      const float sg = glm::dot(smp.wi, s.b.n_geo);
      if (c.kind == Kind::Mirror) {
        ASSERT_EQ((bool)smp.valid, sg > 0.0f) << describe(c) << ": wi " << str(smp.wi);
      }
      if (!smp.valid) continue;
      ++valid;
      if (!may_leave(s, smp.wi) && crossing++ == 0)
        example = "wi " + str(smp.wi) + ", lobe " + std::to_string(smp.lobe) + ", weight " + str(smp.weight);
    }
    EXPECT_EQ(crossing, 0) << describe(c) << ": " << crossing << " of " << valid
                           << " valid samples cross the geometric horizon, e.g. " << example;
  }
}

// A coat with a normal of its own over an opaque base (Cycles' coat closure) reflects wherever it is
// above the coat's normal and the geometric one, below the base's normal too: a rough coat on the
// geometric normal over a rough red dielectric whose normal map tilts it 19° towards wo, wo at 60°: of 4000 samples some valid coat reflections leave below the base's normal, each above
// the geometric normal with eval's f > 0 and pdf > 0 there. Must-fail: over glass (transmission 1) a
// direction below the base's normal is its transmission side, and no valid reflection goes there.
TEST(BsdfLobes, CoatReflectsBelowTheBasesNormal) {
  for (float transmission : {0.0f, 1.0f}) {
    const glm::vec3 towards_wo = glm::normalize(glm::vec3(0.35f, 0.0f, 1.0f));
    Case c = normals(coated(pbr(kColour, 0.3f, 0.0f, transmission, true), 0.3f), towards_wo, kUp);
    c.degrees = 60.0f;
    Surface s = surface(c);
    s.b.pbr.coat_normal = glm::normalize(s.to_local(s.b.n_geo));
    s.b.pbr_at = xi_bsdf_at_wo(s.b, s.wo);
    Uniform xi(0xc0a7u);
    int below = 0;
    for (int k = 0; k < 4000; ++k) {
      BsdfSample smp = draw(s, xi);
      if (!smp.valid || !(smp.lobe & XI_LOBE_REFLECTION) || glm::dot(smp.wi, s.b.n) >= 0.0f) continue;
      ++below;
      ASSERT_GT(glm::dot(smp.wi, s.b.n_geo), 0.0f);
      BsdfValue v = xi_bsdf_eval(s.b, s.shading, s.wo, smp.wi);
      ASSERT_GT(std::max(v.colour.x, std::max(v.colour.y, v.colour.z)) * v.scale, 0.0f);
      ASSERT_GT(v.pdf, 0.0f);
    }
    std::printf("[ coat     ] transmission %.0f: %d valid reflections below the base's normal\n", transmission, below);
    if (transmission > 0.0f) {
      EXPECT_EQ(below, 0);
    } else {
      EXPECT_GT(below, 0);
    }
  }
}

// Lanes with no surface: eval gives f = 0 and pdf 0, and no sample is valid.
TEST(BsdfOffSurface, NothingScatters) {
  const std::vector<Case> cases = all_cases();
  for (size_t i = 0; i < cases.size(); ++i) {
    const Case& c = cases[i];
    Surface s = surface(c, false);
    Uniform xi(0x0ff0u + (uint32_t)i);
    EXPECT_FALSE(xi_bsdf_has_non_delta(s.b, s.shading)) << describe(c);
    for (int k = 0; k < 50; ++k) {
      glm::vec3 wi = xi_square_to_sphere(xi.pair());
      BsdfValue v = xi_bsdf_eval(s.b, s.shading, s.wo, wi);
      ASSERT_EQ(v.colour, glm::vec3(0.0f)) << describe(c);
      ASSERT_EQ(v.pdf, 0.0f) << describe(c);
      ASSERT_FALSE(draw(s, xi).valid) << describe(c);
    }
  }
}

}  // namespace
