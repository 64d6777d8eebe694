// The watertight ray/triangle test (Woop, Benthin and Wald 2013) with a bound on the rounding error
// of t, in three forms that find bitwise the same hits: one ray and one triangle (the reference the
// host's tests use), one ray and a leaf's block of 4 or 8 triangles (xi_trace), and a packet of
// rays and one triangle (ray packets, 8-wide trees only).
#ifndef XI_TRIANGLE_H
#define XI_TRIANGLE_H
#include "compat.h"
#include "layout.h"

// Watertightness needs every product rounded on its own: the edge function of a shared edge is
// bx·cy − by·cx in one triangle and exactly its negation, cx·by − cy·bx, in the other, which a
// fused multiply-add breaks (it rounds one product, not the other). OpenCL contracts a·b + c by
// default (and xi builds with -cl-mad-enable), which let rays aimed at the edges and vertices of a
// closed mesh escape it (HardCases.TenMillionRaysFromInsideClosedMeshesNoneEscapes). Restored at
// the end of this file.
#ifdef __OPENCL_VERSION__
#pragma OPENCL FP_CONTRACT OFF
#endif

// Per-ray constants of the test: the axis of largest |d| becomes z (a cyclic permutation of the
// axes, the same for every triangle the ray meets), then a shear makes the ray the +z axis so the
// edge functions are evaluated exactly as 2D cross products. (Woop et al. also swap x and y when
// d.z < 0 to keep the winding; that negates all three edge functions and their sum alike, which
// changes neither the hit test nor t, u, v.)
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

// The arithmetic all three forms share, written once for scalars and vector lanes alike (OpenCL C
// has no templates), so they perform the same operations in the same order.
//
// XI_SHEAR_EDGES: from the vertices a, b, c relative to the ray's origin, axes permuted as the
// ray's, the shear that makes the ray the +z axis (x and y in place), the edge functions e0, e1, e2
// and t·det.
#define XI_SHEAR_EDGES(sx, sy, sz, ax, ay, az, bx, by, bz, cx, cy, cz, e0, e1, e2, t_det) \
  ax = ax - (sx) * az, ay = ay - (sy) * az;                                                \
  bx = bx - (sx) * bz, by = by - (sy) * bz;                                                \
  cx = cx - (sx) * cz, cy = cy - (sy) * cz;                                                \
  e0 = bx * cy - by * cx;                                                                  \
  e1 = cx * ay - cy * ax;                                                                  \
  e2 = ax * by - ay * bx;                                                                  \
  t_det = e0 * (sz) * az + e1 * (sz) * bz + e2 * (sz) * cz

// XI_T_ERROR_DET: the bound on the rounding error of t, times |det| (Pharr, Jakob and Humphreys,
// Physically Based Rendering 4th ed., "Managing Rounding Error"), into t_err_det, from the largest
// magnitudes of the sheared coordinates (x, y; z scaled by sz) and of the edge functions; T is the
// lane type and `maxf` its max. A hit within it may be the surface the ray was spawned from, so it
// is refused: with origins offset by their own error bounds (spawn.h), no ray re-hits its surface,
// at any scale, without an epsilon.
#define XI_T_ERROR_DET(T, maxf, sz, ax, ay, az, bx, by, bz, cx, cy, cz, e0, e1, e2, t_err_det)              \
  {                                                                                                         \
    T max_x = maxf(maxf(fabs(ax), fabs(bx)), fabs(cx)), max_y = maxf(maxf(fabs(ay), fabs(by)), fabs(cy));   \
    T max_z = maxf(maxf(fabs((sz) * az), fabs((sz) * bz)), fabs((sz) * cz));                                \
    T max_e = maxf(maxf(fabs(e0), fabs(e1)), fabs(e2));                                                     \
    t_err_det = 3.0f * (XI_GAMMA(3) * max_e * max_z +                                                       \
                        2.0f * (XI_GAMMA(2) * max_x * max_y + XI_GAMMA(5) * (max_y + max_z) * max_x +        \
                                XI_GAMMA(5) * (max_x + max_z) * max_y) * max_z +                            \
                        XI_GAMMA(3) * max_z * max_e);                                                       \
  }

