// Ray–triangle intersection (watertight, Woop–Benthin–Wald 2013) and BVH traversal, shared by the
// extend and shadow kernels and by the host's brute-force reference in tests.
#ifndef XI_INTERSECT_H
#define XI_INTERSECT_H
#include "compat.h"
#include "layout.h"

// Watertightness needs every product rounded on its own: the edge function of a shared edge is
// bx·cy − by·cx in one triangle and exactly its negation, cx·by − cy·bx, in the other, which a
// fused multiply-add breaks (it rounds one product, not the other). OpenCL contracts a·b + c by
// default (and xi builds with -cl-mad-enable), which let 0.1% of rays aimed at the edges and
// vertices of a closed mesh escape it on PoCL
// (HardCases.TenMillionRaysFromInsideClosedMeshesNoneEscapes). Restored at the end of this file.
#ifdef __OPENCL_VERSION__
#pragma OPENCL FP_CONTRACT OFF
#endif

#define XI_BVH_STACK 128  // entries; the BVH builder checks that its tree never needs more

// The width of the BVH nodes the kernels traverse (layout.h), set by the host (RenderOptions::
// bvh_width): 8 on CPU devices, 4 elsewhere and on the host (its tests' xi_trace).
#ifndef XI_BVH_WIDTH
#define XI_BVH_WIDTH 4
#endif
#if XI_BVH_WIDTH == 8
typedef BvhNode8 TraceNode;
typedef float8 NodeFloat;
#define xi_node_lane_bits(m) xi_lane_bits8(m)
#elif XI_BVH_WIDTH == 4
typedef BvhNode TraceNode;
typedef float4 NodeFloat;
#define xi_node_lane_bits(m) xi_lane_bits(m)
#else
#error "XI_BVH_WIDTH must be 4 or 8"
#endif

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

// The axes that become x and y when axis kz becomes z.
static inline int xi_axis_to_x(int kz) { return kz == 2 ? 0 : kz + 1; }
static inline int xi_axis_to_y(int kz) { return kz == 0 ? 2 : kz - 1; }

// By index, not by a choice between three vectors: the axis is random from ray to ray, so a
// branch on it is mispredicted.
static inline float3 xi_permute_axes(float3 v, int kz) {
  float a[3] = {v.x, v.y, v.z};
  return make_float3(a[xi_axis_to_x(kz)], a[xi_axis_to_y(kz)], a[kz]);
}

static inline RayShear xi_ray_shear(float3 o, float3 d) {
  RayShear s;
  float ax = fabs(d.x), ay = fabs(d.y), az = fabs(d.z);
  s.kz = (ax > ay) ? (ax > az ? 0 : 2) : (ay > az ? 1 : 2);
  s.o = xi_permute_axes(o, s.kz);
  float3 dp = xi_permute_axes(d, s.kz);
  s.sz = 1.0f / dp.z;  // |dp.z| is the largest component: never 0 for a unit direction
  s.sx = dp.x * s.sz;
  s.sy = dp.y * s.sz;
  return s;
}

// The bound on the rounding error of t, times |det| (Pharr, Jakob and Humphreys, Physically Based
// Rendering 4th ed., "Managing Rounding Error"), from the largest magnitudes of the sheared vertex
// coordinates (x, y; z scaled by sz) and of the edge functions. A hit within it may be the surface
// a ray was spawned from, so it is refused: with origins offset by their own error bounds (below),
// no ray re-hits its surface, at any scale, without an epsilon. Scalars or float4 lanes alike.
#define XI_T_ERROR_DET(max_x, max_y, max_z, max_e)                                                 \
  (3.0f * (XI_GAMMA(3) * (max_e) * (max_z) +                                                      \
           2.0f * (XI_GAMMA(2) * (max_x) * (max_y) + XI_GAMMA(5) * ((max_y) + (max_z)) * (max_x) + \
                   XI_GAMMA(5) * ((max_x) + (max_z)) * (max_y)) * (max_z) +                       \
           XI_GAMMA(3) * (max_z) * (max_e)))

