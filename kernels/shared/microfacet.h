// The glTF 2.0 metallic-roughness BSDF (spec appendix B, with KHR_materials_transmission): a GGX
// (Trowbridge–Reitz) microfacet model on lane types (lanes.h).
//
// Every function works in the local shading frame: the normal is +z and wo.z > 0 (the caller flips
// the normal to wo's side and passes eta accordingly). Directions point away from the surface.
//
//   f = mix(dielectric, metal, metallic)
//   metal      = spec(h) · Schlick(f0 = base_color, wo·h)
//   dielectric = spec(h) · F(wo·h)                                        the specular layer
//              + (1 − transmission) · (1 − E_spec(wo.z)) · base_color / π    the base (layering below)
//              + transmission · √base_color · (1 − F(wo·h_t)) · btdf(h_t)
//   spec(h) = D(h) G2 / (4 |wo.z| |wi.z|), h = normalize(wo + wi)           reflection (wi.z > 0)
//   btdf(h) = η² |wi·h| |wo·h| D(h) G2 / (|wo.z| |wi.z| (wo·h + η wi·h)²)  Walter et al. 2007, with
//             h = normalize(wo + η wi) turned to +z                       transmission (wi.z < 0)
//
// D is GGX (anisotropic under KHR_materials_anisotropy: below), G2 the height-correlated Smith term
// 1 / (1 + Λ(wo) + Λ(wi)), F the exact dielectric Fresnel of η, as Blender's Principled BSDF,
// Mitsuba and pbrt use (Schlick's approximation, which the glTF spec's sample code uses, reflects
// less on average: 0.086 against 0.092 at η = 1.5, which shows where the base is dark). The
// dielectric specular reflection and the rough transmission share D, G2 and the microfacet's F, so
// together they keep at most the energy that arrives (F + (1 − F) per microfacet, G2 ≤ G1).
//
// The layering of the dielectric specular over the base (PbrLobes.albedo_scaling):
// - albedo scaling (1, the default; Blender's Principled BSDF and OpenPBR do the same): the base
//   receives what the specular layer does not reflect towards wo, (1 − E_spec(wo.z)), with
//   E_spec(mu) = ∫ spec·F·cos θi the layer's directional albedo, looked up (ggx_albedo.h:
//   f0 E + (1 − f0) E_F). A white base under the layer then reflects exactly what
//   arrives, at every roughness and ior. Like those models it weighs by wo alone: not reciprocal,
//   which a path traced from the camera does not need.
// - the Fresnel mix (0): the base weighed by (1 − F(wo.z)) (1 − F(wi.z)), reciprocal, but it
//   loses the light the rough layer neither reflects nor passes (up to a few percent at high
//   roughness). (The spec's own fresnel_mix, 1 − F(wo·h) with h the half vector of wo and wi, does
//   not conserve energy at all: at grazing wo the smooth layer already reflects nearly everything
//   while the base below is barely dimmed, albedo up to ~1.8.)
//
// Multiple scattering (Kulla and Conty, "Revisiting Physically Based Shading at Imageworks", 2017):
// single-scattering GGX loses the light that bounces between microfacets, up to 69% of it for a
// white metal at roughness 1, so rough metals come out too dark. Where PbrLobes.multiple_scattering
// is 1, the metal gains the reciprocal lobe
//   f_ms = F_ms (1 − E(wo.z)) (1 − E(wi.z)) / (π (1 − E_avg)),   F_ms = F_avg² E_avg / (1 − F_avg (1 − E_avg)),
// E the directional albedo of the single-scattering lobe with a Fresnel of 1 and E_avg its cosine-
// weighted mean (tables in ggx_albedo.h), F_avg = f0 + (1 − f0) / 21 Schlick's mean: a white metal
// then reflects all it receives. It is sampled with the diffuse lobe's cosine distribution. The
// dielectric layer, under albedo scaling, is scaled instead (xi_layer_scattering_scale).
//
// Rough glass loses the light that bounces between its microfacets too (6% at roughness 0.3 seen
// from inside, more at grazing angles and high roughness). With albedo scaling, as Blender's
// Principled BSDF, the glass lobes (the transmission and the transmissive share of the specular
// reflection) are scaled by 1 / E_glass(wo.z), E_glass the single-scattering boundary's albedo
// (ggx_albedo.h, from outside and from inside): white rough glass then keeps what arrives. The
// scale weighs by wo alone, as the layering does.
//
// Transmission is tinted by √base_color at each crossing, so that light through a closed object
// (in and out) is tinted by the base colour once, as through the spec's thin-walled surface and in
// Blender's Principled BSDF.
//
// Light transport convention: the BTDF carries no 1/η² radiance scaling (f·|cos|/pdf of a refracted
// sample is (1 − F) G2/G1, the same in both directions). For camera paths in a scene whose camera
// and lights lie in the same medium the factors cancel along every path, and the BSDF keeps its
// directional albedo ≤ 1 on both sides.
//
// Below XI_DELTA_ALPHA the specular reflection and the transmission are delta lobes (a perfect
// mirror and smooth refraction with the same Fresnel terms at wo.z): xi_pbr_eval and xi_pbr_pdf
// leave them out, xi_pbr_sample returns them with *delta set. No function divides by alpha below
// XI_DELTA_ALPHA or by a cosine below XI_MIN_COS.
#ifndef XI_MICROFACET_H
#define XI_MICROFACET_H
#include "bsdf.h"
#include "ggx_albedo.h"
#include "sheen_albedo.h"
#include "lanes.h"
#include "shading.h"
#include "thin_film.h"
#include "warps.h"

// The diffuse base's own normals (xi_diffuse_cosine) are held only by programs with normal maps: a
// program without them carries no such fields through its BSDFs.
#if XI_COMPILED(XI_USE_NORMAL_MAP)
#define XI_DIFFUSE_NORMALS 1
#else
#define XI_DIFFUSE_NORMALS 0
#endif

#define XI_DELTA_ALPHA 1e-4f  // GGX alpha (roughness²) below which the specular lobes are delta
#define XI_MIN_COS 1e-9f      // cosines in denominators are clamped here

typedef struct {
  xfloat3 base_color;   // linear RGB
  xfloat metallic;      // [0, 1]
  xfloat alpha;         // GGX alpha = roughness² (the caller squares); below XI_DELTA_ALPHA: delta lobes
  // KHR_materials_anisotropy: the base's alphas along the frame's x and y are alpha · stretch_x and
  // alpha · stretch_y (1, 1: isotropic); alpha is then their geometric mean (xi_set_anisotropy).
  xfloat stretch_x, stretch_y;
  xfloat eta;           // n on the far side of the surface / n on wo's side (ior entering, 1/ior leaving)
  xfloat transmission;  // [0, 1] (KHR_materials_transmission)
  xfloat multiple_scattering;  // 1: the metal's and the layer's multiple scattering restored (above); 0: single scattering
  xfloat albedo_scaling;       // 1: the base weighed by the layer's albedo (above); 0: the Fresnel mix
  xfloat3 specular_color;      // KHR_materials_specular: the dielectric f0's tint (1: none)
  xfloat specular;             // KHR_materials_specular: the dielectric layer's strength (1: none)
  xfloat coat;                 // KHR_materials_clearcoat: the coat's weight (0: none)
  xfloat coat_alpha;           // the coat's GGX alpha
  xfloat3 coat_normal;         // the coat's own normal in this frame (+z: the base's), wo above it
#if XI_DIFFUSE_NORMALS
  // Under a normal map, the Lambertian base's own normal in this frame, the map's before shade turned
  // it, and the interpolated normal (+z, +z: none; xi_diffuse_cosine).
  xfloat3 diffuse_normal, smooth_normal;
#endif
  xfloat3 sheen_color;         // KHR_materials_sheen (0: none)
  xfloat sheen_alpha;          // the sheen's alpha, roughness²
  xfloat iridescence;          // KHR_materials_iridescence: the thin film's weight (0: none)
  xfloat iridescence_ior;      // the film's ior
  xfloat iridescence_thickness;  // the film's thickness in nanometres
} PbrLobes;

