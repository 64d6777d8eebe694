// Data shared between host and kernels: structs stored in device buffers and the path state.
// Buffers hold only float4/uint-sized members (never float3, whose size differs host vs device);
// every struct is a multiple of 16 bytes with its float4 members first, so C++ and OpenCL C agree.
#ifndef XI_LAYOUT_H
#define XI_LAYOUT_H
#include "compat.h"

#define XI_MATERIAL_DIFFUSE 0u
#define XI_MATERIAL_MIRROR 1u
#define XI_MATERIAL_DIELECTRIC 2u

typedef struct {
  float4 albedo;    // rgb; w: index of refraction (dielectric)
  float4 emission;  // rgb radiance; w: 1 when both faces emit
  uint type;        // XI_MATERIAL_*
  uint pad0, pad1, pad2;
} MaterialData;

// A flattened BVH node. Interior: count == 0, left child at index + 1, right child at `index`.
// Leaf: `count` triangles starting at `index`.
typedef struct {
  float4 bmin;  // w: as_float(index)
  float4 bmax;  // w: as_float(count)
} BvhNode;

typedef struct {
  float4 position;
  float4 forward;  // unit view direction; w: lens radius (0 = pinhole)
  float4 right;    // unit, scaled by tan(vfov/2)·aspect; w: focus distance
  float4 up;       // unit, scaled by tan(vfov/2)
  uint width;
  uint height;
  uint pad0, pad1;
} CameraData;

// Per-path state, one device buffer per field, indexed by path slot. Each stage kernel takes all
// of them first (XI_PATH_PARAMS) in this order, and the host creates and binds them from this list.
#define XI_PATH_STATE(F)                                                    \
  F(float4, ray_org)    /* xyz: ray origin */                               \
  F(float4, ray_dir)    /* xyz: unit direction */                           \
  F(float4, hit)        /* t (< 0: miss), barycentric u, v, as_float(tri) */ \
  F(float4, throughput) /* rgb; w: solid-angle pdf of the last BSDF sample, 0 if specular */ \
  F(float4, radiance)   /* rgb gathered so far */                           \
  F(uint, depth)        /* bounces so far */                              \
  F(float4, aov_albedo) /* rgb: reflectance at the first hit (for denoisers) */ \
  F(float4, aov_normal) /* xyz: shading normal at the first hit, facing the camera */

// Shadow rays queued by shade, traced by shadow. Compact: item i lives at index i.
#define XI_SHADOW_STATE(F)                                  \
  F(float4, shadow_org)     /* xyz: origin; w: tmax */      \
  F(float4, shadow_dir)     /* xyz: unit direction */       \
  F(float4, shadow_contrib) /* rgb; w: as_float(path slot) */

#define XI_PARAM(type, name) __global type* restrict name,
#define XI_PATH_PARAMS XI_PATH_STATE(XI_PARAM)
#define XI_SHADOW_PARAMS XI_SHADOW_STATE(XI_PARAM)

// Counters in one small device buffer; queues ping-pong between two index buffers.
#define XI_COUNTER_RAYS_OUT 0
#define XI_COUNTER_SHADOW 1  // must follow RAYS_OUT: the host reads the two together
#define XI_COUNTER_NONFINITE 2
#define XI_COUNTER_COUNT 3

#endif