// The test from the vertices a, b, c relative to the ray's origin, axes permuted as the ray's: the
// shear that makes the ray the +z axis, the edge functions e0, e1, e2 and t·det. One sequence for
// one triangle and one ray (xi_intersect_triangle), four or eight triangles and one ray
// (xi_intersect_block) and one triangle and eight rays (xi_trace_packet8): the same operations in
// the same order, so all three find bitwise the same hits. Scalars or vector lanes alike.
#define XI_SHEARED_EDGES(sx, sy, sz, ax, ay, az, bx, by, bz, cx, cy, cz, e0, e1, e2, t_det) \
  ax = ax - (sx) * az, ay = ay - (sy) * az;                                                 \
  bx = bx - (sx) * bz, by = by - (sy) * bz;                                                 \
  cx = cx - (sx) * cz, cy = cy - (sy) * cz;                                                 \
  e0 = bx * cy - by * cx;                                                                   \
  e1 = cx * ay - cy * ax;                                                                   \
  e2 = ax * by - ay * bx;                                                                   \
  t_det = e0 * (sz) * az + e1 * (sz) * bz + e2 * (sz) * cz

// XI_T_ERROR_DET from the same values, with `maxf` the lane type's max.
#define XI_T_ERROR_DET_OF(maxf, sz, ax, ay, az, bx, by, bz, cx, cy, cz, e0, e1, e2)              \
  XI_T_ERROR_DET(maxf(maxf(fabs(ax), fabs(bx)), fabs(cx)), maxf(maxf(fabs(ay), fabs(by)), fabs(cy)), \
                 maxf(maxf(fabs((sz) * az), fabs((sz) * bz)), fabs((sz) * cz)),                   \
                 maxf(maxf(fabs(e0), fabs(e1)), fabs(e2)))

// The end of the test, on the edge functions e0, e1, e2, t·det and the error bound of t·|det|: a
// hit in (t error, tmax) when the edge functions do not differ in sign and do not all vanish.
static inline bool xi_edge_hit(float e0, float e1, float e2, float t_det, float t_err_det, float tmax, float* t,
                               float* u, float* v) {
  if ((e0 < 0.0f || e1 < 0.0f || e2 < 0.0f) && (e0 > 0.0f || e1 > 0.0f || e2 > 0.0f)) return false;
  float det = e0 + e1 + e2;
  if (det == 0.0f) return false;
  float tt = t_det / det;
  if (!(tt > t_err_det / fabs(det) && tt < tmax)) return false;  // also rejects NaN (an unused block lane)
  *t = tt;
  *u = e1 / det;
  *v = e2 / det;
  return true;
}

// Returns true and sets *t, *u, *v (barycentrics of v1 and v2) for a hit in (0, tmax).
static inline bool xi_intersect_triangle(RayShear s, float3 p0, float3 p1, float3 p2, float tmax, float* t,
                                         float* u, float* v) {
  float3 a = xi_permute_axes(p0, s.kz) - s.o, b = xi_permute_axes(p1, s.kz) - s.o,
         c = xi_permute_axes(p2, s.kz) - s.o;
  float ax = a.x, ay = a.y, az = a.z, bx = b.x, by = b.y, bz = b.z, cx = c.x, cy = c.y, cz = c.z;
  float e0, e1, e2, t_det;
  XI_SHEARED_EDGES(s.sx, s.sy, s.sz, ax, ay, az, bx, by, bz, cx, cy, cz, e0, e1, e2, t_det);
  return xi_edge_hit(e0, e1, e2, t_det, XI_T_ERROR_DET_OF(fmax, s.sz, ax, ay, az, bx, by, bz, cx, cy, cz, e0, e1, e2),
                     tmax, t, u, v);
}

// The same test on the four triangles of a block at once, or on two blocks' eight where the BVH is
// 8 wide (CPU devices: AVX tests eight lanes in one operation as fast as four, and a leaf holds at
// most two blocks), up to the edge functions and t·det, with the same operations in the same order
// as xi_intersect_triangle.
#if XI_BVH_WIDTH == 8
#define XI_BLOCK_LANES 8
typedef float8 BlockFloat;
typedef int8 BlockMask;
#define xi_block_lane_bits(m) xi_lane_bits8(m)
#define XI_BLOCK_COORD(b0, b1, axis, j) ((float8)((b0)->coord[axis][j], (b1)->coord[axis][j]))
#else
#define XI_BLOCK_LANES 4
typedef float4 BlockFloat;
typedef int4 BlockMask;
#define xi_block_lane_bits(m) xi_lane_bits(m)
#define XI_BLOCK_COORD(b0, b1, axis, j) ((void)(b1), (b0)->coord[axis][j])
#endif
typedef struct {
  BlockFloat e0, e1, e2, t_det, t_err_det;
} BlockEdges;