// A metallic-roughness material of a base colour and nothing else: a smooth dielectric of ior 1.5
// seen from outside, isotropic, none of the layers (the specular layer's 1, no coat, no sheen),
// single scattering and the Fresnel mix. shade and the tests start from it and set what they use.
static inline PbrLobes xi_plain_pbr_lobes(xfloat3 base_color) {
  PbrLobes m;
  m.base_color = base_color;
  m.metallic = m.alpha = m.transmission = 0.0f;
  m.stretch_x = m.stretch_y = 1.0f;
  m.eta = 1.5f;
  m.multiple_scattering = m.albedo_scaling = 0.0f;
  m.specular_color = make_xfloat3((xfloat)1.0f, (xfloat)1.0f, (xfloat)1.0f);
  m.specular = 1.0f;
  m.coat = m.coat_alpha = 0.0f;
  m.coat_normal = make_xfloat3((xfloat)0.0f, (xfloat)0.0f, (xfloat)1.0f);
#if XI_DIFFUSE_NORMALS
  m.diffuse_normal = m.smooth_normal = m.coat_normal;
#endif
  m.sheen_color = make_xfloat3((xfloat)0.0f, (xfloat)0.0f, (xfloat)0.0f);
  m.sheen_alpha = 0.0f;
  m.iridescence = 0.0f;
  m.iridescence_ior = 1.3f;
  m.iridescence_thickness = 400.0f;
  return m;
}

// --- GGX

// D(h) = 1 / (π α² (sin²θ/α² + cos²θ)²) for h above the surface, 0 below. (The form of sin² taken
// from x and y stays accurate for the tiny angles of a near-delta lobe.)
static inline xfloat xi_ggx_d(xfloat3 h, xfloat alpha) {
  xfloat a = fmax(alpha, (xfloat)XI_DELTA_ALPHA), a2 = a * a;
  xfloat t = (h.x * h.x + h.y * h.y) / a2 + h.z * h.z;
  return h.z > 0.0f ? 1.0f / (XI_PI * a2 * t * t) : (xfloat)0.0f;
}

// Smith Λ(w) = (√(1 + α² tan²θ) − 1) / 2, written as x / (2 (1 + √(1 + x))), x = α² tan²θ, which
// keeps its digits for small x; tan²θ is bounded by the clamp of cos²θ at 1e-30.
static inline xfloat xi_ggx_lambda(xfloat3 w, xfloat alpha) {
  xfloat a = fmax(alpha, (xfloat)XI_DELTA_ALPHA);
  xfloat x = a * a * (w.x * w.x + w.y * w.y) / fmax(w.z * w.z, (xfloat)1e-30f);
  return x / (2.0f * (1.0f + sqrt(1.0f + x)));
}
static inline xfloat xi_ggx_g1(xfloat3 w, xfloat alpha) { return 1.0f / (1.0f + xi_ggx_lambda(w, alpha)); }
// Height-correlated masking-shadowing.
static inline xfloat xi_ggx_g2(xfloat3 wo, xfloat3 wi, xfloat alpha) {
  return 1.0f / (1.0f + xi_ggx_lambda(wo, alpha) + xi_ggx_lambda(wi, alpha));
}

// A normal h of the visible normals seen from wo (Heitz 2018, "Sampling the GGX Distribution of
// Visible Normals", JCGT 7(4)): stretch wo to the hemisphere configuration, sample the projected
// area of the half disc, unstretch.
static inline xfloat3 xi_ggx_sample_visible(xfloat3 wo, xfloat alpha, xfloat2 u) {
  xfloat a = fmax(alpha, (xfloat)XI_DELTA_ALPHA);
  xfloat3 vh = xi_normalize3(make_xfloat3(a * wo.x, a * wo.y, wo.z));
  xfloat lensq = vh.x * vh.x + vh.y * vh.y;
  xmask tilted = lensq > 0.0f;
  xfloat inv = tilted ? 1.0f / sqrt(tilted ? lensq : (xfloat)1.0f) : (xfloat)0.0f;
  xfloat3 t1 = make_xfloat3(tilted ? -vh.y * inv : (xfloat)1.0f, tilted ? vh.x * inv : (xfloat)0.0f, (xfloat)0.0f);
  xfloat3 t2 = xi_cross3(vh, t1);
  xfloat r = sqrt(u.x), phi = 2.0f * XI_PI * u.y;
  xfloat p1 = r * cos(phi), p2 = r * sin(phi);
  xfloat s = 0.5f * (1.0f + vh.z);
  p2 = (1.0f - s) * xi_safe_sqrt(1.0f - p1 * p1) + s * p2;
  xfloat3 nh = xi_add3(xi_add3(xi_scale3(t1, p1), xi_scale3(t2, p2)), xi_scale3(vh, xi_safe_sqrt(1.0f - p1 * p1 - p2 * p2)));
  return xi_normalize3(make_xfloat3(a * nh.x, a * nh.y, fmax(nh.z, (xfloat)0.0f)));
}

// The density of xi_ggx_sample_visible's h (solid angle of h): G1(wo) max(0, wo·h) D(h) / wo.z.
static inline xfloat xi_ggx_visible_pdf(xfloat3 wo, xfloat3 h, xfloat alpha) {
  return xi_ggx_g1(wo, alpha) * fmax(xi_dot3(wo, h), (xfloat)0.0f) * xi_ggx_d(h, alpha) /
         fmax(wo.z, (xfloat)XI_MIN_COS);
}

// --- Anisotropic GGX: the base's lobes (the coat stays isotropic)
//
// Alphas αx = alpha·sx along x and αy = alpha·sy along y (sx = m.stretch_x, sy = m.stretch_y) give
//   D(h) = 1 / (π αx αy (hx²/αx² + hy²/αy² + hz²)²),   Λ(w) from αx² wx² + αy² wy² in place of α² (wx² + wy²),
// which are the isotropic functions of alpha at h scaled by (1/sx, 1/sy, 1) (D over sx sy) and at w
// scaled by (sx, sy, 1); the visible normals are sampled as isotropic ones from wo scaled the same
// way, then scaled back (Heitz 2018 stretches by αx, αy). With sx = sy = 1 every scale is exact, so
// isotropic lobes are computed bit for bit as by the isotropic functions.

// glTF's mapping: the alpha along the anisotropy direction (frame x) rises from alpha towards 1 with
// the strength squared; across it alpha stays (at least XI_DELTA_ALPHA: an anisotropic lobe is never
// a delta). The albedo tables then take the geometric mean of the two, as Cycles does: their
// compensation of the metal and the layer is approximate (xi_pbr_at leaves anisotropic glass
// uncompensated: there the tables overshoot at grazing angles).
static inline void xi_set_anisotropy(PbrLobes* m, xfloat strength) {
  xfloat ay = fmax(m->alpha, (xfloat)XI_DELTA_ALPHA), ax = ay + (1.0f - ay) * strength * strength;
  xmask on = strength > 0.0f;
  xfloat mean = sqrt(ax * ay);
  m->stretch_x = on ? ax / mean : (xfloat)1.0f;
  m->stretch_y = on ? ay / mean : (xfloat)1.0f;
  m->alpha = on ? mean : m->alpha;
}

