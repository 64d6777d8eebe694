// Stage 4, shadow: any-hit test of every queued shadow ray; an unoccluded ray adds its
// contribution to its path. A path queues at most one shadow ray per bounce, so the add is safe.
// Through an 8-wide tree the rays of a small tree go in packets of 8 or 16 rays, one packet per work
// item (packet.h, xi_occluded_packet), and in a large one bounce 0's in hybrid packets
// (xi_occluded_hybrid) (layout.h's XI_SHADOW_RAYS); else one per work item (traverse.h, xi_trace's
// any-hit query). In a scene with cut-out or transparent surfaces (XI_ALPHA) a ray goes alone, from
// hit to hit, until an opaque one or its end.
#include "layout.h"
#include "packet.h"
#include "rng.h"
#include "textures.h"
#include "traverse.h"

// What a shadow ray needs to see through cut-out surfaces: the scene's surface data, the render's
// seed, and the path's pixel and sample (path state) and bounce for its blend decisions.
#define XI_ALPHA_PARAMS XI_SURFACE_BUFFERS(XI_CONST_PARAM) uint seed
#define XI_ALPHA_ARGS XI_SURFACE_BUFFERS(XI_ARG) seed
#define XI_PATH_ID_PARAMS __global const uint *restrict item_pixel, __global const uint *restrict item_sample, uint bounce
#define XI_PATH_ID_ARGS item_pixel, item_sample, bounce

static inline void xi_add_unoccluded(__global float4* radiance, float4 contrib) {
  radiance[as_uint(contrib.w)] += (float4)(contrib.xyz, 0.0f);
}

#ifdef XI_ALPHA
// Whether the closest surfaces along the ray before tmax are all ones it passes through: each
// closest hit decides, and the ray goes on from just beyond it (any hit would not do: a far
// transparent hit found first says nothing of the surfaces before it).
// The blend decisions draw on a stream of the path's own (seed, pixel, sample, bounce), as its
// other samples do, so an image depends on the seed alone and every pass decides afresh.
static inline bool xi_unoccluded_through_alpha(XI_ALPHA_PARAMS, __global const TraceNode* nodes,
                                               __global const TriBlock* tri_blocks, float3 o, float3 d, float tmax,
                                               uint pixel, uint sample, uint bounce) {
  for (uint k = 0u; k < 256u; ++k) {
    float t, u, v;
    const uint tri = xi_trace(nodes, tri_blocks, o, d, tmax, false, &t, &u, &v);
    if (tri == XI_NO_HIT) return true;
    const uint mi = tri_material[tri];
    if (xi_alpha_mode(materials, mi) == XI_ALPHA_OPAQUE) return false;
    float2 uv0, uv1;
    xi_hit_uv(tri_uv, tri, u, v, &uv0, &uv1);
    const float blend_u = xi_unit_float(xi_hash4(seed ^ 0x0a1fa5edu, pixel, sample, (bounce << 8) | k));
    float texture_alpha;
    xi_material_texture(materials, texture_refs, images, texels, mi, XI_TEXTURE_BASE_COLOR, uv0, uv1, &texture_alpha);
    if (!xi_passes_through(materials, mi, texture_alpha, blend_u)) return false;
    const float advance = t + 1e-5f * fmax(t, 1.0f);
    o += d * advance;
    tmax -= advance;
    if (tmax <= 0.0f) return true;
  }
  return false;
}
#endif

// Shadow ray i alone.
static inline void xi_shadow_one(__global float4* radiance, __global const float4* shadow_org,
                                 __global const float4* shadow_dir, __global const float4* shadow_contrib, uint i,
                                 __global const TraceNode* nodes, __global const TriBlock* tri_blocks,
                                 XI_ALPHA_PARAMS, XI_PATH_ID_PARAMS) {
  const float4 o = shadow_org[i];
#ifdef XI_ALPHA
  const uint slot = as_uint(shadow_contrib[i].w);
  if (xi_unoccluded_through_alpha(XI_ALPHA_ARGS, nodes, tri_blocks, o.xyz, shadow_dir[i].xyz, o.w,
                                  item_pixel[slot], item_sample[slot], bounce))
    xi_add_unoccluded(radiance, shadow_contrib[i]);
#else
  float t, u, v;
  if (xi_trace(nodes, tri_blocks, o.xyz, shadow_dir[i].xyz, o.w, true, &t, &u, &v) == XI_NO_HIT)
    xi_add_unoccluded(radiance, shadow_contrib[i]);
#endif
}

