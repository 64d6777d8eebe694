// Stage 5, accumulate: adds each finished path's radiance to its pixel, one work item per pixel,
// so the sums are formed in a fixed order (no float atomics) and the image is reproducible.
// Non-finite samples are dropped and counted so the host can warn. The first-hit albedo and normal
// are summed alongside, for denoisers.
#include "layout.h"

__kernel void accumulate(XI_PATH_PARAMS __global float4* restrict film_sum,
                         __global float4* restrict film_sum_sq, __global float4* restrict film_albedo,
                         __global float4* restrict film_normal, volatile __global uint* restrict counters,
                         uint first_pixel, uint count) {
  uint slot = get_global_id(0);
  if (slot >= count) return;
  float4 l = (float4)(radiance[slot].xyz, 1.0f);
  if (!all(isfinite(l))) {
    atomic_inc(&counters[XI_COUNTER_NONFINITE]);
    return;
  }
  uint pixel = first_pixel + slot;
  film_sum[pixel] += l;  // w counts the samples that made it
  film_sum_sq[pixel] += l * l;
  film_albedo[pixel] += aov_albedo[slot];
  film_normal[pixel] += aov_normal[slot];
}