static inline xfloat3 xi_stretch(xfloat3 w, xfloat sx, xfloat sy) { return make_xfloat3(w.x * sx, w.y * sy, w.z); }
static inline xfloat xi_base_d(PbrLobes m, xfloat3 h) {
  return xi_ggx_d(make_xfloat3(h.x / m.stretch_x, h.y / m.stretch_y, h.z), m.alpha) / (m.stretch_x * m.stretch_y);
}
static inline xfloat xi_base_g1(PbrLobes m, xfloat3 w) {
  return xi_ggx_g1(xi_stretch(w, m.stretch_x, m.stretch_y), m.alpha);
}
static inline xfloat xi_base_g2(PbrLobes m, xfloat3 wo, xfloat3 wi) {
  return xi_ggx_g2(xi_stretch(wo, m.stretch_x, m.stretch_y), xi_stretch(wi, m.stretch_x, m.stretch_y), m.alpha);
}
static inline xfloat3 xi_base_sample_visible(PbrLobes m, xfloat3 wo, xfloat2 u) {
  xfloat3 h = xi_ggx_sample_visible(xi_stretch(wo, m.stretch_x, m.stretch_y), m.alpha, u);
  xmask anisotropic = m.stretch_x != 1.0f || m.stretch_y != 1.0f;
  if (XI_ANY(anisotropic)) h = xi_select3(anisotropic, xi_normalize3(xi_stretch(h, m.stretch_x, m.stretch_y)), h);
  return h;
}
static inline xfloat xi_base_visible_pdf(PbrLobes m, xfloat3 wo, xfloat3 h) {
  return xi_base_g1(m, wo) * fmax(xi_dot3(wo, h), (xfloat)0.0f) * xi_base_d(m, h) / fmax(wo.z, (xfloat)XI_MIN_COS);
}

// --- Fresnel

// Schlick with a colour f0 (the metal).
static inline xfloat3 xi_schlick_color(xfloat3 f0, xfloat cos_o) {
  xfloat m = 1.0f - clamp(cos_o, (xfloat)0.0f, (xfloat)1.0f), m2 = m * m, w = m2 * m2 * m;
  return make_xfloat3(f0.x + (1.0f - f0.x) * w, f0.y + (1.0f - f0.y) * w, f0.z + (1.0f - f0.z) * w);
}

static inline xfloat xi_luminance(xfloat3 c) { return 0.2126f * c.x + 0.7152f * c.y + 0.0722f * c.z; }

// The albedo tables' roughness coordinate r = √alpha (alpha the lobes' GGX alpha, for an anisotropic
// lobe the geometric mean of its two).
static inline xfloat xi_table_roughness(PbrLobes m) { return sqrt(fmax(m.alpha, (xfloat)0.0f)); }

// --- multiple scattering

// The tables' roughness axis (ggx_albedo.h's layout, n entries): r = √α's row below it and the
// fraction towards the next, clamped.
static inline xuint xi_albedo_row(xfloat r, const uint n, xfloat* fy) {
  xfloat y = clamp(r * (float)(n - 1u), 0.0f, (float)(n - 1u)), y0 = fmin(floor(y), (xfloat)(n - 2u));
  *fy = y - y0;
  return convert_xuint(y0);
}
// An n × n (mu, r) table (ggx_albedo.h's E, a slice of E_F or E_glass, sheen_albedo.h's) starting at
// entry `first`, interpolated linearly in both, clamped.
static inline xfloat xi_albedo_lookup_from(__constant const float* table, const uint n, xuint first, xfloat mu, xfloat r) {
  xfloat x = clamp(mu * (float)n - 0.5f, 0.0f, (float)(n - 1u)), x0 = fmin(floor(x), (xfloat)(n - 2u)), fx = x - x0, fy;
  xuint i = first + xi_albedo_row(r, n, &fy) * n + convert_xuint(x0);
  xfloat a = xi_gather_table(table, i), b = xi_gather_table(table, i + 1u);
  xfloat c = xi_gather_table(table, i + n);
  xfloat d = xi_gather_table(table, i + n + 1u);
  xfloat lo = a + (b - a) * fx, hi = c + (d - c) * fx;
  return lo + (hi - lo) * fy;
}
static inline xfloat xi_albedo_lookup(__constant const float* table, xfloat mu, xfloat r) {
  return xi_albedo_lookup_from(table, XI_GGX_ALBEDO_SIZE, (xuint)0u, mu, r);
}
static inline xfloat xi_ggx_albedo(xfloat mu, xfloat r) { return xi_albedo_lookup(xi_ggx_albedo_table, mu, r); }
// The tables sliced by ior (ggx_albedo.h's XI_GGX_FRESNEL_SLICES slices in z = √((η − 1)/(η + 1)),
// η ≥ 1): the slice below eta's z and the fraction towards the next, clamped.
static inline xuint xi_ior_slice(xfloat eta, xfloat* fz) {
  const float last = (float)(XI_GGX_FRESNEL_SLICES - 1);
  xfloat z = clamp(sqrt(fmax((eta - 1.0f) / (eta + 1.0f), (xfloat)0.0f)) * (last / XI_GGX_FRESNEL_Z_MAX), 0.0f, last);
  xfloat z0 = fmin(floor(z), (xfloat)(last - 1.0f));
  *fz = z - z0;
  return convert_xuint(z0);
}
// n × n (mu, r) tables in slices by ior from entry `first`, for an ior eta ≥ 1: linear between the
// slices.
static inline xfloat xi_sliced_lookup(__constant const float* table, const uint n, xuint first, xfloat mu, xfloat r,
                                      xfloat eta) {
  xfloat fz;
  first += xi_ior_slice(eta, &fz) * (n * n);
  xfloat lo = xi_albedo_lookup_from(table, n, first, mu, r), hi = xi_albedo_lookup_from(table, n, first + n * n, mu, r);
  return lo + (hi - lo) * fz;
}
// E_F(mu, r) for a dielectric of relative ior eta ≥ 1.
static inline xfloat xi_ggx_fresnel_albedo(xfloat mu, xfloat r, xfloat eta) {
  return xi_sliced_lookup(xi_ggx_albedo_fresnel_table, XI_GGX_ALBEDO_SIZE, (xuint)0u, mu, r, eta);
}
// E_glass(mu, r): the rough dielectric boundary's reflection and transmission together, met from
// outside (eta ≥ 1) or inside (the table's second half, by 1 / eta).
static inline xfloat xi_glass_albedo(xfloat mu, xfloat r, xfloat eta) {
  const uint n = XI_GGX_GLASS_SIZE;
  xmask inside = eta < 1.0f;
  xuint first = inside ? (xuint)(XI_GGX_FRESNEL_SLICES * n * n) : (xuint)0u;
  return xi_sliced_lookup(xi_ggx_glass_albedo_table, n, first, mu, r, inside ? 1.0f / eta : eta);
}
// E_avg(r), interpolated likewise.
static inline xfloat xi_ggx_albedo_average(xfloat r) {
  xfloat fy;
  xuint j = xi_albedo_row(r, XI_GGX_ALBEDO_SIZE, &fy);
  xfloat a = xi_gather_table(xi_ggx_albedo_average_table, j), b = xi_gather_table(xi_ggx_albedo_average_table, j + 1u);
  return a + (b - a) * fy;
}
// F_ms: the Fresnel of light that scatters more than once, from f0's Schlick mean F_avg.
static inline xfloat3 xi_ggx_multiple_scattering_fresnel(xfloat3 f0, xfloat e_avg) {
  const float k = 1.0f / 21.0f;
  xfloat ax = f0.x + (1.0f - f0.x) * k, ay = f0.y + (1.0f - f0.y) * k, az = f0.z + (1.0f - f0.z) * k;
  return make_xfloat3(ax * ax * e_avg / (1.0f - ax * (1.0f - e_avg)), ay * ay * e_avg / (1.0f - ay * (1.0f - e_avg)),
                      az * az * e_avg / (1.0f - az * (1.0f - e_avg)));
}
// The metal's multiple-scattering lobe (no metallic weight) for wo.z = mu_o, wi.z = mu_i above the
// surface, and in *albedo its integral over wi, F_ms (1 − E(mu_o)): the lobe chooser's estimate.
// Both 0 for a smooth metal, and where multiple scattering is off.
static inline xfloat3 xi_ggx_multiple_scattering(PbrLobes m, xfloat mu_o, xfloat mu_i, xfloat3* albedo) {
  *albedo = make_xfloat3((xfloat)0.0f, (xfloat)0.0f, (xfloat)0.0f);
  // Off, nothing is looked up (a constant, where the shading word is the program's).
  if (!XI_ANY(m.multiple_scattering > 0.0f)) return *albedo;
  xfloat r = xi_table_roughness(m), e_avg = xi_ggx_albedo_average(r);
  xfloat3 f_ms = xi_ggx_multiple_scattering_fresnel(m.base_color, e_avg);
  xfloat lost = m.alpha >= XI_DELTA_ALPHA ? m.multiple_scattering * (1.0f - xi_ggx_albedo(mu_o, r)) : (xfloat)0.0f;
  *albedo = xi_scale3(f_ms, lost);
  return xi_scale3(f_ms, lost * (1.0f - xi_ggx_albedo(mu_i, r)) / (XI_PI * fmax(1.0f - e_avg, (xfloat)1e-6f)));
}

