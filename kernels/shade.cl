// Stage 3, shade: at each queued hit, adds emitted radiance (MIS-weighted against light
// sampling), queues one shadow ray toward a light (next-event estimation), samples the BSDF for
// the next ray, applies Russian roulette and appends surviving paths to the next ray queue.
// What it does beyond diffuse surfaces is the shading word's (shading.h): mirrors, glass,
// interpolated shading normals, emitters, light sampling (NEE) and MIS.
// Each work item shades XI_LANES paths at once (lanes.h): branches that differ between paths are
// lane masks, and every path of one launch is at the same depth, `bounce`.
#include "bsdf.h"
#include "lanes.h"
#include "layout.h"
#include "lights.h"
#include "sampling.h"
#include "shading.h"
#include "spawn.h"
#include "warps.h"

// Russian roulette from this bounce on, as in Mitsuba 3 (rr_depth 5): earlier bounces carry most
// of the image, and ending them early adds more variance than it saves time.
#define XI_ROULETTE_DEPTH 5u

// What shading the paths produced: which go on (their new rays are in the path state) and which
// queue a shadow ray.
typedef struct {
  xmask next_ray;
  xmask shadow;
  xfloat3 shadow_org;
  xfloat shadow_tmax;
  xfloat3 shadow_dir;
  xfloat3 shadow_contrib;
} ShadeResult;