#if XI_BVH_WIDTH == 8
// Shadow rays wi to wi + w - 1 (w = XI_PACKET_WIDTH); a last packet of fewer than w goes one ray
// at a time.
static inline void xi_shadow_packet(__global float4* radiance, __global const float4* shadow_org,
                                    __global const float4* shadow_dir, __global const float4* shadow_contrib,
                                    uint count, bool hybrid, __global const TraceNode* nodes,
                                    __global const TriBlock* tri_blocks, XI_ALPHA_PARAMS, XI_PATH_ID_PARAMS) {
  const uint first = (uint)get_global_id(0) * XI_PACKET_WIDTH;
  if (first >= count) return;
  if (count - first < XI_PACKET_WIDTH) {
    for (uint i = first; i < count; ++i)
      xi_shadow_one(radiance, shadow_org, shadow_dir, shadow_contrib, i, nodes, tri_blocks, XI_ALPHA_ARGS, XI_PATH_ID_ARGS);
    return;
  }
  float4 o[XI_PACKET_WIDTH], d[XI_PACKET_WIDTH];
  XI_UNROLL for (uint k = 0u; k < XI_PACKET_WIDTH; ++k) {
    o[k] = shadow_org[first + k];
    d[k] = shadow_dir[first + k];
  }
  const uint occluded =
      hybrid ? xi_occluded_hybrid(nodes, tri_blocks, o, d) : xi_occluded_packet(nodes, tri_blocks, o, d);
  // Over the set bits of the unoccluded rays, not a test per ray: which rays a light reaches is
  // what no branch predictor learns.
  for (uint reached = ~occluded & ((1u << XI_PACKET_WIDTH) - 1u); reached != 0u; reached &= reached - 1u)
    xi_add_unoccluded(radiance, shadow_contrib[first + 31u - clz(reached & (0u - reached))]);
}
#endif

__kernel void shadow(XI_PATH_PARAMS XI_SHADOW_PARAMS __global const uint* restrict counters, uint bounce,
                     __global const TraceNode* restrict nodes, __global const TriBlock* restrict tri_blocks,
                     XI_ALPHA_PARAMS) {
  uint count = counters[XI_COUNTER_SHADOW(bounce)];
#if XI_BVH_WIDTH == 8
  // A program's shadow packets are all of one kind (hybrid unless XI_RAY_PACKETS), so it compiles one.
  if (XI_SHADOW_RAYS(XI_BVH_WIDTH, bounce, XI_RAY_PACKETS, XI_HYBRID_PACKETS) != XI_RAYS_ALONE) {
    xi_shadow_packet(radiance, shadow_org, shadow_dir, shadow_contrib, count, !XI_RAY_PACKETS, nodes, tri_blocks,
                     XI_ALPHA_ARGS, XI_PATH_ID_ARGS);
    return;
  }
#endif
  uint i = get_global_id(0);
  if (i >= count) return;  // launched over an upper bound
#if XI_HAS_PREFETCH
  // The radiance of the path 4 entries on, which its ray adds to if unoccluded, fetched while this
  // one traverses (as extend does), so that add no longer waits on memory.
  if (i + 4u < count) XI_PREFETCH(&radiance[as_uint(shadow_contrib[i + 4u].w)], 1);
#endif
  xi_shadow_one(radiance, shadow_org, shadow_dir, shadow_contrib, i, nodes, tri_blocks, XI_ALPHA_ARGS, XI_PATH_ID_ARGS);
}
