// The BSDF interface: every material behind one contract, as pbrt-v4's BxDF and Mitsuba 3's BSDF.
// shade builds a Bsdf at each hit (the material's parameters after textures, the shading frame),
// then asks only two things of it:
//
//   xi_bsdf_eval(b, shading, wo, wi)      f(wo, wi) and the solid-angle density with which
//                                         xi_bsdf_sample would produce wi; both 0 for delta lobes,
//                                         which no given direction reaches
//   xi_bsdf_sample(b, shading, wo, u_lobe, u)
//                                         wi, its weight f·|cos θi| / pdf (a delta lobe: its own
//                                         weight), pdf (0 for a delta lobe), the lobe it came from,
//                                         and whether the path may follow it
//
// Directions are unit world-space vectors pointing away from the surface; wo is the hit's, for which
// the Bsdf was built (b.pbr_at). A material whose shading word bit is off is never evaluated: its
// lanes get f = 0 and samples that end the path.
// Written on lane types (lanes.h), so the host's tests call the same code.
#ifndef XI_MATERIAL_H
#define XI_MATERIAL_H
#include "bsdf.h"
#include "lanes.h"
#include "layout.h"
#include "microfacet.h"
#include "shading.h"
#include "warps.h"

// A surface's BSDF at one hit, lane k holding path k's.
typedef struct {
  xmask at_surface;  // lanes with a surface to scatter from; the others scatter nothing
  xuint type;        // XI_MATERIAL_*
  xfloat3 tint;      // Lambertian albedo, mirror and glass tint, the metallic-roughness base colour
  xfloat ior;        // glass
  xmask entering;    // wo on the geometric normal's front side (glass)
  xfloat3 n;         // shading normal, on wo's side
  xfloat3 n_geo;     // geometric normal, on wo's side: no lobe may cross it
  xfloat3 frame_t, frame_b;  // the metallic-roughness lobes' frame: (frame_t, frame_b, n)
  PbrLobes pbr;
  PbrAtWo pbr_at;  // what the metallic-roughness lobes do towards this hit's wo: xi_bsdf_at_wo
} Bsdf;

// f = colour · scale. Kept apart so that a path's throughput is multiplied by the colour first and
// by the scale (a Lambertian surface's 1/π; 1 for the others) after, the same for every material.
typedef struct {
  xfloat3 colour;
  xfloat scale;
  xfloat pdf;
} BsdfValue;

typedef struct {
  xfloat3 wi;
  xfloat3 weight;  // f·|cos θi| / pdf, or a delta lobe's own weight
  xfloat pdf;      // 0 for a delta lobe
  xuint lobe;      // XI_LOBE_* bits
  xmask valid;     // wi leaves on its lobe's side of both normals: the path may follow it
} BsdfSample;

static inline xfloat3 xi_bsdf_to_local(Bsdf b, xfloat3 w) {
  return make_xfloat3(xi_dot3(w, b.frame_t), xi_dot3(w, b.frame_b), xi_dot3(w, b.n));
}

// What b's metallic-roughness lobes do towards wo, the direction every eval and sample at this hit
// shares: computed once, where the Bsdf is built.
static inline PbrAtWo xi_bsdf_at_wo(Bsdf b, xfloat3 wo) { return xi_pbr_at(b.pbr, xi_bsdf_to_local(b, wo)); }

// Whether light may pass along a direction at cosine `side` with the geometric normal and z with
// the shading normal: the two must agree on the side, or light would leak through; an opaque
// metallic-roughness surface reflects above the geometric normal alone (its coat's reflection may
// be below the base's normal, its other lobes are 0 there).
static inline xmask xi_bsdf_side_agrees(Bsdf b, xfloat side, xfloat z) {
  xmask opaque = b.type == XI_MATERIAL_PBR && b.pbr.transmission <= 0.0f;
  return opaque ? side > 0.0f : side * z > 0.0f;
}

// Whether a light sample can reach a lobe of b: b has a lobe that is not a delta.
static inline XI_INLINE xmask xi_bsdf_has_non_delta(Bsdf b, uint shading) {
  xmask some = b.at_surface && b.type == XI_MATERIAL_DIFFUSE && xi_max3(b.tint) > 0.0f;
  if (xi_uses(shading, XI_USE_PBR))
    // A metal whose lobes are all delta (its coat's too) has nothing for a light sample to reach.
    some = some || (b.at_surface && b.type == XI_MATERIAL_PBR &&
                    (!(b.pbr.alpha < XI_DELTA_ALPHA && b.pbr.metallic >= 1.0f) ||
                     (b.pbr.coat > 0.0f && b.pbr.coat_alpha >= XI_DELTA_ALPHA) || xi_max3(b.pbr.sheen_color) > 0.0f));
  return some;
}

