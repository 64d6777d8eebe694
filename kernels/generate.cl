// Stage 1, generate: one camera ray per (pixel, sample) item of the wave, jittered inside the
// pixel (box filter) by the sampler's first pair of dimensions; a thin lens where the shading word
// (shading.h) says XI_USE_LENS, the lens point drawn by the concentric disc map from the second pair.
// Each work item starts XI_LANES consecutive path slots (lanes.h), as shade does: on a CPU the
// sampler's hashing then runs in vector lanes.
#include "layout.h"
#include "lanes.h"
#include "sampling.h"
#include "shading.h"
#include "warps.h"

__kernel void generate(XI_PATH_PARAMS __global uint* restrict queue, __global uint* restrict counters,
                       __global const uint* restrict pixel_list, CameraData cam, SamplerParams sampler,
                       uint shading_argument, WaveParams wave) {
  const uint shading = xi_shading(shading_argument);
  const int sampler_kind = xi_sampler_of(shading);
  uint count = wave.pixels * wave.samples;
  if (get_global_id(0) == 0u) counters[XI_COUNTER_RAYS(0)] = count;
  xuint slot = (uint)get_global_id(0) * XI_LANES + XI_LANE_INDEX;
  xmask active = slot < count;
  if (!XI_ANY(active)) return;
  // The slot's frame pixel (WaveParams): column x of film row film_pixel / width. (Slots past the
  // wave read the list at its last entry.)
  xuint at = XI_WAVE_PIXEL(wave, slot >= count ? (xuint)(count - 1u) : slot);
  xuint film_pixel = wave.pixel_list ? xi_gather_uint(pixel_list, at) : at;
  xuint x = film_pixel % wave.width, y = wave.first_row + film_pixel / wave.width * wave.row_stride;
  xuint pixel = y * wave.width + x, sample_index = XI_WAVE_SAMPLE(wave, slot);
  xfloat2 u = xi_sample_2d(sampler_kind, sampler, pixel, sample_index, XI_PAIR_PIXEL);
  // Film coordinates in [-1, 1]², x to the right, y up; pixel (0, 0) is the top-left corner.
  xfloat sx = 2.0f * (xi_to_float(x) + u.x) / (float)cam.width - 1.0f;
  xfloat sy = 1.0f - 2.0f * (xi_to_float(y) + u.y) / (float)cam.height;
  xfloat3 dir = xi_normalize3(xi_add3(xi_add3(xi_splat3(cam.forward.xyz), xi_scale3(xi_splat3(cam.right.xyz), sx)),
                                      xi_scale3(xi_splat3(cam.up.xyz), sy)));
  xfloat3 org = xi_splat3(cam.position.xyz);
  if (xi_uses(shading, XI_USE_LENS)) {
    xfloat lens_radius = cam.forward.w, focus_distance = cam.right.w;
    xfloat2 d = xi_square_to_concentric_disc(xi_sample_2d(sampler_kind, sampler, pixel, sample_index, XI_PAIR_LENS));
    xfloat3 focus = xi_add3(org, xi_scale3(dir, focus_distance / xi_dot3(dir, xi_splat3(cam.forward.xyz))));
    org = xi_add3(org, xi_scale3(xi_add3(xi_scale3(xi_splat3(normalize(cam.right.xyz)), d.x),
                                         xi_scale3(xi_splat3(normalize(cam.up.xyz)), d.y)),
                                 lens_radius));
    dir = xi_normalize3(xi_sub3(focus, org));
  }
  const xfloat zero = 0.0f;
  xi_scatter4(ray_org, slot, org, zero, active);
  xi_scatter4(ray_dir, slot, dir, zero, active);
  // (No throughput or radiance: shade starts a camera ray with its known 1 and 0, most of an asset
  // shot's camera rays escaping with no more than one lookup.)
  const xfloat3 none = xi_splat3(make_float3(0.0f, 0.0f, 0.0f));
  xi_scatter_uint(item_pixel, slot, pixel, active);  // shade draws its samples for them without redoing the divisions
  xi_scatter_uint(item_sample, slot, sample_index, active);
  xi_scatter4(aov_albedo, slot, none, zero, active);
  xi_scatter4(aov_normal, slot, none, zero, active);
  xi_scatter_uint(queue, slot, slot, active);
}