// Vertex j of the blocks' triangles (b1 is read only when 8 wide), axes permuted as the ray's and
// relative to its origin. The permutation is an index per axis (the same for every block the ray
// meets), not a choice per coordinate.
static inline void xi_block_vertex(__global const TriBlock* b0, __global const TriBlock* b1, int j, RayShear s,
                                   BlockFloat* x, BlockFloat* y, BlockFloat* z) {
  *x = XI_BLOCK_COORD(b0, b1, xi_axis_to_x(s.kz), j) - s.o.x;
  *y = XI_BLOCK_COORD(b0, b1, xi_axis_to_y(s.kz), j) - s.o.y;
  *z = XI_BLOCK_COORD(b0, b1, s.kz, j) - s.o.z;
}

// The lanes of the blocks that the ray hits in (t error, tmax), as bits; *e gets the lanes' edge
// functions, t·det and t's error bound (set whenever a lane hits), for xi_edge_hit to finish a lane
// as xi_intersect_triangle would. (det = 0 gives t = ±inf or NaN, which fails the tests.) On a CPU
// (XI_CPU_DEVICE, set by the host) the bound is computed only once a lane has passed the cheaper
// tests, as most blocks a ray visits it misses: extend +7% on PoCL. A GPU warp computes it whenever
// any of its rays needs it, so there the early exit is only a branch: without it, extend ran 8–12%
// faster on an H200 (README, "On a GPU"). Hits are bitwise the same either way.
static inline uint xi_intersect_block(RayShear s, __global const TriBlock* b0, __global const TriBlock* b1,
                                      float tmax, BlockEdges* e) {
  BlockFloat ax, ay, az, bx, by, bz, cx, cy, cz;
  xi_block_vertex(b0, b1, 0, s, &ax, &ay, &az);
  xi_block_vertex(b0, b1, 1, s, &bx, &by, &bz);
  xi_block_vertex(b0, b1, 2, s, &cx, &cy, &cz);
  XI_SHEARED_EDGES(s.sx, s.sy, s.sz, ax, ay, az, bx, by, bz, cx, cy, cz, e->e0, e->e1, e->e2, e->t_det);
  const BlockFloat zero = (BlockFloat)(0.0f);
  BlockMask mixed = (xi_less4(e->e0, zero) | xi_less4(e->e1, zero) | xi_less4(e->e2, zero)) &
                    (xi_greater4(e->e0, zero) | xi_greater4(e->e1, zero) | xi_greater4(e->e2, zero));
  BlockFloat det = e->e0 + e->e1 + e->e2;
  BlockFloat t = e->t_det / det;
  BlockMask candidate = xi_greater4(t, zero) & xi_less4(t, (BlockFloat)(tmax)) & ~mixed;
#ifdef XI_CPU_DEVICE
  if (xi_block_lane_bits(candidate) == 0u) return 0u;
#endif
  // (An unused lane's NaNs make its bound NaN, or not: its t is NaN, which fails either way.)
  e->t_err_det = XI_T_ERROR_DET_OF(xi_max, s.sz, ax, ay, az, bx, by, bz, cx, cy, cz, e->e0, e->e1, e->e2);
  return xi_block_lane_bits(candidate & xi_greater4(t, e->t_err_det / fabs(det)));
}

static inline float3 xi_safe_inverse(float3 d) {
  const float big = 1e30f;
  return make_float3(d.x != 0.0f ? 1.0f / d.x : big, d.y != 0.0f ? 1.0f / d.y : big,
                     d.z != 0.0f ? 1.0f / d.z : big);
}

// A little slack on box tests so rounding never rejects a box that a triangle in it would hit.
#define XI_BOX_SLACK 1.00000024f

