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
  const uint first = (uint)get_global_id(0) * XI_LANES;
  xuint slot = first + XI_LANE_INDEX;
  xmask active = slot < count;
  if (!XI_ANY(active)) return;
  // The slot's wave pixel and sample (XI_WAVE_PIXEL, XI_WAVE_SAMPLE), then its frame pixel: column x
  // of film row film_pixel / width. The divisions go by xi_div. (Slots past the wave take its last.)
  const XiDivisor by_samples = xi_divisor(wave.samples), by_width = xi_divisor(wave.width);
  xuint item = slot >= count ? (xuint)(count - 1u) : slot;
  xuint wave_pixel = xi_div(item, by_samples);
  xuint at = wave.first_pixel + wave_pixel, sample_index = wave.first_sample + (item - wave_pixel * wave.samples);
  xuint film_pixel = wave.pixel_list ? xi_gather_uint(pixel_list, at) : at;
  xuint row = xi_div(film_pixel, by_width);
  xuint x = film_pixel - row * wave.width, y = wave.first_row + row * wave.row_stride;
  xuint pixel = y * wave.width + x;
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
  xi_store4_from(ray_org, first, org, zero, active);
  xi_store4_from(ray_dir, first, dir, zero, active);
  // (No throughput or radiance: shade starts a camera ray with its known 1 and 0, most of an asset
  // shot's camera rays escaping with no more than one lookup.)
  const xfloat3 none = xi_splat3(make_float3(0.0f, 0.0f, 0.0f));
  xi_store_uint_from(item_pixel, first, pixel, active);  // shade draws its samples for them without redoing the divisions
  xi_store_uint_from(item_sample, first, sample_index, active);
  xi_store4_from(aov_albedo, first, none, zero, active);
  xi_store4_from(aov_normal, first, none, zero, active);
  xi_store_uint_from(queue, first, slot, active);
}
