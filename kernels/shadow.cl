// Stage 4, shadow: any-hit test of every queued shadow ray; an unoccluded ray adds its
// contribution to its path. A path queues at most one shadow ray per bounce, so the add is safe.
#include "intersect.h"
#include "layout.h"

__kernel void shadow(XI_PATH_PARAMS XI_SHADOW_PARAMS __global const uint* restrict counters, uint bounce,
                     __global const TraceNode* restrict nodes, __global const TriBlock* restrict tri_blocks) {
  uint i = get_global_id(0);
  if (i >= counters[XI_COUNTER_SHADOW(bounce)]) return;  // launched over an upper bound
  float4 o = shadow_org[i];
  float t, u, v;
  if (xi_trace(nodes, tri_blocks, o.xyz, shadow_dir[i].xyz, o.w, true, &t, &u, &v) != XI_NO_HIT) return;
  float4 c = shadow_contrib[i];
  uint slot = as_uint(c.w);
  radiance[slot] += (float4)(c.xyz, 0.0f);
}
