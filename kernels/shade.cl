// Stage 3, shade: at each queued hit, adds emitted radiance (MIS-weighted against light
// sampling), queues one shadow ray toward a light (next-event estimation), samples the BSDF for
// the next ray, applies Russian roulette and appends surviving paths to the next ray queue.
// Compiled per scene: XI_HAS_MIRROR, XI_HAS_DIELECTRIC, XI_HAS_NORMALS (interpolated shading
// normals), XI_HAS_EMITTERS, XI_NEE (light sampling), XI_MIS (combine it with BSDF sampling).
#include "bsdf.h"
#include "layout.h"
#include "lights.h"
#include "sampling.h"
#include "warps.h"

// Russian roulette from this bounce on, as in Mitsuba 3 (rr_depth 5): earlier bounces carry most
// of the image, and ending them early adds more variance than it saves time.
#define XI_ROULETTE_DEPTH 5u

// What shading one path produced: whether it goes on (its new ray is in the path state) and
// whether it queues a shadow ray.
typedef struct {
  bool next_ray;
  bool shadow;
  float4 shadow_org;      // xyz: origin; w: tmax
  float4 shadow_dir;
  float4 shadow_contrib;  // rgb; w: as_float(path slot)
} ShadeResult;

static inline ShadeResult xi_shade_path(XI_PATH_PARAMS uint slot, bool active, __global const MaterialData* restrict materials,
                                        __global const float4* restrict tri_verts,
                                        __global const uint* restrict tri_material,
                                        __global const float4* restrict tri_normals,
                                        __global const float* restrict light_cdf,
                                        __global const uint* restrict light_tri,
                                        __global const float* restrict tri_light_pdf, uint light_count,
                                        SamplerParams sampler, uint pixel, uint sample_index, uint max_depth,
                                        float4 background) {
  ShadeResult r;
  r.next_ray = false;
  r.shadow = false;
  if (!active) return r;
  uint d = depth[slot];
  float4 h = hit[slot];
  float4 beta4 = throughput[slot];
  float3 beta = beta4.xyz;
  float prev_pdf = beta4.w;  // 0 after a camera ray or a specular bounce
  float3 L = radiance[slot].xyz;

  if (h.x < 0.0f) {  // escaped: the background is not sampled as a light, so it has weight 1
    radiance[slot] = (float4)(L + beta * background.xyz, 0.0f);
    return r;
  }

  uint tri = as_uint(h.w);
  float3 p0 = tri_verts[3u * tri].xyz, p1 = tri_verts[3u * tri + 1u].xyz, p2 = tri_verts[3u * tri + 2u].xyz;
  float3 wo = -ray_dir[slot].xyz;
  float3 ng = normalize(cross(p1 - p0, p2 - p0));
  bool front = dot(ng, wo) > 0.0f;
  MaterialData m = materials[tri_material[tri]];
  float3 p_error;
  float3 p = xi_interpolate(p0, p1, p2, h.y, h.z, &p_error);

#ifdef XI_HAS_EMITTERS
  if ((front || m.emission.w > 0.0f) && xi_max3(m.emission.xyz) > 0.0f) {
    float w = 1.0f;
#ifdef XI_NEE
    if (prev_pdf > 0.0f) {
#ifdef XI_MIS
      w = xi_power_heuristic(prev_pdf, xi_light_pdf(tri_light_pdf, tri, h.x, fabs(dot(ng, wo))));
#else
      w = 0.0f;  // light sampling alone already counted this light
#endif
    }
#endif
    L += beta * m.emission.xyz * w;
  }
#endif

  radiance[slot] = (float4)(L, 0.0f);
  if (d >= max_depth) return r;

  float3 n_geo = front ? ng : -ng;  // geometric normal on the side of wo
  float3 n = n_geo;
#ifdef XI_HAS_NORMALS
  float4 na = tri_normals[3u * tri];
  if (na.w > 0.0f) {  // w marks a triangle that has vertex normals
    float3 ns = normalize((1.0f - h.y - h.z) * na.xyz + h.y * tri_normals[3u * tri + 1u].xyz +
                          h.z * tri_normals[3u * tri + 2u].xyz);
    n = dot(ns, n_geo) < 0.0f ? -ns : ns;
  }
#endif

  if (d == 0u) {
    aov_albedo[slot] = (float4)(m.albedo.xyz, 0.0f);
    aov_normal[slot] = (float4)(n, 0.0f);
  }

  float3 wi;
  float pdf = 0.0f;  // stays 0 for specular lobes
  if (m.type == XI_MATERIAL_DIFFUSE) {
    if (xi_max3(m.albedo.xyz) <= 0.0f) return r;
#ifdef XI_NEE
    if (light_count > 0u) {
      float2 ul = xi_sample_2d(XI_SAMPLER, sampler, pixel, sample_index, XI_PAIR_BOUNCE(d, XI_BOUNCE_LIGHT));
      float3 org = xi_offset_ray_origin(p, p_error, n_geo, n_geo);  // lights behind n_geo are skipped
      LightSample ls = xi_sample_light(light_cdf, light_tri, tri_light_pdf, tri_verts, tri_material, materials,
                                       light_count, org, ul);
      float cos_s = dot(n, ls.wi);
      if (ls.pdf > 0.0f && cos_s > 0.0f && dot(n_geo, ls.wi) > 0.0f) {
        float w = 1.0f;
#ifdef XI_MIS
        w = xi_power_heuristic(ls.pdf, xi_lambert_pdf(n, ls.wi));
#endif
        float3 c = beta * m.albedo.xyz * XI_INV_PI * ls.radiance * (cos_s * w / ls.pdf);
        r.shadow = true;
        // Its end is off the light already; the margin covers the rounding of the hit distance.
        r.shadow_org = (float4)(org, ls.dist * (1.0f - 1e-4f));
        r.shadow_dir = (float4)(ls.wi, 0.0f);
        r.shadow_contrib = (float4)(c, as_float(slot));
      }
    }
#endif
    float2 ub = xi_sample_2d(XI_SAMPLER, sampler, pixel, sample_index, XI_PAIR_BOUNCE(d, XI_BOUNCE_BSDF_DIR));
    wi = xi_lambert_sample(n, ub, &pdf);
    if (dot(wi, n_geo) <= 0.0f || pdf <= 0.0f) return r;  // shading normal pointed below the surface
    beta *= m.albedo.xyz;
  }
#ifdef XI_HAS_MIRROR
  else if (m.type == XI_MATERIAL_MIRROR) {
    wi = xi_reflect(wo, n);
    if (dot(wi, n_geo) <= 0.0f) return r;
    beta *= m.albedo.xyz;
  }
#endif
#ifdef XI_HAS_DIELECTRIC
  else if (m.type == XI_MATERIAL_DIELECTRIC) {
    float2 uc = xi_sample_2d(XI_SAMPLER, sampler, pixel, sample_index, XI_PAIR_BOUNCE(d, XI_BOUNCE_LOBE));
    bool reflected;
    wi = xi_dielectric_sample(wo, n, m.albedo.w, front, uc.x, &reflected);
    beta *= m.albedo.xyz;
  }
#endif
  else {
    return r;  // a material this build was not compiled for
  }

  if (d + 1u >= XI_ROULETTE_DEPTH) {
    // The decision takes an independent uniform, whatever the sampler: a deterministic sample set
    // (grid's cell centres) would make it a fixed cut, ending every path whose q is below them all.
    float q = fmin(xi_max3(beta), 0.95f);
    float u = xi_sample_2d(XI_SAMPLER_RANDOM, sampler, pixel, sample_index, XI_PAIR_BOUNCE(d, XI_BOUNCE_ROULETTE)).x;
    if (u >= q) return r;
    beta /= q;
  }
  if (xi_max3(beta) <= 0.0f) return r;

  ray_org[slot] = (float4)(xi_offset_ray_origin(p, p_error, n_geo, wi), 0.0f);
  ray_dir[slot] = (float4)(wi, 0.0f);
  throughput[slot] = (float4)(beta, pdf);
  depth[slot] = d + 1u;
  r.next_ray = true;
  return r;
}