// The tint of one crossing by transmission (the convention above).
static inline xfloat3 xi_transmission_tint(PbrLobes m) {
  return make_xfloat3(sqrt(fmax(m.base_color.x, (xfloat)0.0f)), sqrt(fmax(m.base_color.y, (xfloat)0.0f)),
                      sqrt(fmax(m.base_color.z, (xfloat)0.0f)));
}

// --- the dielectric layer over the base

// KHR_materials_iridescence: a thin film over the base (thin_film.h) whose reflectance replaces the
// Fresnel in the share `iridescence` of the surface, as glTF mixes them. Over a dielectric the base's
// ior is that of the layer's f0' (below) per channel, the film's reflectance then times the layer's
// strength; over a metal it is the ior of the base colour as f0. The film is met from outside only:
// a surface seen from inside a denser medium keeps its Fresnel.
static inline bool xi_has_film(PbrLobes m) { return XI_COMPILED(XI_USE_IRIDESCENCE) && XI_ANY(m.iridescence > 0.0f); }
static inline xfloat xi_film_weight(PbrLobes m) { return m.eta >= 1.0f ? m.iridescence : (xfloat)0.0f; }
static inline xfloat3 xi_film_fresnel(PbrLobes m, xfloat cos_o, xfloat3 f0) {
  return xi_thin_film_fresnel(cos_o, m.iridescence_ior, m.iridescence_thickness, xi_ior_of_f0(f0));
}

// The metal's Fresnel: Schlick's with f0 = base_color, or the film's over it.
static inline xfloat3 xi_metal_fresnel(PbrLobes m, xfloat cos_o) {
  xfloat3 f = xi_schlick_color(m.base_color, cos_o);
  if (!xi_has_film(m)) return f;
  return xi_mix3(f, xi_film_fresnel(m, cos_o, m.base_color), xi_film_weight(m));
}

// The dielectric layer's f0' = min(f0 · specular_color, 1) per channel, f0 = ((η − 1)/(η + 1))².
static inline xfloat3 xi_layer_f0_color(PbrLobes m) {
  xfloat q = (m.eta - 1.0f) / (m.eta + 1.0f), f0 = q * q;
  return make_xfloat3(fmin(f0 * m.specular_color.x, (xfloat)1.0f), fmin(f0 * m.specular_color.y, (xfloat)1.0f),
                      fmin(f0 * m.specular_color.z, (xfloat)1.0f));
}

// The dielectric layer's Fresnel at a microfacet cosine cos_o, with KHR_materials_specular as
// Blender reads it: the exact Fresnel F of eta remapped to run from F0 = min(f0 · specular_color, 1)
// · specular at normal incidence to specular at grazing, specular · (f0' + (1 − f0') s) with
// f0' = min(f0 · specular_color, 1), f0 = ((η − 1)/(η + 1))² = F(1) and s = (F − f0) / (1 − f0)
// (1 under total internal reflection). Without the extension (both 1) it is F in every channel.
// With a film, the film's reflectance over f0' in its share (above).
// Both before the layer's strength: the remapped Fresnel, returned, and in *film the film's (with
// none, the same).
static inline xfloat3 xi_layer_fresnel_parts(PbrLobes m, xfloat cos_o, xfloat3* film) {
  xfloat q = (m.eta - 1.0f) / (m.eta + 1.0f), f0 = q * q;
  xfloat s = clamp((xi_fresnel_dielectric(cos_o, m.eta) - f0) / (1.0f - f0), (xfloat)0.0f, (xfloat)1.0f);
  xfloat3 f0s = xi_layer_f0_color(m);
  xfloat3 f = make_xfloat3(f0s.x + (1.0f - f0s.x) * s, f0s.y + (1.0f - f0s.y) * s, f0s.z + (1.0f - f0s.z) * s);
  *film = f;
  if (xi_has_film(m)) *film = xi_film_fresnel(m, cos_o, f0s);
  return f;
}
static inline xfloat3 xi_dielectric_fresnel(PbrLobes m, xfloat cos_o) {
  xfloat3 film, f = xi_layer_fresnel_parts(m, cos_o, &film);
  if (xi_has_film(m)) f = xi_mix3(f, film, xi_film_weight(m));
  return xi_scale3(f, m.specular);
}

// Where the layer's albedo is known: a smooth layer reflects its Fresnel at wo.z (total internal
// reflection included); a rough one met from outside (eta ≥ 1), xi_fresnel_layer_albedo of f0'.
// A rough layer met from inside a denser medium (a surface seen from behind) keeps the Fresnel mix.
static inline xmask xi_layer_albedo_known(PbrLobes m) { return m.alpha < XI_DELTA_ALPHA || m.eta >= 1.0f; }

// The directional albedo at wo.z = mu of a rough GGX layer (alpha = r²) whose Fresnel runs from f0
// to 1 as eta's (≥ 1) does from its own f0 to 1 (xi_dielectric_fresnel): f0 E + (1 − f0) E_F.
static inline xfloat xi_fresnel_layer_albedo(xfloat f0, xfloat mu, xfloat r, xfloat eta) {
  return f0 * xi_ggx_albedo(mu, r) + (1.0f - f0) * xi_ggx_fresnel_albedo(mu, r, eta);
}

// The layer's f0' = min(f0 · specular_color, 1) (xi_dielectric_fresnel) in its largest channel.
static inline xfloat xi_layer_f0(PbrLobes m) { return xi_max3(xi_layer_f0_color(m)); }

