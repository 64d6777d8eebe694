// Lets the shared headers compile both as OpenCL C 1.2 (kernels) and as C++ (host and tests).
// On the host the OpenCL vector types map to GLM, so a test can call the very function a kernel
// calls. Shared headers stick to the common subset: no swizzles (use xyz()), constructors only
// through make_float2/3/4 and make_uint2, `static inline` functions, address-space qualifiers that
// vanish on host.
#ifndef XI_COMPAT_H
#define XI_COMPAT_H

#ifdef __OPENCL_VERSION__

#define XI_DEVICE 1
#define make_float2(x, y) ((float2)((x), (y)))
#define make_uint2(x, y) ((uint2)((x), (y)))
#define make_float3(x, y, z) ((float3)((x), (y), (z)))
#define make_float4(x, y, z, w) ((float4)((x), (y), (z), (w)))
#define xyz(v) ((v).xyz)
// Lane-wise comparisons: −1 where true, 0 where false.
#define xi_less4(a, b) ((a) < (b))
#define xi_greater4(a, b) ((a) > (b))
#define xi_less_equal(a, b) ((a) <= (b))
// Lane-wise min and max of vectors (any width) as one instruction each: OpenCL's fmin/fmax must
// return the number when the other operand is NaN, a compare and blend more on x86. (For operands
// that are never NaN.)
#define xi_min(a, b) select((b), (a), (a) < (b))
#define xi_max(a, b) select((b), (a), (a) > (b))

#else  // host C++

#include <cmath>
#include <cstdint>
#include <cstring>
#include <glm/glm.hpp>

#define __global
#define __local
#define __constant
#define __kernel

typedef uint32_t uint;
typedef glm::vec2 float2;
typedef glm::vec3 float3;
typedef glm::vec4 float4;
typedef glm::uvec2 uint2;
typedef glm::uvec4 uint4;
typedef glm::ivec3 int3;
typedef glm::ivec4 int4;
// Only for laying out buffers that kernels read as float8 (OpenCL aligns it to 32 bytes).
struct alignas(32) float8 {
  float s[8];
};

using glm::cross;
using glm::dot;
using glm::length;
using glm::normalize;
using std::cos;
using std::exp;
using std::fabs;
using std::floor;
using std::fmax;
using std::fmin;
using std::log;
using std::nextafter;
using std::sin;
using std::sqrt;
using std::acos;
using std::atan2;
using std::pow;

static inline float2 make_float2(float x, float y) { return float2(x, y); }
static inline uint2 make_uint2(uint x, uint y) { return uint2(x, y); }
static inline float3 make_float3(float x, float y, float z) { return float3(x, y, z); }
static inline float4 make_float4(float x, float y, float z, float w) { return float4(x, y, z, w); }
static inline float3 xyz(const float4& v) { return float3(v.x, v.y, v.z); }
static inline float3 fmin(const float3& a, const float3& b) { return glm::min(a, b); }
static inline float3 fmax(const float3& a, const float3& b) { return glm::max(a, b); }
static inline int4 xi_less4(const float4& a, const float4& b) { return -int4(glm::lessThan(a, b)); }
static inline int4 xi_greater4(const float4& a, const float4& b) { return -int4(glm::greaterThan(a, b)); }
static inline int4 xi_less_equal(const float4& a, const float4& b) { return -int4(glm::lessThanEqual(a, b)); }
static inline float4 xi_min(const float4& a, const float4& b) { return glm::min(a, b); }
static inline float4 xi_max(const float4& a, const float4& b) { return glm::max(a, b); }
static inline float4 fmin(const float4& a, const float4& b) { return glm::min(a, b); }
static inline float4 fmax(const float4& a, const float4& b) { return glm::max(a, b); }
static inline float3 fabs(const float3& a) { return glm::abs(a); }
static inline float4 fabs(const float4& a) { return glm::abs(a); }
static inline uint clz(uint x) { return x ? (uint)__builtin_clz(x) : 32u; }
typedef uint64_t ulong;
static inline uint mul_hi(uint a, uint b) { return (uint)(((uint64_t)a * b) >> 32); }
static inline float clamp(float x, float lo, float hi) { return std::fmin(std::fmax(x, lo), hi); }
static inline int clamp(int x, int lo, int hi) { return x < lo ? lo : x > hi ? hi : x; }
static inline uint as_uint(float f) { uint u; std::memcpy(&u, &f, 4); return u; }
static inline float as_float(uint u) { float f; std::memcpy(&f, &u, 4); return f; }
static inline int as_int(float f) { int i; std::memcpy(&i, &f, 4); return i; }
static inline float as_float_i(int i) { float f; std::memcpy(&f, &i, 4); return f; }