// Pushes child lane `k` of node `n` if bit k of `hits` says the ray enters its box (at tn_k). A
// closest-hit query keeps the entries pushed for this node sorted so the nearest is on top; an
// any-hit query (shadow rays) stops at whichever hit it finds, so it skips the sort (shadow stage
// on PoCL: the engine 5% faster, the Cornell box the same). (Branch-free placement, each lane's
// rank among the entered lanes by vector compares, was 3–10% slower on PoCL.)
#define XI_PUSH_CHILD(n, k, tn_k)                                                    \
  if (hits & (1u << (k))) {                                                          \
    uint j = sp++;                                                                   \
    for (; !any_hit && j > base && as_float(stack[j - 1u].y) < (tn_k); --j)          \
      stack[j] = stack[j - 1u];                                                      \
    stack[j] = make_uint2((n)->child[k], as_uint(tn_k));                             \
  }

// Takes lane `c` (x, y, z, w or s0 … s7; index l, triangle k of block blk) of a block test, in lane
// order, as xi_intersect_triangle would one triangle after the other: a closer hit becomes the best.
#define XI_BLOCK_LANE(c, l, blk, k)                                                                  \
  if ((hits & (1u << (l))) &&                                                                      \
      xi_edge_hit(e.e0.c, e.e1.c, e.e2.c, e.t_det.c, e.t_err_det.c, best, &tt, &uu, &vv)) {         \
    best = tt;                                                                                       \
    *t = tt;                                                                                         \
    *u = uu;                                                                                         \
    *v = vv;                                                                                         \
    found = (blk)->tri[k];                                                                           \
    if (any_hit) return found;                                                                       \
  }

// Closest hit (any_hit == false) or any hit before tmax (any_hit == true). Returns the triangle
// index (its position in BVH order) or XI_NO_HIT; *t, *u, *v describe the hit. The stack holds
// node or leaf entries with the distance at which the ray enters them, so entries behind the best
// hit are skipped when popped; the host checks that no tree needs more than XI_BVH_STACK entries
// (xi::Bvh::stats.stack).
static inline uint xi_trace(__global const TraceNode* nodes, __global const TriBlock* blocks, float3 o,
                            float3 d, float tmax, bool any_hit, float* t, float* u, float* v) {
  RayShear s = xi_ray_shear(o, d);
  float3 inv_d = xi_safe_inverse(d);
  // Which of a node's bounds (lo x, hi x, lo y, ...) is each axis's near plane: an index, so a
  // node's slab test loads its planes without a choice per plane.
  int near_x = inv_d.x < 0.0f ? 1 : 0, near_y = inv_d.y < 0.0f ? 3 : 2, near_z = inv_d.z < 0.0f ? 5 : 4;
  uint2 stack[XI_BVH_STACK];  // (entry, the distance at which the ray enters it as bits): one move each
  uint sp = 0u;
  uint entry = 0u;  // the root, always an interior node
  uint found = XI_NO_HIT;
  float best = tmax;
  for (;;) {
    if (entry & XI_BVH_LEAF) {
      uint first = entry & XI_BVH_FIRST_MASK, end = first + 1u + ((entry >> 27) & 15u);
      for (uint k = first; k < end; k += XI_BLOCK_LANES / 4) {
        __global const TriBlock* b0 = blocks + k;
#if XI_BLOCK_LANES == 8
        // A leaf's two blocks in one test; a lone block is tested twice over, the copy's lanes off.
        __global const TriBlock* b1 = k + 1u < end ? b0 + 1 : b0;
        const uint lanes = k + 1u < end ? 0xffu : 0x0fu;
#else
        __global const TriBlock* b1 = b0;
        const uint lanes = 0xfu;
#endif
        BlockEdges e;
        uint hits = xi_intersect_block(s, b0, b1, best, &e) & lanes;
        if (hits == 0u) continue;
        float tt, uu, vv;
#if XI_BLOCK_LANES == 8
        XI_BLOCK_LANE(s0, 0, b0, 0)
        XI_BLOCK_LANE(s1, 1, b0, 1)
        XI_BLOCK_LANE(s2, 2, b0, 2)
        XI_BLOCK_LANE(s3, 3, b0, 3)
        XI_BLOCK_LANE(s4, 4, b1, 0)
        XI_BLOCK_LANE(s5, 5, b1, 1)
        XI_BLOCK_LANE(s6, 6, b1, 2)
        XI_BLOCK_LANE(s7, 7, b1, 3)
#else
        XI_BLOCK_LANE(x, 0, b0, 0)
        XI_BLOCK_LANE(y, 1, b0, 1)
        XI_BLOCK_LANE(z, 2, b0, 2)
        XI_BLOCK_LANE(w, 3, b0, 3)
#endif
      }
    } else {
      // Slab test of all the child boxes at once, each axis's near plane chosen by the sign of the
      // direction (an unused lane's inverted box is then always missed). No NaN can arise (inv_d
      // is finite, a plane infinite only in an unused lane), so xi_min/xi_max will do.
      __global const TraceNode* n = nodes + entry;
      NodeFloat nx = n->bounds[near_x], fx = n->bounds[near_x ^ 1];
      NodeFloat ny = n->bounds[near_y], fy = n->bounds[near_y ^ 1];
      NodeFloat nz = n->bounds[near_z], fz = n->bounds[near_z ^ 1];
      NodeFloat tn = xi_max(xi_max((nx - o.x) * inv_d.x, (ny - o.y) * inv_d.y),
                            xi_max((nz - o.z) * inv_d.z, (NodeFloat)0.0f));
      NodeFloat tf = xi_min(xi_min((fx - o.x) * inv_d.x, (fy - o.y) * inv_d.y),
                            xi_min((fz - o.z) * inv_d.z, (NodeFloat)best));
      uint hits = xi_node_lane_bits(xi_less_equal(tn, tf * XI_BOX_SLACK));
      if (hits != 0u && (hits & (hits - 1u)) == 0u) {  // one child: go there, the stack untouched
        entry = n->child[31 - clz(hits)];
        continue;
      }
      uint base = sp;
#if XI_BVH_WIDTH == 8
      XI_PUSH_CHILD(n, 0, tn.s0)
      XI_PUSH_CHILD(n, 1, tn.s1)
      XI_PUSH_CHILD(n, 2, tn.s2)
      XI_PUSH_CHILD(n, 3, tn.s3)
      XI_PUSH_CHILD(n, 4, tn.s4)
      XI_PUSH_CHILD(n, 5, tn.s5)
      XI_PUSH_CHILD(n, 6, tn.s6)
      XI_PUSH_CHILD(n, 7, tn.s7)
#else
      XI_PUSH_CHILD(n, 0, tn.x)
      XI_PUSH_CHILD(n, 1, tn.y)
      XI_PUSH_CHILD(n, 2, tn.z)
      XI_PUSH_CHILD(n, 3, tn.w)
#endif
    }
    // Pop the nearest entry the ray enters before its best hit so far.
    for (;;) {
      if (sp == 0u) return found;
      --sp;
      if (as_float(stack[sp].y) <= best * XI_BOX_SLACK) break;
    }
    entry = stack[sp].x;
  }
}


