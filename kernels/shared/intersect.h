// Ray–triangle intersection (watertight, Woop–Benthin–Wald 2013) and BVH traversal, shared by the
// extend and shadow kernels and by the host's brute-force reference in tests.
#ifndef XI_INTERSECT_H
#define XI_INTERSECT_H
#include "compat.h"
#include "layout.h"

#define XI_BVH_STACK 128  // entries; the BVH builder checks that its tree never needs more
#define XI_NO_HIT 0xffffffffu

// Per-ray constants of the watertight test: the axis of largest |d| becomes z (a cyclic
// permutation of the axes, the same for every triangle the ray meets), then a shear makes the ray
// the +z axis so the edge functions are evaluated exactly as 2D cross products. (Woop et al. also
// swap x and y when d.z < 0 to keep the winding; that negates all three edge functions and their
// sum alike, which changes neither the hit test nor t, u, v.)
typedef struct {
  float3 o;  // the origin, permuted
  int kz;    // 0: (x, y, z) → (y, z, x); 1: → (z, x, y); 2: unchanged
  float sx, sy, sz;
} RayShear;

static inline float3 xi_permute_axes(float3 v, int kz) {
  return kz == 0 ? make_float3(v.y, v.z, v.x) : (kz == 1 ? make_float3(v.z, v.x, v.y) : v);
}

static inline RayShear xi_ray_shear(float3 o, float3 d) {
  RayShear s;
  float ax = fabs(d.x), ay = fabs(d.y), az = fabs(d.z);
  s.kz = (ax > ay) ? (ax > az ? 0 : 2) : (ay > az ? 1 : 2);
  s.o = xi_permute_axes(o, s.kz);
  float3 dp = xi_permute_axes(d, s.kz);
  s.sx = dp.x / dp.z;
  s.sy = dp.y / dp.z;
  s.sz = 1.0f / dp.z;
  return s;
}

// Returns true and sets *t, *u, *v (barycentrics of v1 and v2) for a hit in (0, tmax).
static inline bool xi_intersect_triangle(RayShear s, float3 p0, float3 p1, float3 p2, float tmax, float* t,
                                         float* u, float* v) {
  float3 a = xi_permute_axes(p0, s.kz) - s.o, b = xi_permute_axes(p1, s.kz) - s.o,
         c = xi_permute_axes(p2, s.kz) - s.o;
  float ax = a.x - s.sx * a.z, ay = a.y - s.sy * a.z;
  float bx = b.x - s.sx * b.z, by = b.y - s.sy * b.z;
  float cx = c.x - s.sx * c.z, cy = c.y - s.sy * c.z;
  float e0 = bx * cy - by * cx;
  float e1 = cx * ay - cy * ax;
  float e2 = ax * by - ay * bx;
  if ((e0 < 0.0f || e1 < 0.0f || e2 < 0.0f) && (e0 > 0.0f || e1 > 0.0f || e2 > 0.0f)) return false;
  float det = e0 + e1 + e2;
  if (det == 0.0f) return false;
  float tt = (e0 * s.sz * a.z + e1 * s.sz * b.z + e2 * s.sz * c.z) / det;
  if (!(tt > 0.0f && tt < tmax)) return false;
  *t = tt;
  *u = e1 / det;
  *v = e2 / det;
  return true;
}

static inline float3 xi_safe_inverse(float3 d) {
  const float big = 1e30f;
  return make_float3(d.x != 0.0f ? 1.0f / d.x : big, d.y != 0.0f ? 1.0f / d.y : big,
                     d.z != 0.0f ? 1.0f / d.z : big);
}

static inline float3 xi_tri_vertex(__global const float4* verts, uint tri, uint k) {
  return xyz(verts[3u * tri + k]);
}

// A little slack on box tests so rounding never rejects a box that a triangle in it would hit.
#define XI_BOX_SLACK 1.00000024f

// Pushes child lane `k` of node `n` if the ray enters its box (entry distance tn_k, exit tf_k),
// keeping the entries pushed for this node sorted so the nearest is on top. (An empty lane's box
// passes the test when both distances are +inf: a ray with no tmax, every direction positive.)
#define XI_PUSH_CHILD(n, k, tn_k, tf_k)                                  \
  if ((tn_k) <= (tf_k) * XI_BOX_SLACK && (n)->child[k] != XI_BVH_EMPTY) { \
    uint j = sp++;                                                       \
    for (; j > base && stack_tn[j - 1u] < (tn_k); --j) {                  \
      stack[j] = stack[j - 1u];                                          \
      stack_tn[j] = stack_tn[j - 1u];                                      \
    }                                                                    \
    stack[j] = (n)->child[k];                                            \
    stack_tn[j] = (tn_k);                                                 \
  }

// Closest hit (any_hit == false) or any hit before tmax (any_hit == true). Returns the triangle
// index or XI_NO_HIT; *t, *u, *v describe the hit. The stack holds node or leaf entries with the
// distance at which the ray enters them, so entries behind the best hit are skipped when popped;
// the host checks that no tree needs more than XI_BVH_STACK entries (xi::Bvh::stats.stack).
static inline uint xi_trace(__global const BvhNode* nodes, __global const float4* verts, float3 o,
                            float3 d, float tmax, bool any_hit, float* t, float* u, float* v) {
  RayShear s = xi_ray_shear(o, d);
  float3 inv_d = xi_safe_inverse(d);
  uint stack[XI_BVH_STACK];
  float stack_tn[XI_BVH_STACK];
  uint sp = 0u;
  uint entry = 0u;  // the root, always an interior node
  uint found = XI_NO_HIT;
  float best = tmax;
  for (;;) {
    if (entry & XI_BVH_LEAF) {
      uint first = entry & XI_BVH_FIRST_MASK, end = first + 1u + ((entry >> 27) & 15u);
      for (uint i = first; i < end; ++i) {
        float tt, uu, vv;
        if (xi_intersect_triangle(s, xi_tri_vertex(verts, i, 0u), xi_tri_vertex(verts, i, 1u),
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
      // Slab test of all four child boxes at once.
      __global const BvhNode* n = nodes + entry;
      float4 x0 = (n->lo_x - o.x) * inv_d.x, x1 = (n->hi_x - o.x) * inv_d.x;
      float4 y0 = (n->lo_y - o.y) * inv_d.y, y1 = (n->hi_y - o.y) * inv_d.y;
      float4 z0 = (n->lo_z - o.z) * inv_d.z, z1 = (n->hi_z - o.z) * inv_d.z;
      float4 tn = fmax(fmax(fmin(x0, x1), fmin(y0, y1)), fmax(fmin(z0, z1), make_float4(0.0f, 0.0f, 0.0f, 0.0f)));
      float4 tf = fmin(fmin(fmax(x0, x1), fmax(y0, y1)), fmin(fmax(z0, z1), make_float4(best, best, best, best)));
      uint base = sp;
      XI_PUSH_CHILD(n, 0, tn.x, tf.x)
      XI_PUSH_CHILD(n, 1, tn.y, tf.y)
      XI_PUSH_CHILD(n, 2, tn.z, tf.z)
      XI_PUSH_CHILD(n, 3, tn.w, tf.w)
    }
    // Pop the nearest entry the ray enters before its best hit so far.
    for (;;) {
      if (sp == 0u) return found;
      --sp;
      if (stack_tn[sp] <= best * XI_BOX_SLACK) break;
    }
    entry = stack[sp];
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
