// Stage 1, generate: one camera ray per (pixel, sample) item of the wave, jittered inside the
// pixel (box filter) by the sampler's first pair of dimensions; thin lens when compiled with
// XI_HAS_LENS, the lens point drawn by the concentric disc map from the second pair.
#include "layout.h"
#include "sampling.h"
#include "warps.h"

__kernel void generate(XI_PATH_PARAMS __global uint* restrict queue, __global uint* restrict counters,
                       CameraData cam, SamplerParams sampler, WaveParams wave) {
  uint slot = get_global_id(0);
  uint count = wave.pixels * wave.samples;
  if (slot == 0u) counters[XI_COUNTER_RAYS(0)] = count;
  if (slot >= count) return;
  uint pixel = xi_frame_pixel(wave, slot), sample_index = wave.first_sample + slot / wave.pixels;
  float px = (float)(pixel % cam.width), py = (float)(pixel / cam.width);
  float2 u = xi_sample_2d(XI_SAMPLER, sampler, pixel, sample_index, XI_PAIR_PIXEL);
  // Film coordinates in [-1, 1]², x to the right, y up; pixel (0, 0) is the top-left corner.
  float sx = 2.0f * (px + u.x) / (float)cam.width - 1.0f;
  float sy = 1.0f - 2.0f * (py + u.y) / (float)cam.height;
  float3 dir = normalize(cam.forward.xyz + sx * cam.right.xyz + sy * cam.up.xyz);
  float3 org = cam.position.xyz;
#ifdef XI_HAS_LENS
  float lens_radius = cam.forward.w, focus_distance = cam.right.w;
  float2 d = xi_square_to_concentric_disc(xi_sample_2d(XI_SAMPLER, sampler, pixel, sample_index, XI_PAIR_LENS));
  float3 focus = org + dir * (focus_distance / dot(dir, cam.forward.xyz));
  org += lens_radius * (d.x * normalize(cam.right.xyz) + d.y * normalize(cam.up.xyz));
  dir = normalize(focus - org);
#endif
  ray_org[slot] = (float4)(org, 0.0f);
  ray_dir[slot] = (float4)(dir, 0.0f);
  throughput[slot] = (float4)(1.0f, 1.0f, 1.0f, 0.0f);
  radiance[slot] = (float4)(0.0f);
  item_pixel[slot] = pixel;  // shade draws its samples for them without redoing the divisions
  item_sample[slot] = sample_index;
  aov_albedo[slot] = (float4)(0.0f);
  aov_normal[slot] = (float4)(0.0f);
  queue[slot] = slot;
}