#if XI_BVH_WIDTH == 8
// Rays in packets of eight (an 8-wide tree; the extend kernel's camera rays, and in a small tree its
// bounce rays and the shadow kernel's rays too: layout.h's XI_EXTEND_PACKET and XI_SHADOW_PACKET).
// Eight rays go through the tree together: a node's eight
// child boxes are each tested against the eight rays, and a leaf's triangles each against the eight
// rays at once, so a node's loads, its stack entries and its branches serve eight rays, and a leaf of
// two triangles no longer costs each ray a whole eight-lane block test. A node is entered when any
// of the rays enters it, so the packet does the union of its rays' work: for neighbouring camera
// rays little more than each one's; for bounce rays, which part ways, little more only where each
// ray visits most of the tree anyway. Each ray's hit is the one xi_trace finds, bitwise (the same
// box and triangle arithmetic per lane; where two triangles are hit at exactly the same t, the order
// of traversal may pick the other). Each ray has its own axis permutation (watertight test) and near
// planes (slab test), chosen per lane by selects; where all eight share them, as neighbouring camera
// rays do, the packet's one permutation and planes are indices, as in xi_trace (engine camera rays
// 16% slower with the selects).
static inline float xi_lanes_min8(float8 v) {
  float4 a = xi_min(v.lo, v.hi);
  float2 b = xi_min(a.lo, a.hi);
  return b.x < b.y ? b.x : b.y;
}
static inline float xi_lanes_max8(float8 v) {
  float4 a = xi_max(v.lo, v.hi);
  float2 b = xi_max(a.lo, a.hi);
  return b.x > b.y ? b.x : b.y;
}

