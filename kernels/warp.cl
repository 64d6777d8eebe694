// A tool kernel, not a wavefront stage: draws `count` points of a sample set (the sampler's pair
// `pair` for pixel `pixel`) and warps them with one of the maps of warps.h, exactly as the renderer
// would. Used by `xi warp` and by the χ² tests.
#include "sampling.h"
#include "warps.h"

// points[i] = (warped point, 0); squares[i] = (ξ₁, ξ₂) it came from.
__kernel void warp_points(__global float4* restrict points, __global float2* restrict squares, int map,
                          int sampler, SamplerParams params, uint pixel, uint pair, uint count) {
  uint i = get_global_id(0);
  if (i >= count) return;
  float2 u = xi_sample_2d(sampler, params, pixel, i, pair);
  points[i] = (float4)(xi_warp(map, u), 0.0f);
  squares[i] = u;
}