static inline XI_INLINE BsdfValue xi_bsdf_eval(Bsdf b, uint shading, xfloat3 wo, xfloat3 wi) {
  BsdfValue v;
  xfloat3 zero = make_xfloat3((xfloat)0.0f, (xfloat)0.0f, (xfloat)0.0f);
  xfloat cos_i = xi_dot3(b.n, wi);
  xmask diffuse = b.at_surface && b.type == XI_MATERIAL_DIFFUSE;
  v.colour = xi_select3(diffuse && cos_i > 0.0f, b.tint, zero);
  v.scale = diffuse ? (xfloat)XI_INV_PI : (xfloat)1.0f;
  v.pdf = diffuse ? xi_lambert_pdf(b.n, wi) : (xfloat)0.0f;
  if (xi_uses(shading, XI_USE_PBR)) {
    xmask pbr = b.at_surface && b.type == XI_MATERIAL_PBR;
    if (XI_ANY(pbr)) {
      // Reflection above n, transmission below it.
      xfloat3 wi_local = make_xfloat3(xi_dot3(wi, b.frame_t), xi_dot3(wi, b.frame_b), cos_i);
      xfloat pdf;
      xfloat3 f = xi_pbr_eval_pdf_at(b.pbr, b.pbr_at, xi_bsdf_to_local(b, wo), wi_local, &pdf);
      v.colour = xi_select3(pbr, f, v.colour);
      v.pdf = pbr ? pdf : v.pdf;
    }
  }
  return v;
}

// u_lobe chooses among lobes (glass: reflection or refraction), u places the direction in one.
static inline XI_INLINE BsdfSample xi_bsdf_sample(Bsdf b, uint shading, xfloat3 wo, xfloat u_lobe, xfloat2 u) {
  BsdfSample s;
  s.wi = b.n;
  s.weight = b.tint;
  s.pdf = 0.0f;
  s.lobe = 0u;
  s.valid = XI_FALSE;
  xmask diffuse = b.at_surface && b.type == XI_MATERIAL_DIFFUSE && xi_max3(b.tint) > 0.0f;
  if (XI_ANY(diffuse)) {
    // Cosine-weighted, so f·cos/pdf is the albedo.
    xfloat pdf;
    xfloat3 wi = xi_lambert_sample(b.n, u, &pdf);
    s.wi = xi_select3(diffuse, wi, s.wi);
    s.pdf = diffuse ? pdf : s.pdf;
    s.lobe = diffuse ? (xuint)(XI_LOBE_REFLECTION | XI_LOBE_DIFFUSE) : s.lobe;
    // A shading normal may send the sample below the surface.
    s.valid = s.valid || (diffuse && xi_dot3(wi, b.n_geo) > 0.0f && pdf > 0.0f);
  }
  xmask mirror = b.at_surface && b.type == XI_MATERIAL_MIRROR;
  if (xi_uses(shading, XI_USE_MIRROR) && XI_ANY(mirror)) {
    xfloat3 wi = xi_reflect(wo, b.n);
    s.wi = xi_select3(mirror, wi, s.wi);
    s.lobe = mirror ? (xuint)(XI_LOBE_REFLECTION | XI_LOBE_SPECULAR) : s.lobe;
    s.valid = s.valid || (mirror && xi_dot3(wi, b.n_geo) > 0.0f);
  }
  xmask glass = b.at_surface && b.type == XI_MATERIAL_DIELECTRIC;
  if (xi_uses(shading, XI_USE_DIELECTRIC) && XI_ANY(glass)) {
    xmask reflected;
    xfloat3 wi = xi_dielectric_sample(wo, b.n, b.ior, b.entering, u_lobe, &reflected);
    s.wi = xi_select3(glass, wi, s.wi);
    s.lobe = glass ? (reflected ? (xuint)(XI_LOBE_REFLECTION | XI_LOBE_SPECULAR)
                                : (xuint)(XI_LOBE_TRANSMISSION | XI_LOBE_SPECULAR))
                   : s.lobe;
    // A shading normal may send a reflection below the surface or a refraction above it.
    xfloat side = xi_dot3(wi, b.n_geo);
    s.valid = s.valid || (glass && (reflected ? side > 0.0f : side < 0.0f));
  }
  xmask pbr = b.at_surface && b.type == XI_MATERIAL_PBR;
  if (xi_uses(shading, XI_USE_PBR) && XI_ANY(pbr)) {
    xfloat3 wi_local;
    xfloat pdf;
    xmask delta;
    xuint lobe;
    xfloat3 weight =
        xi_pbr_sample_lobe_at(b.pbr, b.pbr_at, xi_bsdf_to_local(b, wo), u_lobe, u, &wi_local, &pdf, &delta, &lobe);
    xfloat3 wi = xi_add3(xi_add3(xi_scale3(b.frame_t, wi_local.x), xi_scale3(b.frame_b, wi_local.y)),
                         xi_scale3(b.n, wi_local.z));
    s.wi = xi_select3(pbr, wi, s.wi);
    s.weight = xi_select3(pbr, weight, s.weight);
    s.pdf = pbr ? pdf : s.pdf;
    s.lobe = pbr ? lobe : s.lobe;
    s.valid = s.valid || (pbr && xi_max3(weight) > 0.0f && xi_bsdf_side_agrees(b, xi_dot3(wi, b.n_geo), wi_local.z));
  }
  return s;
}

#endif