// E_spec(mu): the dielectric specular layer's directional albedo at wo.z = mu, where known (its
// largest channel, as Blender's Principled BSDF dims the base by).
static inline xfloat xi_dielectric_layer_albedo(PbrLobes m, xfloat mu) {
  // xi_dielectric_fresnel's parts, the film's evaluated once.
  xfloat3 film, plain = xi_layer_fresnel_parts(m, mu, &film), mixed = plain;
  if (xi_has_film(m)) mixed = xi_mix3(plain, film, xi_film_weight(m));
  xfloat smooth = xi_max3(xi_scale3(mixed, m.specular));
  if (!XI_ANY(m.alpha >= XI_DELTA_ALPHA)) return smooth;
  xfloat f0 = xi_layer_f0(m), r = xi_table_roughness(m);
  xfloat rough = m.specular * xi_fresnel_layer_albedo(f0, mu, r, m.eta);
  // No table holds a film's albedo: the layer's, scaled by the film's reflectance at mu over the
  // layer's own there.
  if (xi_has_film(m)) {
    xfloat layer = xi_max3(xi_scale3(plain, m.specular)), film_max = m.specular * xi_max3(film);
    rough += (rough * film_max / fmax(layer, (xfloat)1e-6f) - rough) * xi_film_weight(m);
  }
  return m.alpha >= XI_DELTA_ALPHA ? rough : smooth;
}

// The rough layer's multiple scattering (as the metal's, Kulla and Conty; Blender's Principled BSDF
// does the same): with albedo scaling and multiple scattering on, a rough layer met from outside is
// scaled by 1 + F_ms (1 − E(mu_o)) / E(mu_o), F_ms = F_avg E_avg / (1 − F_avg (1 − E_avg)) (Kulla and
// Conty's over the one F_avg the single-scattering lobe already holds), F_avg = specular (f0' +
// (1 − f0') s_avg) the layer's mean Fresnel, s_avg its remapped exact Fresnel's mean (ggx_albedo.h).
// 1 elsewhere.
static inline xfloat xi_layer_scattering_scale(PbrLobes m, xfloat mu_o) {
  xmask on = m.multiple_scattering > 0.0f && m.albedo_scaling > 0.0f && m.alpha >= XI_DELTA_ALPHA && m.eta >= 1.0f;
  if (!XI_ANY(on)) return 1.0f;
  xfloat fz;
  xuint k = xi_ior_slice(m.eta, &fz);
  xfloat lo = xi_gather_table(xi_ggx_fresnel_average_table, k), hi = xi_gather_table(xi_ggx_fresnel_average_table, k + 1u);
  xfloat s_avg = lo + (hi - lo) * fz;
  xfloat f0 = xi_layer_f0(m);
  xfloat f_avg = m.specular * (f0 + (1.0f - f0) * s_avg);
  xfloat r = xi_table_roughness(m), e = xi_ggx_albedo(mu_o, r), e_avg = xi_ggx_albedo_average(r);
  xfloat f_ms = f_avg * e_avg / (1.0f - f_avg * (1.0f - e_avg));
  return on ? 1.0f + f_ms * (1.0f - e) / fmax(e, (xfloat)1e-4f) : (xfloat)1.0f;
}

// What the layer passes down to the base towards wo (wo.z = mu_o): 1 − E_spec(mu_o) times its
// multiple-scattering scale with albedo scaling where the layer's albedo is known, 1 − F(mu_o) in
// the Fresnel mix.
static inline xfloat xi_base_share(PbrLobes m, xfloat mu_o, xfloat layer_scale) {
  xfloat mixed = 1.0f - xi_max3(xi_dielectric_fresnel(m, mu_o));
  xmask scaled = m.albedo_scaling > 0.0f && xi_layer_albedo_known(m);
  if (!XI_ANY(scaled)) return mixed;
  return scaled ? 1.0f - xi_dielectric_layer_albedo(m, mu_o) * layer_scale : mixed;
}

// The diffuse base's weight between wo and wi (no base colour, transmission or metallic weight),
// from its share towards wo: the Fresnel mix passes the light through the layer both ways.
static inline xfloat xi_base_weight(PbrLobes m, xfloat base_share, xfloat mu_i) {
  xmask scaled = m.albedo_scaling > 0.0f && xi_layer_albedo_known(m);
  return base_share * (scaled ? (xfloat)1.0f : 1.0f - xi_max3(xi_dielectric_fresnel(m, mu_i)));
}

// --- the clear coat (KHR_materials_clearcoat)
//
// A dielectric of ior 1.5 over everything else, weighted by coat, with its own roughness and its
// own normal n_c (glTF: the interpolated normal with the coat's normal map, not the base's); wo_c,
// wi_c are wo and wi in a frame about n_c:
//   f = coat · D_c(h) G2_c F_c(wo_c·h) / (4 |wo_c.z| |wi.z|) + share_c(wo_c.z) · f_below
// for wi above both normals (h = normalize(wo_c + wi_c); |wi.z| where a lobe of its own frame has
// |wi_c.z|, as the renderer multiplies f by the cosine with the base's normal);
// share_c = 1 − coat · E_c(wo_c.z) with albedo scaling (the coat's albedo from the tables, as
// above), 1 − coat · F_c(wo_c.z) in the Fresnel mix (the spec's own layering). A coat met from
// behind is the same coat: it stays on the outside.
#define XI_COAT_ETA 1.5f

// The coat's frame: w in a frame about n_c (its tangents from xi_basis), and back.
typedef struct {
  xfloat3 t, b, n;
} CoatFrame;
static inline CoatFrame xi_coat_frame(PbrLobes m) {
  CoatFrame f;
  f.n = m.coat_normal;
  xi_basis(f.n, &f.t, &f.b);
  return f;
}
static inline xfloat3 xi_to_coat(CoatFrame f, xfloat3 w) {
  return make_xfloat3(xi_dot3(w, f.t), xi_dot3(w, f.b), xi_dot3(w, f.n));
}
static inline xfloat3 xi_from_coat(CoatFrame f, xfloat3 w) {
  return xi_add3(xi_add3(xi_scale3(f.t, w.x), xi_scale3(f.b, w.y)), xi_scale3(f.n, w.z));
}

static inline xfloat xi_coat_albedo(PbrLobes m, xfloat mu) {
  xfloat smooth = xi_fresnel_dielectric(mu, (xfloat)XI_COAT_ETA);
  if (!XI_ANY(m.coat_alpha >= XI_DELTA_ALPHA && m.albedo_scaling > 0.0f)) return smooth;
  const float q = (XI_COAT_ETA - 1.0f) / (XI_COAT_ETA + 1.0f);
  xfloat rough = xi_fresnel_layer_albedo((xfloat)(q * q), mu, sqrt(fmax(m.coat_alpha, (xfloat)0.0f)), (xfloat)XI_COAT_ETA);
  return m.coat_alpha >= XI_DELTA_ALPHA && m.albedo_scaling > 0.0f ? rough : smooth;
}
static inline xfloat xi_coat_share(PbrLobes m, xfloat mu_o) {
  if (!XI_ANY(m.coat > 0.0f)) return 1.0f;
  return 1.0f - m.coat * xi_coat_albedo(m, mu_o);
}

// --- the sheen (KHR_materials_sheen)
//
// A layer of fibres over the base (below the coat): the "Charlie" distribution of Estevez and Kulla
// (2017), D(h) = (2 + 1/α) sin^(1/α)θh / 2π, with Ashikhmin's visibility 1 / (4 (μi + μo − μi μo)),
// as the glTF spec's sample implementation; divided by max(1, E_sh(wo.z)), its directional albedo
// (sheen_albedo.h), which Ashikhmin's visibility lets pass 1 at grazing angles for low roughness.
//   f = sheen_color · D V / max(1, E_sh(μo)) + (1 − max(sheen_color) min(1, E_sh(μo))) · f_below
// It is sampled with the cosine distribution, as the diffuse base.
#define XI_SHEEN_ALPHA_MIN 0.01f  // scripts/make-sheen-albedo.py's ALPHA_MIN

