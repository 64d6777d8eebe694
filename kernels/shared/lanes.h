// Lane types for the sampling and shading code. generate and shade take XI_LANES paths per work
// item on CPU devices, where PoCL runs work items one after another and only vector arithmetic
// fills the vector units: 16 (float16) on CPUs with AVX2 or AVX-512, else 8; 1 on GPUs, whose hardware
// already gives each path its own lane. The sampler, camera, warps, BSDFs, light sampling and spawn
// offsets they call are written once on these types: with XI_LANES 1 (GPU builds, the tool
// kernels, the host's tests) they are float, uint, bool, float2 and float3; with 8, float8, uint8,
// int8 masks and structs of float8 for 2D and 3D values (with 16, the same of float16).
//
// Generic code keeps to what both forms accept: arithmetic and comparison operators, built-ins
// such as sqrt and fmax, `m ? a : b` on xfloat/xuint with constants cast to the lane type, the
// xi_*3 functions below for 3D values, XI_ANY for a mask that steers a loop, and the xi_gather_*
// loads for memory indexed per path.
#ifndef XI_LANES_H
#define XI_LANES_H
#include "compat.h"

#ifndef XI_LANES
#define XI_LANES 1
#endif

#if XI_LANES == 8 || XI_LANES == 16

#if XI_LANES == 16
typedef float16 xfloat;
typedef uint16 xuint;
typedef int16 xint;
typedef int16 xmask;  // a comparison's result: −1 in a lane where true, 0 where false
#define xi_to_float(v) convert_float16(v)
#define convert_xint(v) convert_int16(v)
#define convert_xuint(v) convert_uint16(v)
#define xi_as_uint(v) as_uint16(v)
#define xi_as_int(v) as_int16(v)
#define xi_as_float(v) as_float16(v)
#define XI_LANE_INDEX ((uint16)(0u, 1u, 2u, 3u, 4u, 5u, 6u, 7u, 8u, 9u, 10u, 11u, 12u, 13u, 14u, 15u))
#define XI_VLOAD vload16
#define XI_VSTORE vstore16
#define xi_mask_bits(m) xi_lane_bits16(m)  // bit k: lane k is true
#else
typedef float8 xfloat;
typedef uint8 xuint;
typedef int8 xint;
typedef int8 xmask;  // a comparison's result: −1 in a lane where true, 0 where false
#define xi_to_float(v) convert_float8(v)
#define convert_xint(v) convert_int8(v)
#define convert_xuint(v) convert_uint8(v)
#define xi_as_uint(v) as_uint8(v)
#define xi_as_int(v) as_int8(v)
#define xi_as_float(v) as_float8(v)
#define XI_LANE_INDEX ((uint8)(0u, 1u, 2u, 3u, 4u, 5u, 6u, 7u))
#define XI_VLOAD vload8
#define XI_VSTORE vstore8
#define xi_mask_bits(m) xi_lane_bits8(m)
#endif
typedef struct {
  xfloat x, y;
} xfloat2;
typedef struct {
  xfloat x, y, z;
} xfloat3;

#define XI_ANY(m) any(m)
#define XI_TRUE ((xmask)-1)
#define XI_FALSE ((xmask)0)
// Every function here is forced inline: left as calls, the structs of float8 went through memory.
// Lane loops: unrolled, so every lane access has a constant index and stays in registers (left as
// a loop, PoCL went through the stack for each lane).
#define XI_FOR_LANES(k) _Pragma("unroll") for (int k = 0; k < XI_LANES; ++k)