// --- one ray, one triangle ---------------------------------------------------------------------

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

// Returns true and sets *t, *u, *v (barycentrics of p1 and p2) for a hit in (0, tmax).
static inline bool xi_intersect_triangle(RayShear s, float3 p0, float3 p1, float3 p2, float tmax, float* t,
                                         float* u, float* v) {
  float3 a = xi_permute_axes(p0, s.kz) - s.o, b = xi_permute_axes(p1, s.kz) - s.o,
         c = xi_permute_axes(p2, s.kz) - s.o;
  float ax = a.x, ay = a.y, az = a.z, bx = b.x, by = b.y, bz = b.z, cx = c.x, cy = c.y, cz = c.z;
  float e0, e1, e2, t_det;
  XI_SHEAR_EDGES(s.sx, s.sy, s.sz, ax, ay, az, bx, by, bz, cx, cy, cz, e0, e1, e2, t_det);
  float t_err_det;
  XI_T_ERROR_DET(float, fmax, s.sz, ax, ay, az, bx, by, bz, cx, cy, cz, e0, e1, e2, t_err_det)
  return xi_edge_hit(e0, e1, e2, t_det, t_err_det, tmax, t, u, v);
}

// --- one ray, a leaf's blocks ------------------------------------------------------------------

// The test on the four triangles of a block at once, or on two blocks' eight where the BVH is 8
// wide (CPU devices: AVX tests eight lanes in one operation as fast as four, and a leaf holds at
// most two blocks), up to the edge functions and t·det.
#if XI_BVH_WIDTH == 8
#define XI_BLOCK_LANES 8
typedef float8 BlockFloat;
typedef int8 BlockMask;
static inline uint xi_block_lane_bits(BlockMask m) { return xi_lane_bits8(m); }
#else
#define XI_BLOCK_LANES 4
typedef float4 BlockFloat;
typedef int4 BlockMask;
static inline uint xi_block_lane_bits(BlockMask m) { return xi_lane_bits(m); }
#endif

// What xi_edge_hit needs to finish a lane as xi_intersect_triangle would.
typedef struct {
  BlockFloat e0, e1, e2, t_det, t_err_det;
} BlockEdges;

// Coordinate `axis` of vertex j of the blocks' triangles, lane by lane (b1 is read only when 8 wide).
static inline BlockFloat xi_block_coord(__global const TriBlock* b0, __global const TriBlock* b1, int axis, int j) {
#if XI_BLOCK_LANES == 8
  return (float8)(b0->coord[axis][j], b1->coord[axis][j]);
#else
  (void)b1;
  return b0->coord[axis][j];
#endif
}

// Vertex j of the blocks' triangles, axes permuted as the ray's and relative to its origin. The
// permutation is an index per axis (the same for every block the ray meets), not a choice per
// coordinate.
static inline void xi_block_vertex(__global const TriBlock* b0, __global const TriBlock* b1, int j, RayShear s,
                                   BlockFloat* x, BlockFloat* y, BlockFloat* z) {
  *x = xi_block_coord(b0, b1, xi_axis_to_x(s.kz), j) - s.o.x;
  *y = xi_block_coord(b0, b1, xi_axis_to_y(s.kz), j) - s.o.y;
  *z = xi_block_coord(b0, b1, s.kz, j) - s.o.z;
}

