// Stage 4, shadow: any-hit test of every queued shadow ray; an unoccluded ray adds its
// contribution to its path. A path queues at most one shadow ray per bounce, so the add is safe.
#include "intersect.h"
#include "layout.h"

__kernel void shadow(XI_PATH_PARAMS XI_SHADOW_PARAMS __global const uint* restrict counters, uint bounce,
                     __global const TraceNode* restrict nodes, __global const TriBlock* restrict tri_blocks) {
  uint i = get_global_id(0);
  uint count = counters[XI_COUNTER_SHADOW(bounce)];
  if (i >= count) return;  // launched over an upper bound
#if XI_HAS_PREFETCH
  // The radiance of the path 4 entries on, which its ray adds to if unoccluded (as extend does):
  // shadow up to 8% faster on PoCL.
  if (i + 4u < count) XI_PREFETCH(&radiance[as_uint(shadow_contrib[i + 4u].w)], 1);
#endif
  float4 o = shadow_org[i];
  float t, u, v;
  if (xi_trace(nodes, tri_blocks, o.xyz, shadow_dir[i].xyz, o.w, true, &t, &u, &v) != XI_NO_HIT) return;
  float4 c = shadow_contrib[i];
  uint slot = as_uint(c.w);
  radiance[slot] += (float4)(c.xyz, 0.0f);
}
