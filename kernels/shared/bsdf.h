// Scattering: Lambertian (albedo/π), perfect mirror, smooth dielectric. Directions are unit
// vectors pointing away from the surface; `n` is the normal on the side of wo.
#ifndef XI_BSDF_H
#define XI_BSDF_H
#include "compat.h"
#include "warps.h"

// Lambertian: sampled by the cosine-weighted hemisphere, so f·cos/pdf = albedo.
static inline float3 xi_lambert_sample(float3 n, float2 u, float* pdf) {
  float3 d = xi_square_to_cosine_hemisphere(u);
  *pdf = xi_cosine_hemisphere_pdf(d);
  return xi_to_world(d, n);
}
static inline float xi_lambert_pdf(float3 n, float3 wi) { return fmax(dot(n, wi), 0.0f) * XI_INV_PI; }

static inline float3 xi_reflect(float3 wo, float3 n) { return n * (2.0f * dot(wo, n)) - wo; }

// Fresnel reflectance of a smooth dielectric boundary for unpolarised light. cos_i is measured on
// the side light arrives from; eta = n_transmitted / n_incident. Returns 1 under total internal
// reflection.
static inline float xi_fresnel_dielectric(float cos_i, float eta) {
  cos_i = clamp(cos_i, 0.0f, 1.0f);
  float sin2_t = (1.0f - cos_i * cos_i) / (eta * eta);
  if (sin2_t >= 1.0f) return 1.0f;
  float cos_t = xi_safe_sqrt(1.0f - sin2_t);
  float r_par = (eta * cos_i - cos_t) / (eta * cos_i + cos_t);
  float r_perp = (cos_i - eta * cos_t) / (cos_i + eta * cos_t);
  return 0.5f * (r_par * r_par + r_perp * r_perp);
}

// Refraction of wo through a boundary with normal n (on wo's side) and relative index eta.
// Returns false under total internal reflection.
static inline bool xi_refract(float3 wo, float3 n, float eta, float3* wt) {
  float cos_i = dot(n, wo);
  float sin2_t = fmax(0.0f, 1.0f - cos_i * cos_i) / (eta * eta);
  if (sin2_t >= 1.0f) return false;
  float cos_t = xi_safe_sqrt(1.0f - sin2_t);
  *wt = -wo / eta + n * (cos_i / eta - cos_t);
  return true;
}

// Smooth dielectric: chooses reflection with probability F, else refraction, so the weight is
// the tint alone (energy conserving). `entering`: wo is on the outside (geometric normal side).
// Returns the new direction; *reflected tells which lobe was taken.
static inline float3 xi_dielectric_sample(float3 wo, float3 n, float ior, bool entering, float u,
                                          bool* reflected) {
  float eta = entering ? ior : 1.0f / ior;
  float f = xi_fresnel_dielectric(dot(n, wo), eta);
  float3 wt;
  if (u < f || !xi_refract(wo, n, eta, &wt)) {
    *reflected = true;
    return xi_reflect(wo, n);
  }
  *reflected = false;
  return normalize(wt);
}

// Power heuristic (β = 2) for multiple importance sampling of two strategies.
static inline float xi_power_heuristic(float pdf_a, float pdf_b) {
  float a = pdf_a * pdf_a, b = pdf_b * pdf_b;
  return a + b > 0.0f ? a / (a + b) : 0.0f;
}

#endif