// The lanes of the blocks that the ray hits in (t error, tmax), as bits; *e gets the lanes' edge
// functions, t·det and t's error bound (set whenever a lane hits), for xi_edge_hit to finish a
// lane. (det = 0 gives t = ±inf or NaN, which fails the tests.) On a CPU (XI_CPU_DEVICE, set by
// the host) the bound is computed only once a lane has passed the cheaper tests, as most blocks a
// ray visits it misses. A GPU warp computes it whenever any of its rays needs it, so there the early
// exit would only be one more branch. Hits are bitwise the same either way.
static inline uint xi_intersect_block(RayShear s, __global const TriBlock* b0, __global const TriBlock* b1,
                                      float tmax, BlockEdges* e) {
  BlockFloat ax, ay, az, bx, by, bz, cx, cy, cz;
  xi_block_vertex(b0, b1, 0, s, &ax, &ay, &az);
  xi_block_vertex(b0, b1, 1, s, &bx, &by, &bz);
  xi_block_vertex(b0, b1, 2, s, &cx, &cy, &cz);
  XI_SHEAR_EDGES(s.sx, s.sy, s.sz, ax, ay, az, bx, by, bz, cx, cy, cz, e->e0, e->e1, e->e2, e->t_det);
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
  XI_T_ERROR_DET(BlockFloat, xi_max, s.sz, ax, ay, az, bx, by, bz, cx, cy, cz, e->e0, e->e1, e->e2, e->t_err_det)
  return xi_block_lane_bits(candidate & xi_greater4(t, e->t_err_det / fabs(det)));
}

// --- a packet of rays, one triangle ---------------------------------------------------------------

#if XI_BVH_WIDTH == 8
// A packet's lanes, one ray each: XI_PACKET_WIDTH of them (layout.h).
#if XI_PACKET_WIDTH == 16
typedef float16 PacketFloat;
typedef int16 PacketInt;
typedef uint16 PacketUint;
#define xi_as_packet_float as_float16
static inline uint xi_packet_bits(PacketInt m) { return xi_lane_bits16(m); }
#else
typedef float8 PacketFloat;
typedef int8 PacketInt;
typedef uint8 PacketUint;
#define xi_as_packet_float as_float8
static inline uint xi_packet_bits(PacketInt m) { return xi_lane_bits8(m); }
#endif
#define XI_PACKET_ALL ((1u << XI_PACKET_WIDTH) - 1u)

// xi_ray_shear's constants for a packet's rays (lane k = ray k), each with its own axis permutation.
// Where all share it, as neighbouring camera rays do, a vertex's coordinates are loaded by
// the packet's permutation as indices, as for one ray, instead of chosen per lane by selects.
typedef struct {
  PacketInt kz0, kz1;  // the lanes whose ray permutes with kz 0, with kz 1 (kz 2: unchanged)
  bool same_axes;      // all the rays permute their axes alike: by to_x, to_y, kz
  int to_x, to_y, kz;  // lane 0's permutation
  PacketFloat ox, oy, oz;  // the origins, permuted
  PacketFloat sx, sy, sz;
} RayShearPacket;

// The rays' permuted axes, lane by lane (xi_permute_axes with each lane's kz).
static inline PacketFloat xi_permuted_x(const RayShearPacket* s, PacketFloat x, PacketFloat y, PacketFloat z) {
  return select(select(x, z, s->kz1), y, s->kz0);
}
static inline PacketFloat xi_permuted_y(const RayShearPacket* s, PacketFloat x, PacketFloat y, PacketFloat z) {
  return select(select(y, x, s->kz1), z, s->kz0);
}
static inline PacketFloat xi_permuted_z(const RayShearPacket* s, PacketFloat x, PacketFloat y, PacketFloat z) {
  return select(select(z, y, s->kz1), x, s->kz0);
}

static inline XI_INLINE RayShearPacket xi_ray_shear_packet(PacketFloat ox, PacketFloat oy, PacketFloat oz,
                                                           PacketFloat dx, PacketFloat dy, PacketFloat dz) {
  const PacketFloat adx = fabs(dx), ady = fabs(dy), adz = fabs(dz);
  const PacketInt kz =
      select(select((PacketInt)2, (PacketInt)1, ady > adz), select((PacketInt)2, (PacketInt)0, adx > adz), adx > ady);
  RayShearPacket s;
  s.kz0 = kz == (PacketInt)0;
  s.kz1 = kz == (PacketInt)1;
  s.kz = kz.s0;
  s.same_axes = xi_packet_bits(kz != (PacketInt)s.kz) == 0u;
  s.to_x = xi_axis_to_x(s.kz);
  s.to_y = xi_axis_to_y(s.kz);
  s.ox = xi_permuted_x(&s, ox, oy, oz);
  s.oy = xi_permuted_y(&s, ox, oy, oz);
  s.oz = xi_permuted_z(&s, ox, oy, oz);
  s.sz = 1.0f / xi_permuted_z(&s, dx, dy, dz);
  s.sx = xi_permuted_x(&s, dx, dy, dz) * s.sz;
  s.sy = xi_permuted_y(&s, dx, dy, dz) * s.sz;
  return s;
}