#endif

#ifdef XI_DEVICE
#define as_float_i(i) as_float(i)
#endif

// Forces inlining where the compiler would not, so calls with common arguments share their work
// (the hashes of the sampler). Clang (PoCL's OpenCL compiler) and GCC take it; other compilers
// decide for themselves.
#if defined(__clang__) || defined(__GNUC__)
#define XI_INLINE __attribute__((always_inline))
#else
#define XI_INLINE
#endif

// A constant table the kernels and the host's tests both read.
#ifdef XI_DEVICE
#define XI_TABLE __constant
#else
#define XI_TABLE static const
#endif

#define XI_PI 3.14159265358979323846f
#define XI_INV_PI 0.31830988618379067154f
#define XI_ONE_MINUS_EPSILON 0x1.fffffep-1f  // the largest float below 1

// Bit k set where lane k of a comparison (−1 true, 0 false) is true; xi_lane_bits8 and
// xi_lane_bits16 for 8 and 16 lanes. Compiled for x86 with AVX (PoCL on a CPU), one movmskps reads
// the lanes' sign bits (with AVX-512, one mask move those of 16): LLVM does not find it in the
// portable form, which became some twenty shuffles, ands, ors and extracts per node test; every
// hit is the same either way. (A test builds with XI_PORTABLE_LANE_BITS to check the other
// devices' form on PoCL too.)
#if defined(__OPENCL_VERSION__) && defined(__clang__) && defined(__AVX__) && !defined(XI_PORTABLE_LANE_BITS)
typedef float xi_m128 __attribute__((vector_size(16)));
typedef float xi_m256 __attribute__((vector_size(32)));
static inline uint xi_lane_bits(int4 m) { return (uint)__builtin_ia32_movmskps((xi_m128)as_float4(m)); }
static inline uint xi_lane_bits8(int8 m) { return (uint)__builtin_ia32_movmskps256((xi_m256)as_float8(m)); }
#ifdef __AVX512DQ__
typedef int xi_m512i __attribute__((vector_size(64)));
static inline uint xi_lane_bits16(int16 m) { return (uint)__builtin_ia32_cvtd2mask512((xi_m512i)m); }
#else
static inline uint xi_lane_bits16(int16 m) { return xi_lane_bits8(m.lo) | xi_lane_bits8(m.hi) << 8; }
#endif
#else
static inline uint xi_lane_bits(int4 m) { return (uint)((m.x & 1) | (m.y & 2) | (m.z & 4) | (m.w & 8)); }
#ifdef __OPENCL_VERSION__
static inline uint xi_lane_bits8(int8 m) { return xi_lane_bits(m.lo) | xi_lane_bits(m.hi) << 4; }
static inline uint xi_lane_bits16(int16 m) { return xi_lane_bits8(m.lo) | xi_lane_bits8(m.hi) << 8; }
#endif
#endif

// Before a loop over a vector's lanes: unrolled, each lane is taken with a constant index, from a
// register. (Performance only; the host ignores it.)
#ifdef __OPENCL_VERSION__
#define XI_UNROLL _Pragma("unroll")
#else
#define XI_UNROLL
#endif

// XI_PREFETCH(p, rw): a hint to bring p's cache line in ahead of its use (rw 1: it will be
// written). Only where clang compiles for a CPU (PoCL), whose work items run one after another and
// wait for each miss in turn; a GPU hides the latency by switching warps. XI_HAS_PREFETCH says
// whether it does anything, so the address need not be computed where it does not.
#if defined(__OPENCL_VERSION__) && defined(__clang__) && defined(XI_CPU_DEVICE)
#define XI_HAS_PREFETCH 1
#define XI_PREFETCH(p, rw) __builtin_prefetch((p), (rw))
#else
#define XI_HAS_PREFETCH 0
#define XI_PREFETCH(p, rw) ((void)(p))
#endif

