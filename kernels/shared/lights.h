// Area lights: every emissive triangle, picked in proportion to its power, then a point uniform on
// its area, both from one 2D sample; the pdf is converted from area to solid angle at the shading
// point. Written on lane types (lanes.h).
#ifndef XI_LIGHTS_H
#define XI_LIGHTS_H
#include "bsdf.h"
#include "lanes.h"
#include "layout.h"
#include "spawn.h"
#include "warps.h"

typedef struct {
  xfloat3 wi;        // unit direction from the origin to the light point
  xfloat dist;       // distance to it, the point moved off the light by its rounding error
  xfloat pdf;        // solid-angle density of wi; 0 when the point's emitting side faces away
  xfloat3 radiance;  // emitted toward the origin
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

static inline LightSample xi_sample_light(__global const float* light_cdf, __global const uint* light_tri,
                                          __global const float* tri_light_pdf, __global const float4* tri_verts,
                                          __global const uint* tri_material, __global const MaterialData* materials,
                                          uint light_count, xfloat3 org, xfloat2 u) {
  LightSample ls;
  xfloat u_pick = u.x;
  xuint lt = xi_gather_uint(light_tri, xi_pick_light(light_cdf, light_count, &u_pick));
  xfloat3 q0 = xi_gather_xyz(tri_verts, 3u * lt, 0), q1 = xi_gather_xyz(tri_verts, 3u * lt + 1u, 0),
          q2 = xi_gather_xyz(tri_verts, 3u * lt + 2u, 0);
  xfloat2 b = xi_square_to_triangle(make_xfloat2(u_pick, u.y));
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
  return ls;
}

#endif