static inline xfloat xi_sheen_albedo(PbrLobes m, xfloat mu) {
  return xi_albedo_lookup(xi_sheen_albedo_table, mu, sqrt(fmax(m.sheen_alpha, (xfloat)XI_SHEEN_ALPHA_MIN)));
}
// f of the sheen (no colour) for wi above, h = normalize(wo + wi), given E_sh(wo.z).
static inline xfloat xi_sheen_f(PbrLobes m, xfloat sheen_albedo_o, xfloat3 h, xfloat mu_o, xfloat mu_i) {
  xfloat a = fmax(m.sheen_alpha, (xfloat)XI_SHEEN_ALPHA_MIN);
  xfloat sin2 = fmax(1.0f - h.z * h.z, (xfloat)0.0f);
  xfloat d = (2.0f + 1.0f / a) * pow(sin2, 0.5f / a) * (0.5f * XI_INV_PI);
  xfloat v = 1.0f / (4.0f * fmax(mu_i + mu_o - mu_i * mu_o, (xfloat)XI_MIN_COS));
  return d * v / fmax(sheen_albedo_o, (xfloat)1.0f);
}

// --- the material

// What the material does towards one wo, which eval and sample both need (each a few table
// lookups), computed once per hit by xi_pbr_at: what each layer passes to those below, and the
// probabilities of the lobes xi_pbr_sample chooses: the coat, reflection (specular layer and metal),
// diffuse (the cosine-distributed lobes: the diffuse base, the metal's multiple scattering and the
// sheen), transmission, from estimates of their albedos at wo. Each is positive wherever its lobe
// can be nonzero: the coat wherever it is, reflection always (the Fresnel tends to 1 at grazing
// microfacets), transmission wherever transmission and base colour are, even under total internal
// reflection at wo.z, where tilted microfacets still refract; diffuse vanishes exactly where both
// its terms do.
typedef struct {
  xfloat coat, reflect, diffuse, transmit;  // the lobes' probabilities
  xfloat layer_scale;   // xi_layer_scattering_scale(wo.z)
  xfloat base_share;    // xi_base_share(wo.z)
  xfloat sheen_albedo;  // E_sh(wo.z) (where there is a sheen)
  xfloat sheen_share;   // what the sheen passes below: 1 − max(sheen_color) min(1, E_sh(wo.z))
  xfloat coat_share;    // xi_coat_share(wo.z)
  xfloat glass_scale;   // 1 / E_glass(wo.z) where rough glass is compensated, else 1
} PbrAtWo;

static inline PbrAtWo xi_pbr_at(PbrLobes m, xfloat3 wo) {
  PbrAtWo at;
  at.layer_scale = xi_layer_scattering_scale(m, wo.z);
  at.base_share = xi_base_share(m, wo.z, at.layer_scale);
  at.sheen_albedo = 0.0f;
  at.sheen_share = 1.0f;
  if (XI_ANY(xi_max3(m.sheen_color) > 0.0f)) {
    at.sheen_albedo = xi_sheen_albedo(m, wo.z);
    at.sheen_share = 1.0f - xi_max3(m.sheen_color) * fmin(at.sheen_albedo, (xfloat)1.0f);
  }
  xfloat coat_mu = 1.0f;  // wo's cosine with the coat's normal
  if (XI_ANY(m.coat > 0.0f)) coat_mu = fmax(xi_dot3(wo, m.coat_normal), (xfloat)XI_MIN_COS);
  at.coat_share = xi_coat_share(m, coat_mu);
  at.glass_scale = 1.0f;
  xmask compensated = m.transmission > 0.0f && m.alpha >= XI_DELTA_ALPHA && m.albedo_scaling > 0.0f && m.stretch_x == 1.0f;
  if (XI_ANY(compensated)) {
    xfloat e = xi_glass_albedo(wo.z, xi_table_roughness(m), m.eta);
    at.glass_scale = compensated ? 1.0f / fmax(e, (xfloat)0.05f) : (xfloat)1.0f;
  }

  xfloat fo = xi_max3(xi_dielectric_fresnel(m, wo.z));
  xfloat lum = fmax(xi_luminance(m.base_color), (xfloat)0.0f);
  xfloat dielectric = 1.0f - m.metallic;
  xfloat wr = fmax(m.metallic * xi_luminance(xi_metal_fresnel(m, wo.z)) + dielectric * fo, (xfloat)0.02f);
  xfloat3 ms_albedo;
  xi_ggx_multiple_scattering(m, wo.z, wo.z, &ms_albedo);
  // The diffuse base and the metal's multiple scattering share the cosine distribution.
  xfloat wd = dielectric * (1.0f - m.transmission) * at.base_share * lum + m.metallic * xi_luminance(ms_albedo);
  xfloat wt = dielectric * m.transmission * fmax(1.0f - fo, (xfloat)0.1f) * lum;
  if (XI_ANY(xi_max3(m.sheen_color) > 0.0f)) {
    wr *= at.sheen_share, wd *= at.sheen_share, wt *= at.sheen_share;
    wd += 1.0f - at.sheen_share;  // the sheen's albedo, cosine-sampled with the base
  }
  xfloat wc = 0.0f;
  if (XI_ANY(m.coat > 0.0f)) {
    wr *= at.coat_share, wd *= at.coat_share, wt *= at.coat_share;
    wc = m.coat > 0.0f ? fmax(m.coat * xi_fresnel_dielectric(coat_mu, (xfloat)XI_COAT_ETA), (xfloat)0.02f) : (xfloat)0.0f;
  }
  xfloat inv = 1.0f / (wc + wr + wd + wt);
  at.coat = wc * inv;
  at.reflect = wr * inv;
  at.diffuse = wd * inv;
  at.transmit = wt * inv;
  return at;
}

// The Lambertian base's cosine under a normal map, as Cycles' Principled BSDF has it: with the
// map's normal n_d from before shade turned it to keep wo's mirror direction above the surface
// (sampled, as the other cosine lobes, about +z), light shadowed as by microfacets about the
// interpolated normal n_s (Chiang, Li and Burley, "Taming the Shadow Terminator", 2019: GGX's G1 at
// wi's angle to n_s with α² = tan² of n_d's angle to n_s over 8, at most 1), and none passing from
// the other side of n_s.
#if XI_DIFFUSE_NORMALS
static inline xfloat xi_diffuse_cosine(PbrLobes m, xfloat3 wi) {
  xfloat cd = xi_dot3(m.smooth_normal, m.diffuse_normal), cs = xi_dot3(m.smooth_normal, wi);
  xfloat cm = xi_dot3(m.diffuse_normal, wi);
  xfloat ci = fabs(cs), cd2 = fmax(cd * cd, (xfloat)1e-12f), ci2 = fmax(ci * ci, (xfloat)1e-12f);
  xfloat alpha2 = clamp(0.125f * (1.0f / cd2 - 1.0f), (xfloat)0.0f, (xfloat)1.0f);
  xfloat g = 2.0f / (1.0f + sqrt(1.0f + alpha2 * (1.0f / ci2 - 1.0f)));
  g = cd >= 1.0f || ci >= 1.0f ? (xfloat)1.0f : ci < 1e-6f ? (xfloat)0.0f : g;
  g = cs * cd * cm < 0.0f ? (xfloat)0.0f : g;
  return fmax(cm, (xfloat)0.0f) * g;
}
#endif