// Each ray's permuted axes (xi_permute_axes): kz 0: (x, y, z) → (y, z, x); 1: → (z, x, y); 2: as is.
#define XI_PX(x, y, z) select(select(x, z, kz1), y, kz0)
#define XI_PY(x, y, z) select(select(y, x, kz1), z, kz0)
#define XI_PZ(x, y, z) select(select(z, y, kz1), x, kz0)
// Lane c of node n's bound `lo` (lo x: 0, lo y: 2, lo z: 4) or of the one across (lo + 1), the
// nearer per ray by `back` (its direction is negative on that axis), or the farther; `near` is the
// packet's near plane where its rays share it.
#define XI_NEAR_PLANE(c, lo, back, near) \
  (shared ? (float8)n->bounds[near].c : select((float8)n->bounds[lo].c, (float8)n->bounds[(lo) + 1].c, back))
#define XI_FAR_PLANE(c, lo, back, near) \
  (shared ? (float8)n->bounds[(near) ^ 1].c : select((float8)n->bounds[(lo) + 1].c, (float8)n->bounds[lo].c, back))
// Child `k` (lane `c`: s0 … s7) of node n against the packet, as xi_trace's slab test per ray; sets
// bit k of `hits` and the nearest entry distance of the rays that enter it.
#define XI_PACKET_CHILD(k, c)                                                                             \
  {                                                                                                       \
    float8 tn = xi_max(xi_max((XI_NEAR_PLANE(c, 0, back_x, near_x) - ox) * inv_x,                         \
                              (XI_NEAR_PLANE(c, 2, back_y, near_y) - oy) * inv_y),                        \
                       xi_max((XI_NEAR_PLANE(c, 4, back_z, near_z) - oz) * inv_z, (float8)0.0f));         \
    float8 tf = xi_min(xi_min((XI_FAR_PLANE(c, 0, back_x, near_x) - ox) * inv_x,                          \
                              (XI_FAR_PLANE(c, 2, back_y, near_y) - oy) * inv_y),                         \
                       xi_min((XI_FAR_PLANE(c, 4, back_z, near_z) - oz) * inv_z, best));                  \
    int8 enter = xi_less_equal(tn, tf * XI_BOX_SLACK);                                                    \
    if (xi_lane_bits8(enter)) {                                                                           \
      hits |= 1u << (k);                                                                                  \
      t_enter[k] = xi_lanes_min8(select((float8)INFINITY, tn, enter));                                   \
    }                                                                                                     \
  }
// Vertex `vertex` of triangle j of the block at `coord`, axes permuted as each ray's (with `shared`,
// the packet's permutation to_x, to_y, kz) and relative to its origin.
#define XI_VERTEX(axis, vertex) ((float8)coord[((axis) * 3 + (vertex)) * 4 + j])
#define XI_PACKET_VERTEX(vertex, px, py, pz)                                                              \
  float8 px = (shared ? XI_VERTEX(to_x, vertex)                                                           \
                      : XI_PX(XI_VERTEX(0, vertex), XI_VERTEX(1, vertex), XI_VERTEX(2, vertex))) - o_x;   \
  float8 py = (shared ? XI_VERTEX(to_y, vertex)                                                           \
                      : XI_PY(XI_VERTEX(0, vertex), XI_VERTEX(1, vertex), XI_VERTEX(2, vertex))) - o_y;   \
  float8 pz = (shared ? XI_VERTEX(kz_shared, vertex)                                                      \
                      : XI_PZ(XI_VERTEX(0, vertex), XI_VERTEX(1, vertex), XI_VERTEX(2, vertex))) - o_z

