// Stage 5, accumulate: adds each finished path's radiance to its pixel, one work item per pixel
// adding its samples in sample order, so the sums are formed in a fixed order (no float atomics)
// and the image is reproducible, whatever number of samples a wave holds.
// Non-finite samples are dropped and counted so the host can warn. The first-hit albedo and normal
// are summed alongside, for denoisers; the albedo's w counts the samples taken, dropped ones too
// (the film's `spp`, which adaptive sampling tells apart per pixel).
#include "layout.h"

__kernel void accumulate(XI_PATH_PARAMS XI_FILM_BUFFERS(XI_FILM_PARAM) volatile __global uint* restrict counters,
                         __global const uint* restrict pixel_list, WaveParams wave) {
  uint p = get_global_id(0);
  if (p >= wave.pixels) return;
  uint pixel = XI_WAVE_FILM_PIXEL(wave, pixel_list, wave.first_pixel + p);
  float4 sum = film_sum[pixel], sum_sq = film_sum_sq[pixel];
  float4 albedo = film_albedo[pixel], normal = film_normal[pixel];
  for (uint s = 0u; s < wave.samples; ++s) {
    uint slot = XI_WAVE_SLOT(wave, p, s);
    float4 l = (float4)(radiance[slot].xyz, 1.0f);
    albedo.w += 1.0f;
    if (!all(isfinite(l))) {
      atomic_inc(&counters[XI_COUNTER_NONFINITE]);
      continue;
    }
    sum += l;  // w counts the samples that made it
    sum_sq += l * l;
    albedo += aov_albedo[slot];
    normal += aov_normal[slot];
  }
  film_sum[pixel] = sum;
  film_sum_sq[pixel] = sum_sq;
  film_albedo[pixel] = albedo;
  film_normal[pixel] = normal;
}
