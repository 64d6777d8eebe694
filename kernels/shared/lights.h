// Light sampling. The lights (emissive triangles, punctual lights, the environment) are picked in
// proportion to their power, then a point on the chosen one, both from one 2D sample: uniform on a
// triangle's area (the pdf converted from area to solid angle at the shading point), the light's
// position (point, spot), a direction within a sun's cone, or the environment's own distribution.
// Written on lane types (lanes.h).
#ifndef XI_LIGHTS_H
#define XI_LIGHTS_H
#include "bsdf.h"
#include "environment.h"
#include "lanes.h"
#include "shading.h"
#include "layout.h"
#include "mesh.h"
#include "spawn.h"
#include "warps.h"

typedef struct {
  xfloat3 wi;        // unit direction from the origin to the light point
  xfloat dist;       // distance to it, the point moved off the light by its rounding error
  xfloat pdf;        // solid-angle density of wi; 0 when the point's emitting side faces away
  xfloat3 radiance;  // emitted toward the origin
  xmask delta;       // no BSDF sample can reach it (punctual lights): weight 1, not combined by MIS
} LightSample;

// Binary search of the normalised CDF over the n emissive triangles with *u, which is then
// stretched back to [0, 1) within the chosen triangle's interval, so one uniform both picks the
// light and places the point on it (and keeps its stratification). With lanes, every path steps
// until the last one has found its light.
static inline xuint xi_pick_light(__global const float* cdf, uint n, xfloat* u) {
  xuint lo = 0u, hi = n - 1u;
  while (XI_ANY(lo < hi)) {
    xmask searching = lo < hi;
    xuint mid = (lo + hi) >> 1;
    xmask left = *u < xi_gather_float(cdf, mid);
    hi = searching && left ? mid : hi;
    lo = searching && !left ? mid + 1u : lo;
  }
  xfloat below = lo > 0u ? xi_gather_float(cdf, max(lo, (xuint)1u) - 1u) : (xfloat)0.0f;
  *u = clamp((*u - below) / (xi_gather_float(cdf, lo) - below), 0.0f, XI_ONE_MINUS_EPSILON);
  return lo;
}

// Solid-angle pdf of reaching emissive triangle `tri` at distance dist with cosine cos_l at the
// light; tri_light_pdf holds P(pick tri) / area(tri).
static inline xfloat xi_light_pdf(__global const float* tri_light_pdf, xuint tri, xfloat dist, xfloat cos_l) {
  return cos_l > 0.0f ? xi_gather_float(tri_light_pdf, tri) * dist * dist / cos_l : (xfloat)0.0f;
}

// A point uniform on emissive triangle lt (in BVH order), seen from org.
static inline LightSample xi_sample_triangle_light(__global const float* tri_light_pdf,
                                                   __global const uint4* tri_vertices, __global const float4* vertices,
                                                   __global const uint* tri_material,
                                                   __global const MaterialData* materials, xuint lt, xfloat3 org,
                                                   xfloat2 u) {
  LightSample ls;
  const TriangleCorners c = xi_triangle_corners(tri_vertices, vertices, lt);
  xfloat3 q0 = c.p0, q1 = c.p1, q2 = c.p2;
  xfloat2 b = xi_square_to_triangle(u);
  xfloat3 q_error;
  xfloat3 q = xi_interpolate(q2, q0, q1, b.x, b.y, &q_error);  // b.x q0 + b.y q1 + (1 - b.x - b.y) q2
  xfloat3 nl = xi_normalize3(xi_cross3(xi_sub3(q1, q0), xi_sub3(q2, q0)));
  // The shadow ray ends off the light's surface, on the origin's side: it cannot hit the light.
  xfloat3 to_light = xi_sub3(xi_offset_ray_origin(q, q_error, nl, xi_sub3(org, q)), org);
  ls.dist = xi_length3(to_light);
  ls.wi = xi_div3(to_light, ls.dist);
  ShadingMaterial m = xi_gather_material(materials, xi_gather_uint(tri_material, lt));
  xfloat cos_l = -xi_dot3(nl, ls.wi);
  cos_l = m.two_sided > 0.0f ? fabs(cos_l) : cos_l;
  ls.pdf = xi_light_pdf(tri_light_pdf, lt, ls.dist, cos_l);
  ls.radiance = m.emission;
  ls.delta = XI_FALSE;
  return ls;
}