// f (no cosine) of the non-delta lobes and the solid-angle density with which xi_pbr_sample
// produces wi (non-delta lobes, the probabilities of `at` = xi_pbr_at(m, wo)).
static inline xfloat3 xi_pbr_eval_pdf_at(PbrLobes m, PbrAtWo p, xfloat3 wo, xfloat3 wi, xfloat* pdf) {
  xmask rough = m.alpha >= XI_DELTA_ALPHA;
  xfloat zo = fmax(wo.z, (xfloat)XI_MIN_COS), zi = fmax(fabs(wi.z), (xfloat)XI_MIN_COS);
  xmask above = wi.z > 0.0f, below = wi.z < 0.0f;
  xfloat g2 = xi_base_g2(m, wo, wi);
  xfloat dielectric = 1.0f - m.metallic;
  xfloat3 zero = make_xfloat3((xfloat)0.0f, (xfloat)0.0f, (xfloat)0.0f);

  // Reflection: h = normalize(wo + wi), wo·h = wi·h > 0 for wi above.
  xfloat3 hr = xi_add3(wo, wi);
  hr = xi_scale3(hr, 1.0f / sqrt(fmax(xi_dot3(hr, hr), (xfloat)1e-30f)));
  xfloat cr = fmax(xi_dot3(wo, hr), (xfloat)XI_MIN_COS);
  // The Fresnel terms' cosine, the same whichever of wo and wi comes first, so that f stays
  // reciprocal where the dielectric's Fresnel is steep (near the critical angle).
  xfloat cf = 0.5f * (xi_dot3(wo, hr) + xi_dot3(wi, hr));
  xfloat spec = xi_base_d(m, hr) * g2 / (4.0f * zo * zi);
  xfloat3 fmetal = xi_metal_fresnel(m, cf);
  xfloat3 fdiel = xi_dielectric_fresnel(m, cf);
  // The dielectric's reflection: its opaque share with the layer's multiple scattering, its
  // transmissive share compensated as the transmission is.
  xfloat reflection_scale = (1.0f - m.transmission) * p.layer_scale + m.transmission * p.glass_scale;
  xfloat3 f_spec = xi_scale3(xi_add3(xi_scale3(fmetal, m.metallic), xi_scale3(fdiel, dielectric * reflection_scale)), spec);
  xfloat pdf_r = xi_base_visible_pdf(m, wo, hr) / (4.0f * cr);
  xmask refl = above && rough;

  // Diffuse; with a normal of its own, its f · |wi.z| is its cosine with it times the bump shadowing.
  xfloat kd = dielectric * (1.0f - m.transmission) * xi_base_weight(m, p.base_share, wi.z) * XI_INV_PI;
#if XI_DIFFUSE_NORMALS
  xmask own_normal = m.diffuse_normal.z < 1.0f || m.smooth_normal.z < 1.0f;
  if (XI_ANY(own_normal)) kd = own_normal ? kd * xi_diffuse_cosine(m, wi) / zi : kd;
#endif
  xfloat3 ms_albedo;
  xfloat3 f_diff = xi_add3(xi_scale3(m.base_color, kd),
                           xi_scale3(xi_ggx_multiple_scattering(m, wo.z, wi.z, &ms_albedo), m.metallic));
  xfloat pdf_d = fmax(wi.z, (xfloat)0.0f) * XI_INV_PI;

  // Transmission: h = normalize(wo + η wi) turned to +z; wo and wi must lie on opposite sides of it.
  // (Where no path has transmission, p.transmit and f_trans are 0: nothing to compute.)
  xmask trans = XI_FALSE;
  xfloat3 f_trans = zero;
  xfloat pdf_t = 0.0f;
  if (XI_ANY(below && m.transmission > 0.0f)) {
    xfloat3 ht = xi_add3(wo, xi_scale3(wi, m.eta));
    xfloat len2 = xi_dot3(ht, ht);
    ht = xi_scale3(ht, (ht.z < 0.0f ? (xfloat)-1.0f : (xfloat)1.0f) / sqrt(fmax(len2, (xfloat)1e-30f)));
    xfloat cot = xi_dot3(wo, ht), cit = xi_dot3(wi, ht);
    trans = below && rough && cot > 0.0f && cit < 0.0f && len2 > 1e-12f;
    xfloat jac = m.eta * m.eta * fabs(cit) / fmax(len2, (xfloat)1e-12f);  // dω_h / dω_i, the denominator (wo·h + η wi·h)² = len2
    xfloat bt = fabs(cot) * xi_base_d(m, ht) * g2 * jac / (zo * zi);
    xfloat3 passed = xi_sub3(make_xfloat3((xfloat)1.0f, (xfloat)1.0f, (xfloat)1.0f), xi_dielectric_fresnel(m, cot));
    f_trans = xi_scale3(xi_mul3(xi_transmission_tint(m), passed), dielectric * m.transmission * bt * p.glass_scale);
    pdf_t = xi_base_visible_pdf(m, wo, ht) * jac;
  }

  *pdf = (refl ? p.reflect * pdf_r : (xfloat)0.0f) + (above ? p.diffuse * pdf_d : (xfloat)0.0f) +
         (trans ? p.transmit * pdf_t : (xfloat)0.0f);
  xfloat3 f = xi_add3(xi_add3(xi_select3(refl, f_spec, zero), xi_select3(above, f_diff, zero)), xi_select3(trans, f_trans, zero));

  // The sheen over the base, the coat over it all.
  if (XI_ANY(xi_max3(m.sheen_color) > 0.0f)) {
    xfloat fs = above ? xi_sheen_f(m, p.sheen_albedo, hr, zo, zi) : (xfloat)0.0f;
    f = xi_add3(xi_scale3(f, p.sheen_share), xi_scale3(m.sheen_color, fs));
  }
  if (XI_ANY(m.coat > 0.0f)) {
    CoatFrame coat_frame = xi_coat_frame(m);
    xfloat3 woc = xi_to_coat(coat_frame, wo), wic = xi_to_coat(coat_frame, wi);
    xfloat3 hc = xi_to_coat(coat_frame, hr);
    xfloat ac = fmax(m.coat_alpha, (xfloat)XI_DELTA_ALPHA);
    xfloat zoc = fmax(woc.z, (xfloat)XI_MIN_COS);
    xfloat coc = fmax(xi_dot3(woc, hc), (xfloat)XI_MIN_COS);
    // Above its own normal; over an opaque base that may be below the base's (whose lobes are 0 there).
    xmask coat_rough = (above || m.transmission <= 0.0f) && wic.z > 0.0f && m.coat > 0.0f && m.coat_alpha >= XI_DELTA_ALPHA;
    // Its cosine is wi's with its own normal: f · |wi.z| must be the coat's f · wi_c.z.
    xfloat f_coat = m.coat * xi_ggx_d(hc, ac) * xi_ggx_g2(woc, wic, ac) *
                    xi_fresnel_dielectric(0.5f * (xi_dot3(woc, hc) + xi_dot3(wic, hc)), (xfloat)XI_COAT_ETA) /
                    (4.0f * zoc * zi);
    f = xi_add3(xi_scale3(f, p.coat_share), make_xfloat3(coat_rough ? f_coat : (xfloat)0.0f,
                                                                   coat_rough ? f_coat : (xfloat)0.0f,
                                                                   coat_rough ? f_coat : (xfloat)0.0f));
    *pdf += coat_rough ? p.coat * xi_ggx_visible_pdf(woc, hc, ac) / (4.0f * coc) : (xfloat)0.0f;
  }
  return f;
}

