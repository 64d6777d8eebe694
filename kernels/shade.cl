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

#define XI_ROULETTE_DEPTH 3u

__kernel void shade(XI_PATH_PARAMS __global const uint* restrict queue_in, uint count,
                    __global uint* restrict queue_out, XI_SHADOW_PARAMS volatile __global uint* restrict counters,
                    __global const MaterialData* restrict materials, __global const float4* restrict tri_verts,
                    __global const uint* restrict tri_material, __global const float4* restrict tri_normals,
                    __global const float* restrict light_cdf, __global const uint* restrict light_tri,
                    __global const float* restrict tri_light_pdf, uint light_count,
                    SamplerParams sampler, uint first_pixel, uint sample_index, uint max_depth,
                    float4 background) {
  uint i = get_global_id(0);
  if (i >= count) return;
  uint slot = queue_in[i];
  uint pixel = first_pixel + slot;
  uint d = depth[slot];
  float4 h = hit[slot];
  float4 beta4 = throughput[slot];
  float3 beta = beta4.xyz;
  float prev_pdf = beta4.w;  // 0 after a camera ray or a specular bounce
  float3 L = radiance[slot].xyz;

  if (h.x < 0.0f) {  // escaped: the background is not sampled as a light, so it has weight 1
    radiance[slot] = (float4)(L + beta * background.xyz, 0.0f);
    return;
  }

  uint tri = as_uint(h.w);
  float3 p0 = tri_verts[3u * tri].xyz, p1 = tri_verts[3u * tri + 1u].xyz, p2 = tri_verts[3u * tri + 2u].xyz;
  float3 wo = -ray_dir[slot].xyz;
  float3 ng = normalize(cross(p1 - p0, p2 - p0));
  bool front = dot(ng, wo) > 0.0f;
  MaterialData m = materials[tri_material[tri]];
  float3 p = p0 + h.y * (p1 - p0) + h.z * (p2 - p0);

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
  if (d >= max_depth) return;

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
  bool transmitted = false;
  if (m.type == XI_MATERIAL_DIFFUSE) {
    if (xi_max3(m.albedo.xyz) <= 0.0f) return;
#ifdef XI_NEE
    if (light_count > 0u) {
      float2 uc = xi_sample_2d(XI_SAMPLER, sampler, pixel, sample_index, XI_PAIR_BOUNCE(d, XI_BOUNCE_CHOICES));
      float2 ul = xi_sample_2d(XI_SAMPLER, sampler, pixel, sample_index, XI_PAIR_BOUNCE(d, XI_BOUNCE_LIGHT_POINT));
      float3 org = xi_offset_ray_origin(p, n_geo);
      LightSample ls = xi_sample_light(light_cdf, light_tri, tri_light_pdf, tri_verts, tri_material, materials,
                                       light_count, org, uc.x, ul);
      float cos_s = dot(n, ls.wi);
      if (ls.pdf > 0.0f && cos_s > 0.0f && dot(n_geo, ls.wi) > 0.0f) {
        float w = 1.0f;
#ifdef XI_MIS
        w = xi_power_heuristic(ls.pdf, xi_lambert_pdf(n, ls.wi));
#endif
        float3 c = beta * m.albedo.xyz * XI_INV_PI * ls.radiance * (cos_s * w / ls.pdf);
        uint s = atomic_inc(&counters[XI_COUNTER_SHADOW]);
        shadow_org[s] = (float4)(org, ls.dist * 0.9999f);  // stop short of the light itself
        shadow_dir[s] = (float4)(ls.wi, 0.0f);
        shadow_contrib[s] = (float4)(c, as_float(slot));
      }
    }
#endif
    float2 ub = xi_sample_2d(XI_SAMPLER, sampler, pixel, sample_index, XI_PAIR_BOUNCE(d, XI_BOUNCE_BSDF_DIR));
    wi = xi_lambert_sample(n, ub, &pdf);
    if (dot(wi, n_geo) <= 0.0f || pdf <= 0.0f) return;  // shading normal pointed below the surface
    beta *= m.albedo.xyz;
  }
#ifdef XI_HAS_MIRROR
  else if (m.type == XI_MATERIAL_MIRROR) {
    wi = xi_reflect(wo, n);
    if (dot(wi, n_geo) <= 0.0f) return;
    beta *= m.albedo.xyz;
  }
#endif
#ifdef XI_HAS_DIELECTRIC
  else if (m.type == XI_MATERIAL_DIELECTRIC) {
    float2 uc = xi_sample_2d(XI_SAMPLER, sampler, pixel, sample_index, XI_PAIR_BOUNCE(d, XI_BOUNCE_CHOICES));
    bool reflected;
    wi = xi_dielectric_sample(wo, n, m.albedo.w, front, uc.y, &reflected);
    transmitted = !reflected;
    beta *= m.albedo.xyz;
  }
#endif
  else {
    return;  // a material this build was not compiled for
  }

  if (d + 1u >= XI_ROULETTE_DEPTH) {
    float q = fmin(xi_max3(beta), 0.95f);
    float u = xi_sample_2d(XI_SAMPLER, sampler, pixel, sample_index, XI_PAIR_BOUNCE(d, XI_BOUNCE_ROULETTE)).x;
    if (u >= q) return;
    beta /= q;
  }
  if (xi_max3(beta) <= 0.0f) return;

  ray_org[slot] = (float4)(xi_offset_ray_origin(p, transmitted ? -n_geo : n_geo), 0.0f);
  ray_dir[slot] = (float4)(wi, 0.0f);
  throughput[slot] = (float4)(beta, pdf);
  depth[slot] = d + 1u;
  queue_out[atomic_inc(&counters[XI_COUNTER_RAYS_OUT])] = slot;
}