// Lane k's sample of punctual light `index`: its intensity over the squared distance (point, spot,
// with the spot's smooth cone falloff as glTF's KHR_lights_punctual gives it), or a directional
// light's irradiance, spread over a sun's cone of directions (uniform in solid angle, radiance
// E / (π sin² of its angular radius)).
static inline LightSample xi_sample_punctual(__global const PunctualLightData* lights, xuint index, xfloat3 org,
                                             xfloat2 u) {
  xfloat pick, cos_sun, type;
  xfloat3 pos = XI_GATHER_XYZ_FIELD(lights, index, position, &pick);
  xfloat3 dir = XI_GATHER_XYZ_FIELD(lights, index, direction, &cos_sun);
  xfloat3 intensity = XI_GATHER_XYZ_FIELD(lights, index, intensity, 0);
  xfloat3 cone = XI_GATHER_XYZ_FIELD(lights, index, cone, &type);
  LightSample ls;
  xmask directional = type == (float)XI_LIGHT_DIRECTIONAL;
  xfloat3 to = xi_sub3(pos, org);
  xfloat dist = xi_length3(to);
  xfloat3 wi_point = xi_div3(to, dist);
  xfloat falloff = clamp((-xi_dot3(dir, wi_point) - cone.y) / fmax(cone.x - cone.y, (xfloat)1e-3f), 0.0f, 1.0f);
  falloff = type == (float)XI_LIGHT_SPOT ? falloff * falloff : (xfloat)1.0f;
  xfloat3 radiance_point = xi_scale3(intensity, falloff / (dist * dist));
  xfloat one_minus_cos = 1.0f - cos_sun;
  xfloat cos_t = 1.0f - u.x * one_minus_cos, phi = 2.0f * XI_PI * u.y;
  xfloat sin_t = xi_safe_sqrt(1.0f - cos_t * cos_t);
  xfloat3 wi_sun = xi_to_world(make_xfloat3(sin_t * cos(phi), sin_t * sin(phi), cos_t), xi_neg3(dir));
  xmask sun = one_minus_cos > 0.0f;
  xfloat sin2 = fmax(1.0f - cos_sun * cos_sun, (xfloat)1e-30f);
  ls.wi = xi_select3(directional, xi_select3(sun, wi_sun, xi_neg3(dir)), wi_point);
  ls.dist = directional ? (xfloat)FLT_MAX : dist;
  ls.radiance = xi_select3(directional, xi_scale3(intensity, sun ? 1.0f / (XI_PI * sin2) : (xfloat)1.0f), radiance_point);
  ls.pdf = directional && sun ? pick / (2.0f * XI_PI * one_minus_cos) : pick;
  ls.delta = XI_TRUE;
  return ls;
}

static inline LightSample xi_sample_light(__global const float* light_cdf, __global const uint* light_tri,
                                          __global const float* tri_light_pdf, __global const uint4* tri_vertices,
                                          __global const float4* vertices, __global const uint* tri_material,
                                          __global const MaterialData* materials,
                                          __global const PunctualLightData* punctual, EnvironmentData env,
                                          __global const float4* env_texels, __global const float* env_cdf,
                                          uint shading, uint light_count, xfloat3 org, xfloat2 u) {
  LightSample ls;
  xfloat u_pick = u.x;
  xuint entry = xi_gather_uint(light_tri, xi_pick_light(light_cdf, light_count, &u_pick));
  xmask triangle = entry < XI_LIGHT_PUNCTUAL;
  ls.wi = ls.radiance = xi_splat3(make_float3(0.0f, 0.0f, 1.0f));
  ls.dist = ls.pdf = 0.0f;
  ls.delta = XI_FALSE;
  if (XI_ANY(triangle)) {
    ls = xi_sample_triangle_light(tri_light_pdf, tri_vertices, vertices, tri_material, materials,
                                  triangle ? entry : (xuint)0u, org, make_xfloat2(u_pick, u.y));
  }
  if (xi_uses(shading, XI_USE_PUNCTUAL)) {
    xmask is_punctual = !triangle && entry != XI_LIGHT_ENVIRONMENT;
    if (XI_ANY(is_punctual)) {
      LightSample lp = xi_sample_punctual(punctual, is_punctual ? entry & ~XI_LIGHT_PUNCTUAL : (xuint)0u, org,
                                          make_xfloat2(u_pick, u.y));
      ls.wi = xi_select3(is_punctual, lp.wi, ls.wi);
      ls.dist = is_punctual ? lp.dist : ls.dist;
      ls.pdf = is_punctual ? lp.pdf : ls.pdf;
      ls.radiance = xi_select3(is_punctual, lp.radiance, ls.radiance);
      ls.delta = is_punctual;
    }
  }
  if (xi_uses(shading, XI_USE_ENVIRONMENT)) {
    xmask is_env = entry == XI_LIGHT_ENVIRONMENT;
    if (XI_ANY(is_env)) {
      xfloat env_pdf;
      xfloat3 env_radiance;
      xfloat3 wi = xi_env_sample(env_texels, env_cdf, env, make_xfloat2(u_pick, u.y), &env_pdf, &env_radiance);
      ls.wi = xi_select3(is_env, wi, ls.wi);
      ls.dist = is_env ? (xfloat)FLT_MAX : ls.dist;
      ls.pdf = is_env ? env.scale.w * env_pdf : ls.pdf;
      ls.radiance = xi_select3(is_env, env_radiance, ls.radiance);
    }
  }
  return ls;
}

#endif
