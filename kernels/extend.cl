// Stage 2, extend: the closest hit of every queued ray against the BVH.
#include "intersect.h"
#include "layout.h"

__kernel void extend(XI_PATH_PARAMS __global const uint* restrict queue, __global const uint* restrict counters,
                     uint bounce, __global const TraceNode* restrict nodes, __global const TriBlock* restrict tri_blocks) {
  uint i = get_global_id(0);
  if (i >= counters[XI_COUNTER_RAYS(bounce)]) return;  // launched over an upper bound
  uint slot = queue[i];
  float t, u, v;
  uint tri = xi_trace(nodes, tri_blocks, ray_org[slot].xyz, ray_dir[slot].xyz, INFINITY, false, &t, &u, &v);
  hit[slot] = tri == XI_NO_HIT ? (float4)(-1.0f, 0.0f, 0.0f, 0.0f) : (float4)(t, u, v, as_float(tri));
}