static inline XI_INLINE xfloat2 make_xfloat2(xfloat x, xfloat y) {
  xfloat2 v;
  v.x = x;
  v.y = y;
  return v;
}
static inline XI_INLINE xfloat3 make_xfloat3(xfloat x, xfloat y, xfloat z) {
  xfloat3 v;
  v.x = x;
  v.y = y;
  v.z = z;
  return v;
}
static inline XI_INLINE xfloat3 xi_add3(xfloat3 a, xfloat3 b) { return make_xfloat3(a.x + b.x, a.y + b.y, a.z + b.z); }
static inline XI_INLINE xfloat3 xi_sub3(xfloat3 a, xfloat3 b) { return make_xfloat3(a.x - b.x, a.y - b.y, a.z - b.z); }
static inline XI_INLINE xfloat3 xi_mul3(xfloat3 a, xfloat3 b) { return make_xfloat3(a.x * b.x, a.y * b.y, a.z * b.z); }
static inline XI_INLINE xfloat3 xi_scale3(xfloat3 a, xfloat s) { return make_xfloat3(a.x * s, a.y * s, a.z * s); }
static inline XI_INLINE xfloat3 xi_neg3(xfloat3 a) { return make_xfloat3(-a.x, -a.y, -a.z); }
static inline XI_INLINE xfloat3 xi_abs3(xfloat3 a) { return make_xfloat3(fabs(a.x), fabs(a.y), fabs(a.z)); }
static inline XI_INLINE xfloat xi_dot3(xfloat3 a, xfloat3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
static inline XI_INLINE xfloat3 xi_cross3(xfloat3 a, xfloat3 b) {
  return make_xfloat3(a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x);
}
static inline XI_INLINE xfloat3 xi_div3(xfloat3 a, xfloat s) { return make_xfloat3(a.x / s, a.y / s, a.z / s); }
static inline XI_INLINE xfloat xi_length3(xfloat3 a) { return sqrt(xi_dot3(a, a)); }
static inline XI_INLINE xfloat3 xi_normalize3(xfloat3 a) { return xi_scale3(a, 1.0f / xi_length3(a)); }
static inline XI_INLINE xfloat3 xi_select3(xmask m, xfloat3 a, xfloat3 b) {
  return make_xfloat3(m ? a.x : b.x, m ? a.y : b.y, m ? a.z : b.z);
}
static inline XI_INLINE xfloat3 xi_splat3(float3 v) { return make_xfloat3((xfloat)v.x, (xfloat)v.y, (xfloat)v.z); }

// Loads of per-path memory: lane k reads element i[k] of global, constant (XI_TABLE) or local memory.
#define XI_GATHER(name, space, type, lane_type)                          \
  static inline XI_INLINE lane_type name(space const type* p, xuint i) { \
    uint idx[XI_LANES];                                                  \
    type v[XI_LANES];                                                    \
    XI_VSTORE(i, 0, idx);                                                \
    XI_FOR_LANES(k) v[k] = p[idx[k]];                                    \
    return XI_VLOAD(0, v);                                               \
  }
XI_GATHER(xi_gather_float, __global, float, xfloat)
XI_GATHER(xi_gather_uint, __global, uint, xuint)
XI_GATHER(xi_gather_table, __constant, float, xfloat)
XI_GATHER(xi_local_gather_uint, __local, uint, xuint)
// The x, y, z and w of float4 elements, each as lane vectors (XI_TRANSPOSE4).
static inline XI_INLINE void xi_gather_columns(__global const float4* p, xuint i, xfloat* x, xfloat* y, xfloat* z,
                                               xfloat* w) {
  uint idx[XI_LANES];
  float4 r[XI_LANES];
  XI_VSTORE(i, 0, idx);
  XI_FOR_LANES(k) r[k] = p[idx[k]];
#if XI_HAS_SHUFFLE
  XI_COLUMNS(XI_LANES, r, *x, *y, *z, *w)
#else
  float cx[XI_LANES], cy[XI_LANES], cz[XI_LANES], cw[XI_LANES];
  XI_FOR_LANES(k) cx[k] = r[k].x, cy[k] = r[k].y, cz[k] = r[k].z, cw[k] = r[k].w;
  *x = XI_VLOAD(0, cx), *y = XI_VLOAD(0, cy), *z = XI_VLOAD(0, cz), *w = XI_VLOAD(0, cw);
#endif
}
// xyz of float4 elements, and their w.
static inline XI_INLINE xfloat3 xi_gather_xyz(__global const float4* p, xuint i, xfloat* w) {
  xfloat x, y, z, ww;
  xi_gather_columns(p, i, &x, &y, &z, &ww);
  if (w) *w = ww;
  return make_xfloat3(x, y, z);
}
// The four words of uint4 elements.
static inline XI_INLINE void xi_gather_uint4(__global const uint4* p, xuint i, xuint* x, xuint* y, xuint* z, xuint* w) {
#if XI_HAS_SHUFFLE  // shuffles move the bits as they are (small integers are denormal floats)
  xfloat a, b, c, d;
  xi_gather_columns((__global const float4*)p, i, &a, &b, &c, &d);
  *x = xi_as_uint(a), *y = xi_as_uint(b), *z = xi_as_uint(c), *w = xi_as_uint(d);
#else
  uint idx[XI_LANES], a[XI_LANES], b[XI_LANES], c[XI_LANES], d[XI_LANES];
  XI_VSTORE(i, 0, idx);
  XI_FOR_LANES(k) {
    const uint4 e = p[idx[k]];
    a[k] = e.x, b[k] = e.y, c[k] = e.z, d[k] = e.w;
  }
  *x = XI_VLOAD(0, a), *y = XI_VLOAD(0, b), *z = XI_VLOAD(0, c), *w = XI_VLOAD(0, d);
#endif
}
// Lane k's (xyz, w) as one float4, rows[k], for every lane.
static inline XI_INLINE void xi_lane_rows(xfloat3 v, xfloat w, float4* rows) {
#if XI_HAS_SHUFFLE
  xfloat a = v.x, b = v.y, c = v.z, d = w;
  XI_TRANSPOSE4(XI_LANES, a, b, c, d)
  XI_FOR_LANES(k) rows[k] = XI_ROW(XI_LANES, a, b, c, d, k);
#else
  float x[XI_LANES], y[XI_LANES], z[XI_LANES], ww[XI_LANES];
  XI_VSTORE(v.x, 0, x);
  XI_VSTORE(v.y, 0, y);
  XI_VSTORE(v.z, 0, z);
  XI_VSTORE(w, 0, ww);
  XI_FOR_LANES(k) rows[k] = (float4)(x[k], y[k], z[k], ww[k]);
#endif
}
// Stores (xyz, w) to element i[k] of the lanes where m is true.
static inline XI_INLINE void xi_scatter4(__global float4* p, xuint i, xfloat3 v, xfloat w, xmask m) {
  uint idx[XI_LANES];
  int on[XI_LANES];
  float4 rows[XI_LANES];
  XI_VSTORE(i, 0, idx);
  XI_VSTORE(m, 0, on);
  xi_lane_rows(v, w, rows);
  XI_FOR_LANES(k) if (on[k]) p[idx[k]] = rows[k];
}
// Stores (xyz, w) of lane k to element first + k, in the lanes where m is true: whole rows, without
// a test per lane, where every lane is (the slots a generate work item starts).
static inline XI_INLINE void xi_store4_from(__global float4* p, uint first, xfloat3 v, xfloat w, xmask m) {
  if (!all(m)) {
    xi_scatter4(p, first + XI_LANE_INDEX, v, w, m);
    return;
  }
  float4 rows[XI_LANES];
  xi_lane_rows(v, w, rows);
  XI_FOR_LANES(k) p[first + k] = rows[k];
}
// The number of lanes where m is true.
static inline XI_INLINE uint xi_count(xmask m) {
#if XI_LANES == 16
  int8 ones = (m & 1).lo + (m & 1).hi;
#else
  int8 ones = m & 1;
#endif
  int4 s4 = ones.lo + ones.hi;
  int2 s2 = s4.lo + s4.hi;
  return (uint)(s2.x + s2.y);
}
// Stores v[k] to element i[k] of the lanes where m is true, in global or local memory.
#define XI_SCATTER_UINT(name, space)                                            \
  static inline XI_INLINE void name(space uint* p, xuint i, xuint v, xmask m) { \
    uint idx[XI_LANES], vv[XI_LANES];                                           \
    int on[XI_LANES];                                                           \
    XI_VSTORE(i, 0, idx);                                                       \
    XI_VSTORE(v, 0, vv);                                                        \
    XI_VSTORE(m, 0, on);                                                        \
    XI_FOR_LANES(k) if (on[k]) p[idx[k]] = vv[k];                               \
  }
XI_SCATTER_UINT(xi_scatter_uint, __global)
XI_SCATTER_UINT(xi_local_scatter_uint, __local)
// Stores v of lane k to element first + k, in the lanes where m is true (as xi_store4_from).
static inline XI_INLINE void xi_store_uint_from(__global uint* p, uint first, xuint v, xmask m) {
  if (all(m))
    XI_VSTORE(v, 0, p + first);
  else
    xi_scatter_uint(p, first + XI_LANE_INDEX, v, m);
}
// The last lane where m is true (one is).
static inline XI_INLINE uint xi_last_lane(xmask m) { return 31u - clz(xi_mask_bits(m)); }
// Appends: stores to element i[k] of the lanes where m is true, i being xi_compact_index's. Every
// lane up to the last one on is written, in lane order: a lane that is off writes where the next
// lane on then writes its own (xi_compact_index gives it that element). So no lane waits on a test
// of its own, whose outcome no branch predictor could learn.
static inline XI_INLINE void xi_append4(__global float4* p, xuint i, xfloat3 v, xfloat w, xmask m) {
  if (!XI_ANY(m)) return;
  const uint last = xi_last_lane(m);
  uint idx[XI_LANES];
  float4 rows[XI_LANES];
  XI_VSTORE(i, 0, idx);
  xi_lane_rows(v, w, rows);
  XI_FOR_LANES(k) if ((uint)k <= last) p[idx[k]] = rows[k];
}
static inline XI_INLINE void xi_append_uint(__global uint* p, xuint i, xuint v, xmask m) {
  if (!XI_ANY(m)) return;
  const uint last = xi_last_lane(m);
  uint idx[XI_LANES], vv[XI_LANES];
  XI_VSTORE(i, 0, idx);
  XI_VSTORE(v, 0, vv);
  XI_FOR_LANES(k) if ((uint)k <= last) p[idx[k]] = vv[k];
}
// Where the lanes with m true go when appended, in lane order, to consecutive elements from `at`.
static inline XI_INLINE xuint xi_compact_index(uint at, xmask m) {
  int on[XI_LANES];
  uint idx[XI_LANES];
  XI_VSTORE(m, 0, on);
  XI_FOR_LANES(k) {
    idx[k] = at;
    at += on[k] & 1;
  }
  return XI_VLOAD(0, idx);
}

#elif XI_LANES == 1

typedef float xfloat;
typedef uint xuint;
typedef int xint;
typedef bool xmask;
typedef float2 xfloat2;
typedef float3 xfloat3;

#define xi_to_float(v) ((float)(v))
#define convert_xint(v) ((int)(v))
#define convert_xuint(v) ((uint)(v))
#define xi_as_uint(v) as_uint(v)
#define xi_as_int(v) as_int(v)
#define xi_as_float(v) as_float_i(v)
#define XI_ANY(m) (m)
#define XI_TRUE true
#define XI_FALSE false
#define XI_LANE_INDEX 0u
#define make_xfloat2 make_float2
#define make_xfloat3 make_float3

static inline xfloat3 xi_add3(xfloat3 a, xfloat3 b) { return a + b; }
static inline xfloat3 xi_sub3(xfloat3 a, xfloat3 b) { return a - b; }
static inline xfloat3 xi_mul3(xfloat3 a, xfloat3 b) { return a * b; }
static inline xfloat3 xi_scale3(xfloat3 a, xfloat s) { return a * s; }
static inline xfloat3 xi_neg3(xfloat3 a) { return -a; }
static inline xfloat3 xi_abs3(xfloat3 a) { return fabs(a); }
static inline xfloat xi_dot3(xfloat3 a, xfloat3 b) { return dot(a, b); }
static inline xfloat3 xi_cross3(xfloat3 a, xfloat3 b) { return cross(a, b); }
static inline xfloat3 xi_div3(xfloat3 a, xfloat s) { return a / s; }
static inline xfloat xi_length3(xfloat3 a) { return length(a); }
static inline xfloat3 xi_normalize3(xfloat3 a) { return normalize(a); }
static inline xfloat3 xi_select3(xmask m, xfloat3 a, xfloat3 b) { return m ? a : b; }
static inline xfloat3 xi_splat3(float3 v) { return v; }

static inline xfloat xi_gather_float(__global const float* p, xuint i) { return p[i]; }
static inline xuint xi_gather_uint(__global const uint* p, xuint i) { return p[i]; }
static inline xfloat xi_gather_table(__constant const float* p, xuint i) { return p[i]; }
static inline xfloat3 xi_gather_xyz(__global const float4* p, xuint i, xfloat* w) {
  float4 e = p[i];
  if (w) *w = e.w;
  return xyz(e);
}
static inline void xi_gather_uint4(__global const uint4* p, xuint i, xuint* x, xuint* y, xuint* z, xuint* w) {
  uint4 e = p[i];
  *x = e.x, *y = e.y, *z = e.z, *w = e.w;
}
#ifdef XI_DEVICE
static inline void xi_scatter4(__global float4* p, xuint i, xfloat3 v, xfloat w, xmask m) {
  if (m) p[i] = (float4)(v, w);
}
static inline void xi_scatter_uint(__global uint* p, xuint i, xuint v, xmask m) {
  if (m) p[i] = v;
}
static inline uint xi_count(xmask m) { return m ? 1u : 0u; }
static inline xuint xi_local_gather_uint(__local const uint* p, xuint i) { return p[i]; }
static inline void xi_local_scatter_uint(__local uint* p, xuint i, xuint v, xmask m) {
  if (m) p[i] = v;
}
static inline xuint xi_compact_index(uint at, xmask m) { return at; }
#define xi_append4 xi_scatter4
#define xi_append_uint xi_scatter_uint
static inline void xi_store4_from(__global float4* p, uint first, xfloat3 v, xfloat w, xmask m) {
  if (m) p[first] = (float4)(v, w);
}
static inline void xi_store_uint_from(__global uint* p, uint first, xuint v, xmask m) {
  if (m) p[first] = v;
}
#endif

#else
#error "XI_LANES must be 1, 8 or 16"
#endif

static inline xfloat xi_max3(xfloat3 v) { return fmax(v.x, fmax(v.y, v.z)); }
// a + (b − a) t
static inline xfloat3 xi_mix3(xfloat3 a, xfloat3 b, xfloat t) { return xi_add3(a, xi_scale3(xi_sub3(b, a), t)); }
// sqrt of a value that rounding may have pushed slightly below zero.
static inline xfloat xi_safe_sqrt(xfloat x) { return sqrt(fmax(x, (xfloat)0.0f)); }

// Exact unsigned division by a divisor that is the same for every lane, by a multiply and two
// shifts (Granlund and Montgomery 1994, "Division by invariant integers using multiplication",
// fig. 4.1): vector units have no integer divide, so `/` on lanes is one scalar division per lane.
// Right for every 32-bit n and every d ≥ 1.
typedef struct {
  uint multiplier, shift1, shift2;
} XiDivisor;
static inline XiDivisor xi_divisor(uint d) {
  const uint l = d > 1u ? 32u - clz(d - 1u) : 0u;  // ceil(log2 d)
  XiDivisor v;
  v.multiplier = (uint)(((((ulong)1 << l) - d) << 32) / d + 1u);
  v.shift1 = l > 0u ? 1u : 0u;
  v.shift2 = l > 0u ? l - 1u : 0u;
  return v;
}
static inline XI_INLINE xuint xi_div(xuint n, XiDivisor d) {
  const xuint t = mul_hi(n, (xuint)d.multiplier);
  return (t + ((n - t) >> d.shift1)) >> d.shift2;
}

// Field `field` of struct i of `buffer`, an array of layout.h's structs, in each lane: read at the
// field's place in struct 0 with a stride of one struct, so no offset is counted by hand. (Every
// such struct is a whole number of float4s.)
#define XI_GATHER_UINT_FIELD(buffer, i, field) \
  xi_gather_uint((__global const uint*)&(buffer)[0].field, (uint)(sizeof((buffer)[0]) / 4u) * (i))
#define XI_GATHER_XYZ_FIELD(buffer, i, field, w) \
  xi_gather_xyz((__global const float4*)&(buffer)[0].field, (uint)(sizeof((buffer)[0]) / 16u) * (i), (w))

#endif