__kernel void shade(XI_PATH_PARAMS __global const uint* restrict queue_in, __global uint* restrict queue_out,
                    XI_SHADOW_PARAMS volatile __global uint* restrict counters, uint bounce,
                    __global const MaterialData* restrict materials, __global const float4* restrict tri_verts,
                    __global const uint* restrict tri_material, __global const float4* restrict tri_normals,
                    __global const float* restrict light_cdf, __global const uint* restrict light_tri,
                    __global const float* restrict tri_light_pdf, uint light_count,
                    SamplerParams sampler, uint max_depth, float4 background) {
  volatile __local uint group_count[2], group_base[2];  // for the queue appends below
  uint i = get_global_id(0);
  bool active = i < counters[XI_COUNTER_RAYS(bounce)];  // launched over an upper bound
  uint slot = active ? queue_in[i] : 0u;
  ShadeResult r = xi_shade_path(XI_PATH_ARGS slot, active, materials, tri_verts, tri_material, tri_normals,
                                light_cdf, light_tri, tri_light_pdf, light_count, sampler, item_pixel[slot],
                                item_sample[slot], max_depth, background);
  // Append to the ray and shadow queues: entries are counted in local memory and reserved with one
  // global atomic per work group, since a global atomic per item serialises the cores on one line.
  if (get_local_id(0) == 0u) group_count[0] = group_count[1] = 0u;
  barrier(CLK_LOCAL_MEM_FENCE);
  uint ray_index = r.next_ray ? atomic_inc(&group_count[0]) : 0u;
  uint shadow_index = r.shadow ? atomic_inc(&group_count[1]) : 0u;
  barrier(CLK_LOCAL_MEM_FENCE);
  if (get_local_id(0) == 0u) {
    group_base[0] = atomic_add(&counters[XI_COUNTER_RAYS(bounce + 1u)], group_count[0]);
    group_base[1] = atomic_add(&counters[XI_COUNTER_SHADOW(bounce)], group_count[1]);
  }
  barrier(CLK_LOCAL_MEM_FENCE);
  ray_index += group_base[0];
  shadow_index += group_base[1];
  if (r.next_ray) queue_out[ray_index] = slot;
  if (r.shadow) {
    shadow_org[shadow_index] = r.shadow_org;
    shadow_dir[shadow_index] = r.shadow_dir;
    shadow_contrib[shadow_index] = r.shadow_contrib;
  }
}
