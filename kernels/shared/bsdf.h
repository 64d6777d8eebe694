// The lobes of the simple materials: Lambertian (albedo/π), perfect mirror, smooth dielectric
// (material.h puts them behind the BSDF interface). Directions are unit
// vectors pointing away from the surface; `n` is the normal on the side of wo. Written on lane
// types (lanes.h).
#ifndef XI_BSDF_H
#define XI_BSDF_H
#include "lanes.h"
#include "layout.h"
#include "warps.h"

// The kind of lobe a sample came from (pbrt-v4's BxDFFlags, Mitsuba 3's BSDFFlags, in short).
#define XI_LOBE_REFLECTION 1u
#define XI_LOBE_TRANSMISSION 2u
#define XI_LOBE_DIFFUSE 4u
#define XI_LOBE_GLOSSY 8u
#define XI_LOBE_SPECULAR 16u

// A material's parameters, lane k holding those of path k's material.
typedef struct {
  xfloat3 albedo;
  xfloat ior;
  xfloat3 emission;
  xfloat two_sided;  // > 0 when both faces emit
  xuint type;        // XI_MATERIAL_*
} ShadingMaterial;

#ifdef XI_DEVICE
static inline XI_INLINE ShadingMaterial xi_gather_material(__global const MaterialData* materials, xuint i) {
  ShadingMaterial m;
  m.albedo = XI_GATHER_XYZ_FIELD(materials, i, albedo, &m.ior);
  m.emission = XI_GATHER_XYZ_FIELD(materials, i, emission, &m.two_sided);
  m.type = XI_GATHER_UINT_FIELD(materials, i, type);
  return m;
}
#endif

// Lambertian: sampled by the cosine-weighted hemisphere, so f·cos/pdf = albedo.
static inline xfloat3 xi_lambert_sample(xfloat3 n, xfloat2 u, xfloat* pdf) {
  xfloat3 d = xi_square_to_cosine_hemisphere(u);
  *pdf = xi_cosine_hemisphere_pdf(d);
  return xi_to_world(d, n);
}
static inline xfloat xi_lambert_pdf(xfloat3 n, xfloat3 wi) { return fmax(xi_dot3(n, wi), (xfloat)0.0f) * XI_INV_PI; }

static inline xfloat3 xi_reflect(xfloat3 wo, xfloat3 n) { return xi_sub3(xi_scale3(n, 2.0f * xi_dot3(wo, n)), wo); }

// Fresnel reflectance of a smooth dielectric boundary for unpolarised light. cos_i is measured on
// the side light arrives from; eta = n_transmitted / n_incident. Returns 1 under total internal
// reflection.
static inline xfloat xi_fresnel_dielectric(xfloat cos_i, xfloat eta) {
  cos_i = clamp(cos_i, 0.0f, 1.0f);
  xfloat sin2_t = (1.0f - cos_i * cos_i) / (eta * eta);
  xfloat cos_t = xi_safe_sqrt(1.0f - sin2_t);
  xfloat r_par = (eta * cos_i - cos_t) / (eta * cos_i + cos_t);
  xfloat r_perp = (cos_i - eta * cos_t) / (cos_i + eta * cos_t);
  return sin2_t >= 1.0f ? (xfloat)1.0f : 0.5f * (r_par * r_par + r_perp * r_perp);
}

// Refraction of wo through a boundary with normal n (on wo's side) and relative index eta.
// Returns false under total internal reflection.
static inline xmask xi_refract(xfloat3 wo, xfloat3 n, xfloat eta, xfloat3* wt) {
  xfloat cos_i = xi_dot3(n, wo);
  xfloat sin2_t = fmax((xfloat)0.0f, 1.0f - cos_i * cos_i) / (eta * eta);
  xfloat cos_t = xi_safe_sqrt(1.0f - sin2_t);
  *wt = xi_add3(make_xfloat3(-wo.x / eta, -wo.y / eta, -wo.z / eta), xi_scale3(n, cos_i / eta - cos_t));
  return sin2_t < 1.0f;
}

// Smooth dielectric: chooses reflection with probability F, else refraction, so the weight is
// the tint alone (energy conserving). `entering`: wo is on the outside (geometric normal side).
// Returns the new direction; *reflected tells which lobe was taken.
static inline xfloat3 xi_dielectric_sample(xfloat3 wo, xfloat3 n, xfloat ior, xmask entering, xfloat u,
                                           xmask* reflected) {
  xfloat eta = entering ? ior : 1.0f / ior;
  xfloat f = xi_fresnel_dielectric(xi_dot3(n, wo), eta);
  xfloat3 wt;
  xmask refracts = xi_refract(wo, n, eta, &wt);
  *reflected = u < f || !refracts;
  return xi_select3(*reflected, xi_reflect(wo, n), xi_normalize3(wt));
}

// Power heuristic (β = 2) for multiple importance sampling of two strategies. The pdfs are scaled
// by the larger (each first clamped to the largest float) before they are squared: a tiny light's
// solid-angle pdf beyond about 1e19 squared to infinity, and inf / inf dropped its every sample
// as NaN.
static inline xfloat xi_power_heuristic(xfloat pdf_a, xfloat pdf_b) {
  xfloat pa = fmin(pdf_a, FLT_MAX), pb = fmin(pdf_b, FLT_MAX), larger = fmax(pa, pb);
  xfloat a = pa / larger, b = pb / larger;
  return larger > 0.0f ? a * a / (a * a + b * b) : (xfloat)0.0f;
}

#endif