// XI_TRANSPOSE4(W, a, b, c, d): rows of float4s to columns and back in vectors of W = 8 or 16 floats.
// a holds rows 0, 4, 8, 12 in its 128-bit parts, b rows 1, 5, 9, 13, c rows 2, 6, 10, 14, d rows 3,
// 7, 11, 15; a 4×4 transpose within each part leaves the rows' x in a in row order, their y in b, z
// in c, w in d, and back again (it is its own inverse). XI_COLUMNS(W, r, a, b, c, d): rows r[0..W-1]
// into columns a, b, c, d; XI_ROW(W, a, b, c, d, k): row k of columns transposed back. Two rounds of
// shuffles, where moving the values one by one took an extract and an insert each. Where clang
// compiles (XI_HAS_SHUFFLE), with its __builtin_shufflevector; elsewhere value by value, the form a
// test also builds with XI_PORTABLE_SHUFFLES.
#if defined(__OPENCL_VERSION__) && defined(__clang__) && !defined(XI_PORTABLE_SHUFFLES)
#define XI_HAS_SHUFFLE 1
#define XI_CAT_(a, b) a##b
#define XI_CAT(a, b) XI_CAT_(a, b)
#define XI_TRANSPOSE4(W, a, b, c, d)                                                                     \
  {                                                                                                      \
    const __typeof__(a) t0 = XI_CAT(XI_PAIR_LOW, W)(a, b), t1 = XI_CAT(XI_PAIR_LOW, W)(c, d);              \
    const __typeof__(a) t2 = XI_CAT(XI_PAIR_HIGH, W)(a, b), t3 = XI_CAT(XI_PAIR_HIGH, W)(c, d);            \
    a = XI_CAT(XI_HALVES_LOW, W)(t0, t1), b = XI_CAT(XI_HALVES_HIGH, W)(t0, t1);                          \
    c = XI_CAT(XI_HALVES_LOW, W)(t2, t3), d = XI_CAT(XI_HALVES_HIGH, W)(t2, t3);                          \
  }
#define XI_COLUMNS(W, r, a, b, c, d)                                                                     \
  {                                                                                                      \
    a = XI_CAT(XI_ROWS, W)(r, 0), b = XI_CAT(XI_ROWS, W)(r, 1);                                          \
    c = XI_CAT(XI_ROWS, W)(r, 2), d = XI_CAT(XI_ROWS, W)(r, 3);                                          \
    XI_TRANSPOSE4(W, a, b, c, d)                                                                         \
  }
#define XI_ROW(W, a, b, c, d, k) \
  XI_CAT(XI_ROW_OF, W)(((k) & 3) == 0 ? (a) : ((k) & 3) == 1 ? (b) : ((k) & 3) == 2 ? (c) : (d), (k) >> 2)
#define XI_PAIR_LOW8(a, b) __builtin_shufflevector(a, b, 0, 8, 1, 9, 4, 12, 5, 13)
#define XI_PAIR_HIGH8(a, b) __builtin_shufflevector(a, b, 2, 10, 3, 11, 6, 14, 7, 15)
#define XI_HALVES_LOW8(a, b) __builtin_shufflevector(a, b, 0, 1, 8, 9, 4, 5, 12, 13)
#define XI_HALVES_HIGH8(a, b) __builtin_shufflevector(a, b, 2, 3, 10, 11, 6, 7, 14, 15)
#define XI_ROWS8(r, j) (float8)(r[j], r[(j) + 4])
#define XI_ROW_OF8(v, q) ((q) == 0 ? (v).s0123 : (v).s4567)
#define XI_PAIR_LOW16(a, b) __builtin_shufflevector(a, b, 0, 16, 1, 17, 4, 20, 5, 21, 8, 24, 9, 25, 12, 28, 13, 29)
#define XI_PAIR_HIGH16(a, b) __builtin_shufflevector(a, b, 2, 18, 3, 19, 6, 22, 7, 23, 10, 26, 11, 27, 14, 30, 15, 31)
#define XI_HALVES_LOW16(a, b) __builtin_shufflevector(a, b, 0, 1, 16, 17, 4, 5, 20, 21, 8, 9, 24, 25, 12, 13, 28, 29)
#define XI_HALVES_HIGH16(a, b) __builtin_shufflevector(a, b, 2, 3, 18, 19, 6, 7, 22, 23, 10, 11, 26, 27, 14, 15, 30, 31)
#define XI_ROWS16(r, j) (float16)(r[j], r[(j) + 4], r[(j) + 8], r[(j) + 12])
#define XI_ROW_OF16(v, q) ((q) == 0 ? (v).s0123 : (q) == 1 ? (v).s4567 : (q) == 2 ? (v).s89ab : (v).scdef)
#else
#define XI_HAS_SHUFFLE 0
#endif

// gamma(n) = n eps / (1 - n eps), eps = 2^-24: the relative error bound of n rounded operations.
#define XI_GAMMA(n) ((n) * 0x1p-24f / (1.0f - (n) * 0x1p-24f))

#endif
