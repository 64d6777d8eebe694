// Stage 2, extend: the closest hit of every queued ray against the BVH. Through an 8-wide tree,
// camera rays (bounce 0) go in packets of eight, one packet per work item (packet.h,
// xi_trace_packet8), and so do bounce rays where the host chose it for a small tree
// (XI_RAY_PACKETS, layout.h's XI_EXTEND_PACKET); every other ray alone, one per work item
// (traverse.h, xi_trace).
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
// Queue entries 8i to 8i + 7: at bounce 0 the queue is the wave's slots in order, so these are
// neighbouring pixels of one sample; later, paths that survived in slot order. A last packet of
// fewer than eight is traced one ray at a time.
static inline void xi_extend_packet(__global const float4* ray_org, __global const float4* ray_dir, __global float4* hit,
                                    __global const uint* queue, uint count, __global const TraceNode* nodes,
                                    __global const TriBlock* tri_blocks) {
  const uint first = (uint)get_global_id(0) * 8u;
  if (first >= count) return;
  if (count - first < 8u) {
    for (uint i = first; i < count; ++i) xi_extend_one(ray_org, ray_dir, hit, queue[i], nodes, tri_blocks);
    return;
  }
  const uint8 slot = vload8(0, queue + first);
  const float4 o0 = ray_org[slot.s0], o1 = ray_org[slot.s1], o2 = ray_org[slot.s2], o3 = ray_org[slot.s3],
               o4 = ray_org[slot.s4], o5 = ray_org[slot.s5], o6 = ray_org[slot.s6], o7 = ray_org[slot.s7];
  const float4 d0 = ray_dir[slot.s0], d1 = ray_dir[slot.s1], d2 = ray_dir[slot.s2], d3 = ray_dir[slot.s3],
               d4 = ray_dir[slot.s4], d5 = ray_dir[slot.s5], d6 = ray_dir[slot.s6], d7 = ray_dir[slot.s7];
  float8 t, u, v;
  uint8 tri;
  xi_trace_packet8(nodes, tri_blocks, (float8)(o0.x, o1.x, o2.x, o3.x, o4.x, o5.x, o6.x, o7.x),
                   (float8)(o0.y, o1.y, o2.y, o3.y, o4.y, o5.y, o6.y, o7.y),
                   (float8)(o0.z, o1.z, o2.z, o3.z, o4.z, o5.z, o6.z, o7.z),
                   (float8)(d0.x, d1.x, d2.x, d3.x, d4.x, d5.x, d6.x, d7.x),
                   (float8)(d0.y, d1.y, d2.y, d3.y, d4.y, d5.y, d6.y, d7.y),
                   (float8)(d0.z, d1.z, d2.z, d3.z, d4.z, d5.z, d6.z, d7.z), &t, &u, &v, &tri);
  xi_store_hit(hit, slot.s0, tri.s0, t.s0, u.s0, v.s0);
  xi_store_hit(hit, slot.s1, tri.s1, t.s1, u.s1, v.s1);
  xi_store_hit(hit, slot.s2, tri.s2, t.s2, u.s2, v.s2);
  xi_store_hit(hit, slot.s3, tri.s3, t.s3, u.s3, v.s3);
  xi_store_hit(hit, slot.s4, tri.s4, t.s4, u.s4, v.s4);
  xi_store_hit(hit, slot.s5, tri.s5, t.s5, u.s5, v.s5);
  xi_store_hit(hit, slot.s6, tri.s6, t.s6, u.s6, v.s6);
  xi_store_hit(hit, slot.s7, tri.s7, t.s7, u.s7, v.s7);
}
#endif

__kernel void extend(XI_PATH_PARAMS __global const uint* restrict queue, __global const uint* restrict counters,
                     uint bounce, __global const TraceNode* restrict nodes, __global const TriBlock* restrict tri_blocks) {
  uint count = counters[XI_COUNTER_RAYS(bounce)];
#if XI_BVH_WIDTH == 8
  if (XI_EXTEND_PACKET(XI_BVH_WIDTH, bounce, XI_RAY_PACKETS) == 8) {
    xi_extend_packet(ray_org, ray_dir, hit, queue, count, nodes, tri_blocks);
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