static inline XI_INLINE ShadeResult xi_shade_paths(XI_PATH_PARAMS xuint slot, xmask active, uint d,
                                                   __global const MaterialData* restrict materials,
                                                   __global const float4* restrict tri_verts,
                                                   __global const uint* restrict tri_material,
                                                   __global const float4* restrict tri_normals,
                                                   __global const float* restrict light_cdf,
                                                   __global const uint* restrict light_tri,
                                                   __global const float* restrict tri_light_pdf, uint light_count,
                                                   SamplerParams sampler, uint shading, xuint pixel,
                                                   xuint sample_index, uint max_depth, float4 background) {
  const int sampler_kind = xi_sampler_of(shading);
  ShadeResult r;
  r.next_ray = XI_FALSE;
  r.shadow = XI_FALSE;
  r.shadow_org = r.shadow_dir = r.shadow_contrib = xi_splat3(make_float3(0.0f, 0.0f, 0.0f));
  r.shadow_tmax = 0.0f;
  if (!XI_ANY(active)) return r;
  xfloat tri_bits;
  xfloat3 h = xi_gather_xyz(hit, slot, &tri_bits);  // t (< 0: missed), barycentrics u, v
  xfloat prev_pdf;  // 0 after a camera ray or a specular bounce
  xfloat3 beta = xi_gather_xyz(throughput, slot, &prev_pdf);
  xfloat3 L = xi_gather_xyz(radiance, slot, 0);

  // Escaped: the background is not sampled as a light, so it has weight 1.
  xmask escaped = h.x < 0.0f;
  L = xi_select3(escaped, xi_add3(L, xi_mul3(beta, xi_splat3(xyz(background)))), L);
  xmask at_surface = active && !escaped;
  if (!XI_ANY(at_surface)) {
    xi_scatter4(radiance, slot, L, (xfloat)0.0f, active);
    return r;
  }

  xuint tri = at_surface ? xi_as_uint(tri_bits) : (xuint)0u;  // other lanes read triangle 0, unused
  xfloat3 p0 = xi_gather_xyz(tri_verts, 3u * tri, 0), p1 = xi_gather_xyz(tri_verts, 3u * tri + 1u, 0),
          p2 = xi_gather_xyz(tri_verts, 3u * tri + 2u, 0);
  xfloat3 wo = xi_neg3(xi_gather_xyz(ray_dir, slot, 0));
  xfloat3 ng = xi_normalize3(xi_cross3(xi_sub3(p1, p0), xi_sub3(p2, p0)));
  xmask front = xi_dot3(ng, wo) > 0.0f;
  ShadingMaterial m = xi_gather_material(materials, xi_gather_uint(tri_material, tri));
  xfloat3 p_error;
  xfloat3 p = xi_interpolate(p0, p1, p2, h.y, h.z, &p_error);

  xmask emits = at_surface && (front || m.two_sided > 0.0f) && xi_max3(m.emission) > 0.0f;
  if (xi_uses(shading, XI_USE_EMITTERS) && XI_ANY(emits)) {
    xfloat emit_weight = 1.0f;
    if (xi_uses(shading, XI_USE_MIS))
      emit_weight = prev_pdf > 0.0f ? xi_power_heuristic(prev_pdf, xi_light_pdf(tri_light_pdf, tri, h.x,
                                                                                fabs(xi_dot3(ng, wo))))
                                    : emit_weight;
    else if (xi_uses(shading, XI_USE_NEE))
      emit_weight = prev_pdf > 0.0f ? (xfloat)0.0f : emit_weight;  // light sampling alone already counted it
    L = xi_select3(emits, xi_add3(L, xi_scale3(xi_mul3(beta, m.emission), emit_weight)), L);
  }

  xi_scatter4(radiance, slot, L, (xfloat)0.0f, active);
  if (d >= max_depth) return r;

  xfloat3 n_geo = xi_select3(front, ng, xi_neg3(ng));  // geometric normal on the side of wo
  xfloat3 n = n_geo;
  if (xi_uses(shading, XI_USE_NORMALS)) {
    xfloat has_normals;  // w marks a triangle that has vertex normals
    xfloat3 na = xi_gather_xyz(tri_normals, 3u * tri, &has_normals);
    xmask smooth = has_normals > 0.0f;
    if (XI_ANY(smooth)) {
      xfloat3 ns = xi_normalize3(xi_add3(xi_add3(xi_scale3(na, 1.0f - h.y - h.z),
                                                 xi_scale3(xi_gather_xyz(tri_normals, 3u * tri + 1u, 0), h.y)),
                                         xi_scale3(xi_gather_xyz(tri_normals, 3u * tri + 2u, 0), h.z)));
      ns = xi_select3(xi_dot3(ns, n_geo) < 0.0f, xi_neg3(ns), ns);
      n = xi_select3(smooth, ns, n_geo);
    }
  }

  if (d == 0u) {
    xi_scatter4(aov_albedo, slot, m.albedo, (xfloat)0.0f, at_surface);
    xi_scatter4(aov_normal, slot, n, (xfloat)0.0f, at_surface);
  }

  xfloat3 wi = n;     // the next direction, where a lobe below sets it
  xfloat pdf = 0.0f;  // stays 0 for specular lobes
  xmask goes_on = XI_FALSE;
  xmask diffuse = at_surface && m.type == XI_MATERIAL_DIFFUSE && xi_max3(m.albedo) > 0.0f;
  if (xi_uses(shading, XI_USE_NEE) && light_count > 0u && XI_ANY(diffuse)) {
    xfloat2 ul = xi_sample_2d(sampler_kind, sampler, pixel, sample_index, XI_PAIR_BOUNCE(d, XI_BOUNCE_LIGHT));
    xfloat3 org = xi_offset_ray_origin(p, p_error, n_geo, n_geo);  // lights behind n_geo are skipped
    LightSample ls = xi_sample_light(light_cdf, light_tri, tri_light_pdf, tri_verts, tri_material, materials,
                                     light_count, org, ul);
    xfloat cos_s = xi_dot3(n, ls.wi);
    xfloat w = 1.0f;
    if (xi_uses(shading, XI_USE_MIS)) w = xi_power_heuristic(ls.pdf, xi_lambert_pdf(n, ls.wi));
    r.shadow = diffuse && ls.pdf > 0.0f && cos_s > 0.0f && xi_dot3(n_geo, ls.wi) > 0.0f;
    r.shadow_contrib = xi_scale3(xi_mul3(xi_scale3(xi_mul3(beta, m.albedo), XI_INV_PI), ls.radiance),
                                 cos_s * w / ls.pdf);
    // Its end is off the light already; the margin covers the rounding of the hit distance.
    r.shadow_org = org;
    r.shadow_tmax = ls.dist * (1.0f - 1e-4f);
    r.shadow_dir = ls.wi;
  }
  if (XI_ANY(diffuse)) {
    xfloat2 ub = xi_sample_2d(sampler_kind, sampler, pixel, sample_index, XI_PAIR_BOUNCE(d, XI_BOUNCE_BSDF_DIR));
    xfloat lambert_pdf;
    xfloat3 wl = xi_lambert_sample(n, ub, &lambert_pdf);
    wi = xi_select3(diffuse, wl, wi);
    pdf = diffuse ? lambert_pdf : pdf;
    // A shading normal may send the sample below the surface.
    goes_on = goes_on || (diffuse && xi_dot3(wl, n_geo) > 0.0f && lambert_pdf > 0.0f);
  }
  xmask mirror = at_surface && m.type == XI_MATERIAL_MIRROR;
  if (xi_uses(shading, XI_USE_MIRROR) && XI_ANY(mirror)) {
    xfloat3 wm = xi_reflect(wo, n);
    wi = xi_select3(mirror, wm, wi);
    goes_on = goes_on || (mirror && xi_dot3(wm, n_geo) > 0.0f);
  }
  xmask glass = at_surface && m.type == XI_MATERIAL_DIELECTRIC;
  if (xi_uses(shading, XI_USE_DIELECTRIC) && XI_ANY(glass)) {
    xfloat2 uc = xi_sample_2d(sampler_kind, sampler, pixel, sample_index, XI_PAIR_BOUNCE(d, XI_BOUNCE_LOBE));
    xmask reflected;
    wi = xi_select3(glass, xi_dielectric_sample(wo, n, m.ior, front, uc.x, &reflected), wi);
    goes_on = goes_on || glass;
  }
  // (A material the shading word leaves out ends its path.)
  beta = xi_mul3(beta, m.albedo);

  if (d + 1u >= XI_ROULETTE_DEPTH) {
    // The decision takes an independent uniform, whatever the sampler: a deterministic sample set
    // (grid's cell centres) would make it a fixed cut, ending every path whose q is below them all.
    xfloat q = fmin(xi_max3(beta), 0.95f);
    xfloat u = xi_sample_2d(XI_SAMPLER_RANDOM, sampler, pixel, sample_index, XI_PAIR_BOUNCE(d, XI_BOUNCE_ROULETTE)).x;
    goes_on = goes_on && u < q;
    beta = xi_div3(beta, q);
  }
  goes_on = goes_on && xi_max3(beta) > 0.0f;

  xi_scatter4(ray_org, slot, xi_offset_ray_origin(p, p_error, n_geo, wi), (xfloat)0.0f, goes_on);
  xi_scatter4(ray_dir, slot, wi, (xfloat)0.0f, goes_on);
  xi_scatter4(throughput, slot, beta, pdf, goes_on);
  r.next_ray = goes_on;
  return r;
}

