// Ray–triangle intersection (watertight, Woop–Benthin–Wald 2013) and BVH traversal, shared by the
// extend and shadow kernels and by the host's brute-force reference in tests.
#ifndef XI_INTERSECT_H
#define XI_INTERSECT_H
#include "compat.h"
#include "layout.h"

#define XI_BVH_STACK 64
#define XI_NO_HIT 0xffffffffu

// Per-ray constants of the watertight test: the axis of largest |d| becomes z, then a shear
// makes the ray the +z axis so the edge functions are evaluated exactly as 2D cross products.
typedef struct {
  int kx, ky, kz;
  float sx, sy, sz;
} RayShear;

static inline float xi_axis(float3 v, int k) { return k == 0 ? v.x : (k == 1 ? v.y : v.z); }

static inline RayShear xi_ray_shear(float3 d) {
  RayShear s;
  float ax = fabs(d.x), ay = fabs(d.y), az = fabs(d.z);
  s.kz = (ax > ay) ? (ax > az ? 0 : 2) : (ay > az ? 1 : 2);
  s.kx = s.kz == 2 ? 0 : s.kz + 1;
  s.ky = s.kx == 2 ? 0 : s.kx + 1;
  if (xi_axis(d, s.kz) < 0.0f) {  // keep the winding
    int t = s.kx;
    s.kx = s.ky;
    s.ky = t;
  }
  float dz = xi_axis(d, s.kz);
  s.sx = xi_axis(d, s.kx) / dz;
  s.sy = xi_axis(d, s.ky) / dz;
  s.sz = 1.0f / dz;
  return s;
}

// Returns true and sets *t, *u, *v (barycentrics of v1 and v2) for a hit in (0, tmax).
static inline bool xi_intersect_triangle(float3 o, RayShear s, float3 p0, float3 p1, float3 p2,
                                         float tmax, float* t, float* u, float* v) {
  float3 a = p0 - o, b = p1 - o, c = p2 - o;
  float az = xi_axis(a, s.kz), bz = xi_axis(b, s.kz), cz = xi_axis(c, s.kz);
  float ax = xi_axis(a, s.kx) - s.sx * az, ay = xi_axis(a, s.ky) - s.sy * az;
  float bx = xi_axis(b, s.kx) - s.sx * bz, by = xi_axis(b, s.ky) - s.sy * bz;
  float cx = xi_axis(c, s.kx) - s.sx * cz, cy = xi_axis(c, s.ky) - s.sy * cz;
  float e0 = bx * cy - by * cx;
  float e1 = cx * ay - cy * ax;
  float e2 = ax * by - ay * bx;
  if ((e0 < 0.0f || e1 < 0.0f || e2 < 0.0f) && (e0 > 0.0f || e1 > 0.0f || e2 > 0.0f)) return false;
  float det = e0 + e1 + e2;
  if (det == 0.0f) return false;
  float tt = (e0 * s.sz * az + e1 * s.sz * bz + e2 * s.sz * cz) / det;
  if (!(tt > 0.0f && tt < tmax)) return false;
  *t = tt;
  *u = e1 / det;
  *v = e2 / det;
  return true;
}

// Slab test against a node box with precomputed 1/d; returns the entry distance or +inf.
static inline float xi_intersect_box(float3 o, float3 inv_d, float4 bmin, float4 bmax, float tmax) {
  float3 t0 = (xyz(bmin) - o) * inv_d;
  float3 t1 = (xyz(bmax) - o) * inv_d;
  float3 lo = fmin(t0, t1), hi = fmax(t0, t1);
  float tn = fmax(fmax(lo.x, lo.y), fmax(lo.z, 0.0f));
  float tf = fmin(fmin(hi.x, hi.y), fmin(hi.z, tmax));
  // A little slack so rounding never rejects a box a triangle in it would hit.
  return tn <= tf * 1.00000024f ? tn : INFINITY;
}

static inline float3 xi_safe_inverse(float3 d) {
  const float big = 1e30f;
  return make_float3(d.x != 0.0f ? 1.0f / d.x : big, d.y != 0.0f ? 1.0f / d.y : big,
                     d.z != 0.0f ? 1.0f / d.z : big);
}

static inline float3 xi_tri_vertex(__global const float4* verts, uint tri, uint k) {
  return xyz(verts[3u * tri + k]);
}

// Closest hit (any_hit == false) or any hit before tmax (any_hit == true). Returns the triangle
// index or XI_NO_HIT; *t, *u, *v describe the hit.
static inline uint xi_trace(__global const BvhNode* nodes, __global const float4* verts, float3 o,
                            float3 d, float tmax, bool any_hit, float* t, float* u, float* v) {
  RayShear s = xi_ray_shear(d);
  float3 inv_d = xi_safe_inverse(d);
  uint stack[XI_BVH_STACK];
  uint sp = 0u;
  uint node = 0u;
  uint found = XI_NO_HIT;
  float best = tmax;
  if (xi_intersect_box(o, inv_d, nodes[0].bmin, nodes[0].bmax, best) == INFINITY) return XI_NO_HIT;
  for (;;) {
    BvhNode n = nodes[node];
    uint count = as_uint(n.bmax.w);
    uint index = as_uint(n.bmin.w);
    if (count > 0u) {
      for (uint i = index; i < index + count; ++i) {
        float tt, uu, vv;
        if (xi_intersect_triangle(o, s, xi_tri_vertex(verts, i, 0u), xi_tri_vertex(verts, i, 1u),
                                  xi_tri_vertex(verts, i, 2u), best, &tt, &uu, &vv)) {
          best = tt;
          *t = tt;
          *u = uu;
          *v = vv;
          found = i;
          if (any_hit) return found;
        }
      }
    } else {
      uint left = node + 1u, right = index;
      float tl = xi_intersect_box(o, inv_d, nodes[left].bmin, nodes[left].bmax, best);
      float tr = xi_intersect_box(o, inv_d, nodes[right].bmin, nodes[right].bmax, best);
      if (tl != INFINITY && tr != INFINITY) {
        uint near_child = tl <= tr ? left : right;
        stack[sp++] = tl <= tr ? right : left;  // visit the nearer child first
        node = near_child;
        continue;
      }
      if (tl != INFINITY) { node = left; continue; }
      if (tr != INFINITY) { node = right; continue; }
    }
    // Pop until a node that may still hold something closer than the best hit.
    bool next = false;
    while (sp > 0u) {
      node = stack[--sp];
      if (xi_intersect_box(o, inv_d, nodes[node].bmin, nodes[node].bmax, best) != INFINITY) {
        next = true;
        break;
      }
    }
    if (!next) return found;
  }
}

// Wächter and Binder, Ray Tracing Gems ch. 6: move a hit point off its surface along the geometric
// normal by a few ULPs in integer space (a fixed epsilon near the origin), so the next ray does not
// hit the same surface again, whatever the scene's scale.
static inline float xi_offset_component(float p, float n) {
  const float origin = 1.0f / 32.0f, float_scale = 1.0f / 65536.0f, int_scale = 256.0f;
  int of = (int)(int_scale * n);
  float pi = as_float_i(as_int(p) + (p < 0.0f ? -of : of));
  return fabs(p) < origin ? p + float_scale * n : pi;
}
static inline float3 xi_offset_ray_origin(float3 p, float3 n) {
  return make_float3(xi_offset_component(p.x, n.x), xi_offset_component(p.y, n.y),
                     xi_offset_component(p.z, n.z));
}

#endif
