// Stage 2, extend: the closest hit of every queued ray against the BVH. Through an 8-wide tree,
// camera rays (bounce 0) go in packets of 8 or 16, one packet per work item (packet.h,
// xi_trace_packet), as do the bounce rays of a small tree, and in a large one bounce 1's rays in
// hybrid packets (xi_trace_hybrid) (layout.h's XI_EXTEND_RAYS); every other ray alone, one per work
// item (traverse.h, xi_trace).
#include "layout.h"
#include "packet.h"
#include "traverse.h"

static inline void xi_store_hit(__global float4* hit, uint slot, uint tri, float t, float u, float v) {
  hit[slot] = tri == XI_NO_HIT ? (float4)(-1.0f, 0.0f, 0.0f, 0.0f) : (float4)(t, u, v, as_float(tri));
}

static inline void xi_extend_one(__global const float4* ray_org, __global const float4* ray_dir, __global float4* hit,
                                 uint slot, __global const TraceNode* nodes, __global const TriBlock* tri_blocks) {
  float t, u, v;
  uint tri = xi_trace(nodes, tri_blocks, ray_org[slot].xyz, ray_dir[slot].xyz, INFINITY, false, &t, &u, &v);
  xi_store_hit(hit, slot, tri, t, u, v);
}

#if XI_BVH_WIDTH == 8
// Queue entries wi to wi + w - 1 (w = XI_PACKET_WIDTH): at bounce 0 the queue is the wave's slots
// in order, so these are the samples of a few neighbouring pixels (layout.h); later, paths that
// survived in slot order. A last packet of fewer than w is traced one ray at a time.
static inline void xi_extend_packet(__global const float4* ray_org, __global const float4* ray_dir, __global float4* hit,
                                    __global const uint* queue, uint count, bool hybrid,
                                    __global const TraceNode* nodes, __global const TriBlock* tri_blocks) {
  const uint first = (uint)get_global_id(0) * XI_PACKET_WIDTH;
  if (first >= count) return;
  if (count - first < XI_PACKET_WIDTH) {
    for (uint i = first; i < count; ++i) xi_extend_one(ray_org, ray_dir, hit, queue[i], nodes, tri_blocks);
    return;
  }
  uint slot[XI_PACKET_WIDTH];
  float4 o[XI_PACKET_WIDTH], d[XI_PACKET_WIDTH];
  XI_UNROLL for (uint k = 0u; k < XI_PACKET_WIDTH; ++k) {
    slot[k] = queue[first + k];
    o[k] = ray_org[slot[k]];
    d[k] = ray_dir[slot[k]];
  }
  PacketFloat t, u, v;
  PacketUint tri;
  if (hybrid)
    xi_trace_hybrid(nodes, tri_blocks, o, d, &t, &u, &v, &tri);
  else
    xi_trace_packet(nodes, tri_blocks, o, d, &t, &u, &v, &tri);
  const PacketInt miss = tri == (PacketUint)XI_NO_HIT;  // stored as xi_store_hit stores a miss
  xi_packet_store_rows(hit, slot, select(t, (PacketFloat)-1.0f, miss), select(u, (PacketFloat)0.0f, miss),
                       select(v, (PacketFloat)0.0f, miss), select(xi_as_packet_float(tri), (PacketFloat)0.0f, miss));
}
#endif

__kernel void extend(XI_PATH_PARAMS __global const uint* restrict queue, __global const uint* restrict counters,
                     uint bounce, __global const TraceNode* restrict nodes, __global const TriBlock* restrict tri_blocks) {
  uint count = counters[XI_COUNTER_RAYS(bounce)];
#if XI_BVH_WIDTH == 8
  const int rays = XI_EXTEND_RAYS(XI_BVH_WIDTH, bounce, XI_RAY_PACKETS, XI_HYBRID_PACKETS);
  if (rays != XI_RAYS_ALONE) {
    xi_extend_packet(ray_org, ray_dir, hit, queue, count, rays == XI_RAYS_HYBRID, nodes, tri_blocks);
    return;
  }
#endif
  uint i = get_global_id(0);
  if (i >= count) return;  // launched over an upper bound
#if XI_HAS_PREFETCH
  // The rays at the queue's slots 4 entries on, fetched while this one traverses: their loads and
  // the write of their hit no longer wait on memory.
  if (i + 4u < count) {
    uint ahead = queue[i + 4u];
    XI_PREFETCH(&ray_org[ahead], 0);
    XI_PREFETCH(&ray_dir[ahead], 0);
    XI_PREFETCH(&hit[ahead], 1);
  }
#endif
  xi_extend_one(ray_org, ray_dir, hit, queue[i], nodes, tri_blocks);
}