// The traversal, built four times: `shared` says the eight rays share their permutation and near
// planes; `any_hit`, as xi_trace's, that a ray is done at its first hit before its tmax.
static inline XI_INLINE void xi_trace_packet8_as(__global const BvhNode8* nodes, __global const TriBlock* blocks,
                                                 float8 ox, float8 oy, float8 oz, float8 dx, float8 dy, float8 dz,
                                                 float8 tmax, int8 kz, bool shared, bool any_hit, float8* t,
                                                 float8* u, float8* v, uint8* tri) {
  const int8 kz0 = kz == (int8)0, kz1 = kz == (int8)1;
  const int kz_shared = kz.s0, to_x = xi_axis_to_x(kz_shared), to_y = xi_axis_to_y(kz_shared);
  const float8 inv_x = select((float8)1e30f, 1.0f / dx, dx != 0.0f), inv_y = select((float8)1e30f, 1.0f / dy, dy != 0.0f),
               inv_z = select((float8)1e30f, 1.0f / dz, dz != 0.0f);
  const int8 back_x = inv_x < 0.0f, back_y = inv_y < 0.0f, back_z = inv_z < 0.0f;
  const int near_x = back_x.s0 ? 1 : 0, near_y = back_y.s0 ? 3 : 2, near_z = back_z.s0 ? 5 : 4;
  const float8 o_x = XI_PX(ox, oy, oz), o_y = XI_PY(ox, oy, oz), o_z = XI_PZ(ox, oy, oz);
  const float8 sz = 1.0f / XI_PZ(dx, dy, dz);
  const float8 sx = XI_PX(dx, dy, dz) * sz, sy = XI_PY(dx, dy, dz) * sz;

  uint2 stack[XI_BVH_STACK];  // (entry, the nearest distance at which a ray enters it)
  uint sp = 0u, entry = 0u;
  float8 best = tmax, best_u = 0.0f, best_v = 0.0f;
  uint8 found = (uint8)XI_NO_HIT;
  for (;;) {
    if (entry & XI_BVH_LEAF) {
      const uint first = entry & XI_BVH_FIRST_MASK, end = first + 1u + ((entry >> 27) & 15u);
      for (uint k = first; k < end; ++k) {
        __global const float* coord = (__global const float*)blocks[k].coord;  // [axis][vertex][triangle]
        for (uint j = 0u; j < 4u && blocks[k].tri[j] != XI_NO_HIT; ++j) {  // unused lanes come last
          XI_PACKET_VERTEX(0, ax, ay, az);
          XI_PACKET_VERTEX(1, bx, by, bz);
          XI_PACKET_VERTEX(2, cx, cy, cz);
          float8 e0, e1, e2, t_det;
          XI_SHEARED_EDGES(sx, sy, sz, ax, ay, az, bx, by, bz, cx, cy, cz, e0, e1, e2, t_det);
          // xi_intersect_block's candidate test, then xi_edge_hit's, per ray.
          const float8 zero = 0.0f;
          int8 mixed = (xi_less4(e0, zero) | xi_less4(e1, zero) | xi_less4(e2, zero)) &
                       (xi_greater4(e0, zero) | xi_greater4(e1, zero) | xi_greater4(e2, zero));
          float8 det = e0 + e1 + e2;
          float8 tt = t_det / det;
          int8 hit = xi_greater4(tt, zero) & xi_less4(tt, best) & ~mixed;
          if (xi_lane_bits8(hit) == 0u) continue;
          float8 t_err_det = XI_T_ERROR_DET_OF(xi_max, sz, ax, ay, az, bx, by, bz, cx, cy, cz, e0, e1, e2);
          hit &= xi_greater4(tt, t_err_det / fabs(det));
          found = select(found, (uint8)blocks[k].tri[j], hit);
          if (!any_hit) {
            best = select(best, tt, hit);
            best_u = select(best_u, e1 / det, hit);
            best_v = select(best_v, e2 / det, hit);
          } else {  // a ray that is done enters no box and hits no triangle again
            best = select(best, (float8)(-INFINITY), hit);
            if (xi_lane_bits8(found != (uint8)XI_NO_HIT) == 0xffu) {
              *tri = found;
              return;
            }
          }
        }
      }
    } else {
      __global const BvhNode8* n = nodes + entry;
      uint hits = 0u;
      float t_enter[8];
      XI_PACKET_CHILD(0, s0) XI_PACKET_CHILD(1, s1) XI_PACKET_CHILD(2, s2) XI_PACKET_CHILD(3, s3)
      XI_PACKET_CHILD(4, s4) XI_PACKET_CHILD(5, s5) XI_PACKET_CHILD(6, s6) XI_PACKET_CHILD(7, s7)
      if (hits != 0u && (hits & (hits - 1u)) == 0u) {  // one child: go there
        entry = n->child[31 - clz(hits)];
        continue;
      }
      // Nearest on top for closest hits, any order for any hits, as xi_trace pushes.
      const uint base = sp;
      for (uint k = 0u; k < 8u; ++k) {
        if (!(hits & (1u << k))) continue;
        uint j = sp++;
        for (; !any_hit && j > base && as_float(stack[j - 1u].y) < t_enter[k]; --j) stack[j] = stack[j - 1u];
        stack[j] = make_uint2(n->child[k], as_uint(t_enter[k]));
      }
    }
    // Pop the nearest entry that some ray enters before its best hit so far.
    const float farthest = xi_lanes_max8(best) * XI_BOX_SLACK;
    for (;;) {
      if (sp == 0u) {
        *t = best, *u = best_u, *v = best_v, *tri = found;
        return;
      }
      --sp;
      if (as_float(stack[sp].y) <= farthest) break;
    }
    entry = stack[sp].x;
  }
}
#undef XI_PACKET_VERTEX
#undef XI_VERTEX
#undef XI_PACKET_CHILD
#undef XI_FAR_PLANE
#undef XI_NEAR_PLANE
#undef XI_PZ
#undef XI_PY
#undef XI_PX