// Coordinate `axis` of vertex `vertex` of triangle j of a block, for all the packet's rays.
static inline XI_INLINE PacketFloat xi_packet_coord(__global const TriBlock* block, int axis, int vertex, uint j) {
  __global const float* coord = (__global const float*)block->coord;  // [axis][vertex][triangle]
  return (PacketFloat)(coord[(axis * 3 + vertex) * 4 + j]);
}

// Vertex `vertex` of triangle j of a block, for each ray: axes permuted as its own (`same_axes`: as
// lane 0's, which all share, by index) and relative to its origin.
static inline XI_INLINE void xi_packet_vertex(__global const TriBlock* block, uint j, int vertex,
                                              const RayShearPacket* s, bool same_axes, PacketFloat* x, PacketFloat* y,
                                              PacketFloat* z) {
  if (same_axes) {
    *x = xi_packet_coord(block, s->to_x, vertex, j) - s->ox;
    *y = xi_packet_coord(block, s->to_y, vertex, j) - s->oy;
    *z = xi_packet_coord(block, s->kz, vertex, j) - s->oz;
  } else {
    const PacketFloat vx = xi_packet_coord(block, 0, vertex, j), vy = xi_packet_coord(block, 1, vertex, j),
                      vz = xi_packet_coord(block, 2, vertex, j);
    *x = xi_permuted_x(s, vx, vy, vz) - s->ox;
    *y = xi_permuted_y(s, vx, vy, vz) - s->oy;
    *z = xi_permuted_z(s, vx, vy, vz) - s->oz;
  }
}

// Triangle j of a block against a packet's rays, each as xi_intersect_block's test and then xi_edge_hit's
// finish would find it: the lanes whose ray hits it in (t error, tmax), with t, u, v there. The
// bound is computed only once some ray has passed the cheaper tests (packets run on CPUs only).
static inline XI_INLINE PacketInt xi_intersect_packet(const RayShearPacket* s, bool same_axes,
                                                      __global const TriBlock* block, uint j, PacketFloat tmax,
                                                      PacketFloat* t, PacketFloat* u, PacketFloat* v) {
  PacketFloat ax, ay, az, bx, by, bz, cx, cy, cz, e0, e1, e2, t_det;
  xi_packet_vertex(block, j, 0, s, same_axes, &ax, &ay, &az);
  xi_packet_vertex(block, j, 1, s, same_axes, &bx, &by, &bz);
  xi_packet_vertex(block, j, 2, s, same_axes, &cx, &cy, &cz);
  XI_SHEAR_EDGES(s->sx, s->sy, s->sz, ax, ay, az, bx, by, bz, cx, cy, cz, e0, e1, e2, t_det);
  const PacketFloat zero = 0.0f;
  PacketInt mixed = (xi_less4(e0, zero) | xi_less4(e1, zero) | xi_less4(e2, zero)) &
                    (xi_greater4(e0, zero) | xi_greater4(e1, zero) | xi_greater4(e2, zero));
  PacketFloat det = e0 + e1 + e2;
  *t = t_det / det;
  PacketInt hit = xi_greater4(*t, zero) & xi_less4(*t, tmax) & ~mixed;
  if (xi_packet_bits(hit) == 0u) return hit;
  PacketFloat t_err_det;
  XI_T_ERROR_DET(PacketFloat, xi_max, s->sz, ax, ay, az, bx, by, bz, cx, cy, cz, e0, e1, e2, t_err_det)
  *u = e1 / det;
  *v = e2 / det;
  return hit & xi_greater4(*t, t_err_det / fabs(det));
}
#endif

#undef XI_T_ERROR_DET
#undef XI_SHEAR_EDGES

#ifdef __OPENCL_VERSION__
#pragma OPENCL FP_CONTRACT DEFAULT
#endif

#endif