// Work item i shades queue entries XI_LANES·i to XI_LANES·i + XI_LANES − 1.
__kernel void shade(XI_PATH_PARAMS __global const uint* restrict queue_in, __global uint* restrict queue_out,
                    XI_SHADOW_PARAMS volatile __global uint* restrict counters, uint bounce,
                    __global const MaterialData* restrict materials, __global const float4* restrict tri_verts,
                    __global const uint* restrict tri_material, __global const float4* restrict tri_normals,
                    __global const float* restrict light_cdf, __global const uint* restrict light_tri,
                    __global const float* restrict tri_light_pdf, uint light_count,
                    SamplerParams sampler, uint shading_argument, uint max_depth, float4 background) {
  const uint shading = xi_shading(shading_argument);
  volatile __local uint group_count[2], group_base[2];  // for the queue appends below
  xuint entry = (uint)get_global_id(0) * XI_LANES + XI_LANE_INDEX;
  uint count = counters[XI_COUNTER_RAYS(bounce)];
  xmask active = entry < count;  // launched over an upper bound
#if XI_HAS_PREFETCH
  // The next work item's paths, fetched while this one shades (as extend does), so their loads no
  // longer wait on memory.
  uint next = (uint)get_global_id(0) * XI_LANES + XI_LANES;
  for (uint k = 0u; k < XI_LANES && next + k < count; ++k) {
    uint ahead = queue_in[next + k];
    XI_PREFETCH(&hit[ahead], 0);
    XI_PREFETCH(&throughput[ahead], 1);
    XI_PREFETCH(&radiance[ahead], 1);
    XI_PREFETCH(&ray_dir[ahead], 1);
  }
#endif
  xuint slot = xi_gather_uint(queue_in, active ? entry : (xuint)0u);
  slot = active ? slot : (xuint)0u;  // queue_in[0] may be unwritten when the queue is empty
  ShadeResult r = xi_shade_paths(XI_PATH_ARGS slot, active, bounce, materials, tri_verts, tri_material, tri_normals,
                                 light_cdf, light_tri, tri_light_pdf, light_count, sampler,
                                 shading, xi_gather_uint(item_pixel, slot), xi_gather_uint(item_sample, slot), max_depth,
                                 background);
  // Append to the ray and shadow queues: entries are counted in local memory and reserved with one
  // global atomic per work group, since a global atomic per item serialises the cores on one line.
  uint rays = xi_count(r.next_ray), shadows = xi_count(r.shadow);
  if (get_local_id(0) == 0u) group_count[0] = group_count[1] = 0u;
  barrier(CLK_LOCAL_MEM_FENCE);
  uint ray_index = rays ? atomic_add(&group_count[0], rays) : 0u;
  uint shadow_index = shadows ? atomic_add(&group_count[1], shadows) : 0u;
  barrier(CLK_LOCAL_MEM_FENCE);
  if (get_local_id(0) == 0u) {
    group_base[0] = atomic_add(&counters[XI_COUNTER_RAYS(bounce + 1u)], group_count[0]);
    group_base[1] = atomic_add(&counters[XI_COUNTER_SHADOW(bounce)], group_count[1]);
  }
  barrier(CLK_LOCAL_MEM_FENCE);
  xuint ray_at = xi_compact_index(group_base[0] + ray_index, r.next_ray);
  xuint shadow_at = xi_compact_index(group_base[1] + shadow_index, r.shadow);
  xi_scatter_uint(queue_out, ray_at, slot, r.next_ray);
  xi_scatter4(shadow_org, shadow_at, r.shadow_org, r.shadow_tmax, r.shadow);
  xi_scatter4(shadow_dir, shadow_at, r.shadow_dir, (xfloat)0.0f, r.shadow);
  xi_scatter4(shadow_contrib, shadow_at, r.shadow_contrib, xi_as_float(slot), r.shadow);
}