// Eight rays (origins o, unit directions d, lane k = ray k) as xi_trace takes one: closest hits in
// (0, tmax) or, with any_hit, whether there is one. Chooses the traversal for the rays' permutations
// (as xi_ray_shear chooses them) and the signs of their directions (xi_trace's near planes).
static inline XI_INLINE void xi_packet8(__global const BvhNode8* nodes, __global const TriBlock* blocks, float8 ox,
                                        float8 oy, float8 oz, float8 dx, float8 dy, float8 dz, float8 tmax,
                                        bool any_hit, float8* t, float8* u, float8* v, uint8* tri) {
  const float8 adx = fabs(dx), ady = fabs(dy), adz = fabs(dz);
  const int8 kz = select(select((int8)2, (int8)1, ady > adz), select((int8)2, (int8)0, adx > adz), adx > ady);
  const uint back_x = xi_lane_bits8(dx < 0.0f), back_y = xi_lane_bits8(dy < 0.0f), back_z = xi_lane_bits8(dz < 0.0f);
  if (xi_lane_bits8(kz != (int8)kz.s0) == 0u && (back_x == 0u || back_x == 0xffu) &&
      (back_y == 0u || back_y == 0xffu) && (back_z == 0u || back_z == 0xffu))
    xi_trace_packet8_as(nodes, blocks, ox, oy, oz, dx, dy, dz, tmax, kz, true, any_hit, t, u, v, tri);
  else
    xi_trace_packet8_as(nodes, blocks, ox, oy, oz, dx, dy, dz, tmax, kz, false, any_hit, t, u, v, tri);
}

// Closest hits of eight rays in (0, ∞): sets *t, *u, *v and *tri per lane as xi_trace would (tri
// XI_NO_HIT for a miss).
static inline void xi_trace_packet8(__global const BvhNode8* nodes, __global const TriBlock* blocks, float8 ox,
                                    float8 oy, float8 oz, float8 dx, float8 dy, float8 dz, float8* t, float8* u,
                                    float8* v, uint8* tri) {
  xi_packet8(nodes, blocks, ox, oy, oz, dx, dy, dz, (float8)INFINITY, false, t, u, v, tri);
}

// The rays of eight (tmax per ray) that hit something before their tmax, as bits (lane k: bit k),
// each as xi_trace's any-hit query finds.
static inline uint xi_occluded_packet8(__global const BvhNode8* nodes, __global const TriBlock* blocks, float8 ox,
                                       float8 oy, float8 oz, float8 dx, float8 dy, float8 dz, float8 tmax) {
  float8 t, u, v;
  uint8 tri;
  xi_packet8(nodes, blocks, ox, oy, oz, dx, dy, dz, tmax, true, &t, &u, &v, &tri);
  return xi_lane_bits8(tri != (uint8)XI_NO_HIT);
}
#endif

#ifdef __OPENCL_VERSION__
#pragma OPENCL FP_CONTRACT DEFAULT
#endif

#endif
