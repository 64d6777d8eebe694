// Area lights: every emissive triangle, picked in proportion to its power, then a point uniform on
// its area, both from one 2D sample; the pdf is converted from area to solid angle at the shading
// point.
#ifndef XI_LIGHTS_H
#define XI_LIGHTS_H
#include "compat.h"
#include "intersect.h"
#include "layout.h"
#include "warps.h"

typedef struct {
  float3 wi;        // unit direction from the origin to the light point
  float dist;       // distance to it, the point moved off the light by its rounding error
  float pdf;        // solid-angle density of wi; 0 when the point's emitting side faces away
  float3 radiance;  // emitted toward the origin
} LightSample;

// Binary search of the normalised CDF over the n emissive triangles with *u, which is then
// stretched back to [0, 1) within the chosen triangle's interval, so one uniform both picks the
// light and places the point on it (and keeps its stratification).
static inline uint xi_pick_light(__global const float* cdf, uint n, float* u) {
  uint lo = 0u, hi = n - 1u;
  while (lo < hi) {
    uint mid = (lo + hi) >> 1;
    if (*u < cdf[mid]) hi = mid; else lo = mid + 1u;
  }
  float below = lo > 0u ? cdf[lo - 1u] : 0.0f;
  *u = clamp((*u - below) / (cdf[lo] - below), 0.0f, XI_ONE_MINUS_EPSILON);
  return lo;
}

// Solid-angle pdf of reaching emissive triangle `tri` at distance dist with cosine cos_l at the
// light; tri_light_pdf holds P(pick tri) / area(tri).
static inline float xi_light_pdf(__global const float* tri_light_pdf, uint tri, float dist, float cos_l) {
  return cos_l > 0.0f ? tri_light_pdf[tri] * dist * dist / cos_l : 0.0f;
}

static inline LightSample xi_sample_light(__global const float* light_cdf, __global const uint* light_tri,
                                          __global const float* tri_light_pdf, __global const float4* tri_verts,
                                          __global const uint* tri_material, __global const MaterialData* materials,
                                          uint light_count, float3 org, float2 u) {
  LightSample ls;
  float u_pick = u.x;
  uint lt = light_tri[xi_pick_light(light_cdf, light_count, &u_pick)];
  float2 u_point = make_float2(u_pick, u.y);
  float3 q0 = xyz(tri_verts[3u * lt]), q1 = xyz(tri_verts[3u * lt + 1u]), q2 = xyz(tri_verts[3u * lt + 2u]);
  float2 b = xi_square_to_triangle(u_point);
  float3 q_error;
  float3 q = xi_interpolate(q2, q0, q1, b.x, b.y, &q_error);  // b.x q0 + b.y q1 + (1 - b.x - b.y) q2
  float3 nl = normalize(cross(q1 - q0, q2 - q0));
  // The shadow ray ends off the light's surface, on the origin's side: it cannot hit the light.
  float3 to_light = xi_offset_ray_origin(q, q_error, nl, org - q) - org;
  ls.dist = length(to_light);
  ls.wi = to_light / ls.dist;
  MaterialData m = materials[tri_material[lt]];
  float cos_l = -dot(nl, ls.wi);
  if (m.emission.w > 0.0f) cos_l = fabs(cos_l);  // two-sided
  ls.pdf = xi_light_pdf(tri_light_pdf, lt, ls.dist, cos_l);
  ls.radiance = xyz(m.emission);
  return ls;
}

#endif