static inline xfloat3 xi_pbr_eval_pdf(PbrLobes m, xfloat3 wo, xfloat3 wi, xfloat* pdf) {
  return xi_pbr_eval_pdf_at(m, xi_pbr_at(m, wo), wo, wi, pdf);
}
static inline xfloat3 xi_pbr_eval(PbrLobes m, xfloat3 wo, xfloat3 wi) {
  xfloat pdf;
  return xi_pbr_eval_pdf(m, wo, wi, &pdf);
}
static inline xfloat xi_pbr_pdf(PbrLobes m, xfloat3 wo, xfloat3 wi) {
  xfloat pdf;
  xi_pbr_eval_pdf(m, wo, wi, &pdf);
  return pdf;
}

// Samples wi: u_lobe picks a lobe, u the direction within it (visible normals for the coat,
// reflection and transmission, the cosine hemisphere for diffuse). Returns the weight
// f·|wi.z| / pdf with f the whole non-delta BSDF and pdf = xi_pbr_pdf (one-sample MIS over the
// lobes), and *pdf. A delta lobe returns its own weight (Fresnel and tint over its probability)
// with *pdf = 0 and *delta set. A sample that leaves its lobe's side of the surface (reflection
// below, transmission above) or meets total internal reflection returns weight 0 and *pdf = 0.
// *lobe: the XI_LOBE_* bits of the lobe chosen (material.h).
static inline xfloat3 xi_pbr_sample_lobe_at(PbrLobes m, PbrAtWo p, xfloat3 wo, xfloat u_lobe, xfloat2 u, xfloat3* wi,
                                            xfloat* pdf, xmask* delta, xuint* lobe) {
  xfloat pr = p.reflect, pd = p.diffuse, pt = p.transmit, pc = p.coat;
  xmask pick_c = u_lobe < pc;
  xmask pick_r = !pick_c && (u_lobe < pc + pr || (pd <= 0.0f && pt <= 0.0f));
  xmask pick_t = !pick_c && !pick_r && pt > 0.0f && (u_lobe >= pc + pr + pd || pd <= 0.0f);
  xmask pick_d = !pick_c && !pick_r && !pick_t;
  xmask smooth = m.alpha < XI_DELTA_ALPHA;
  xfloat3 n = make_xfloat3((xfloat)0.0f, (xfloat)0.0f, (xfloat)1.0f);

  // Rough lobes (the coat's microfacet normal, in its own frame, only where some path has a coat).
  xfloat3 h = xi_base_sample_visible(m, wo, u);
  xmask coat_smooth = m.coat_alpha < XI_DELTA_ALPHA;
  xfloat coat_mu = 1.0f;
  xfloat3 nc = n;
  if (XI_ANY(pick_c)) {
    CoatFrame coat_frame = xi_coat_frame(m);
    xfloat3 woc = xi_to_coat(coat_frame, wo);
    coat_mu = fmax(woc.z, (xfloat)XI_MIN_COS);
    nc = m.coat_normal;
    h = xi_select3(pick_c, xi_from_coat(coat_frame, xi_ggx_sample_visible(woc, m.coat_alpha, u)), h);
  }
  // The smooth lobes reflect and refract about n, the smooth coat about its own normal.
  xfloat3 hs = xi_select3(pick_c ? coat_smooth : smooth, xi_select3(pick_c, nc, n), h);
  xfloat3 wr = xi_reflect(wo, hs);
  // Refraction only where some path has transmission (pt, and with it pick_t and weight_t, are 0
  // elsewhere).
  xfloat3 wt = n;
  xmask refracts = XI_FALSE;
  if (XI_ANY(m.transmission > 0.0f)) {
    refracts = xi_refract(wo, hs, m.eta, &wt) && xi_dot3(wo, hs) > 0.0f;
    wt = xi_normalize3(wt);
  }
  xfloat3 wd = xi_square_to_cosine_hemisphere(u);
  xfloat3 w = xi_select3(pick_r || pick_c, wr, xi_select3(pick_t, wt, wd));
  // (A coat's reflection over an opaque base may leave below the base's normal: see the eval.)
  xmask valid = pick_t ? (refracts && w.z < 0.0f)
                       : w.z > 0.0f || (pick_c && m.transmission <= 0.0f && xi_dot3(w, nc) > 0.0f);
  xfloat pw;
  xfloat3 f = xi_pbr_eval_pdf_at(m, p, wo, w, &pw);
  valid = valid && pw > 0.0f;
  xfloat3 zero = make_xfloat3((xfloat)0.0f, (xfloat)0.0f, (xfloat)0.0f);
  xfloat3 weight = xi_select3(valid, xi_scale3(f, fabs(w.z) / (valid ? pw : (xfloat)1.0f)), zero);

  // Delta lobes: the coat's mirror, the base's mirror and smooth refraction with the Fresnel terms
  // at wo.z (the base's dimmed by the coat's share).
  xmask is_delta = pick_c ? coat_smooth : smooth && !pick_d;
  xfloat3 fo = xi_dielectric_fresnel(m, wo.z);
  xfloat dielectric = 1.0f - m.metallic;
  xfloat share = p.coat_share * p.sheen_share;
  xfloat3 mirror = xi_add3(xi_scale3(xi_metal_fresnel(m, wo.z), m.metallic), xi_scale3(fo, dielectric));
  xfloat3 weight_r = xi_scale3(mirror, share / fmax(pr, (xfloat)1e-30f));
  xfloat3 passed = xi_sub3(make_xfloat3((xfloat)1.0f, (xfloat)1.0f, (xfloat)1.0f), fo);
  xfloat3 weight_t = xi_scale3(xi_mul3(xi_transmission_tint(m), passed),
                               (refracts ? share * dielectric * m.transmission : (xfloat)0.0f) / fmax(pt, (xfloat)1e-30f));
  xfloat3 weight_delta = xi_select3(pick_r, weight_r, weight_t);
  if (XI_ANY(m.coat > 0.0f)) {
    xfloat c = m.coat * xi_fresnel_dielectric(coat_mu, (xfloat)XI_COAT_ETA) / fmax(pc, (xfloat)1e-30f);
    weight_delta = xi_select3(pick_c, make_xfloat3(c, c, c), weight_delta);
  }

  *wi = w;
  *pdf = is_delta || !valid ? (xfloat)0.0f : pw;
  *delta = is_delta;
  xuint side = pick_t ? (xuint)XI_LOBE_TRANSMISSION : (xuint)XI_LOBE_REFLECTION;
  *lobe = side | (is_delta ? (xuint)XI_LOBE_SPECULAR : pick_d ? (xuint)XI_LOBE_DIFFUSE : (xuint)XI_LOBE_GLOSSY);
  return xi_select3(is_delta, weight_delta, weight);
}

static inline xfloat3 xi_pbr_sample_lobe(PbrLobes m, xfloat3 wo, xfloat u_lobe, xfloat2 u, xfloat3* wi, xfloat* pdf,
                                         xmask* delta, xuint* lobe) {
  return xi_pbr_sample_lobe_at(m, xi_pbr_at(m, wo), wo, u_lobe, u, wi, pdf, delta, lobe);
}
static inline xfloat3 xi_pbr_sample(PbrLobes m, xfloat3 wo, xfloat u_lobe, xfloat2 u, xfloat3* wi, xfloat* pdf,
                                    xmask* delta) {
  xuint lobe;
  return xi_pbr_sample_lobe(m, wo, u_lobe, u, wi, pdf, delta, &lobe);
}

#endif
