// Tool kernels, not wavefront stages: they run the renderer's own sampling routines on sample sets
// so `xi warp` can draw them and the tests can check them against their pdfs (χ²), and expose a
// device-specific helper to a test.
#include "bsdf.h"
#include "layout.h"
#include "lights.h"
#include "sampling.h"
#include "warps.h"

// points[i] = (warped point, 0); squares[i] = (ξ₁, ξ₂) it came from; sample set of `sampler` with
// spp = count, pixel `pixel`, dimension pair `pair`.
__kernel void warp_points(__global float4* restrict points, __global float2* restrict squares, int map,
                          int sampler, SamplerParams params, uint pixel, uint pair, uint count) {
  uint i = get_global_id(0);
  if (i >= count) return;
  float2 u = xi_sample_2d(sampler, params, pixel, i, pair);
  points[i] = (float4)(xi_warp(map, u), 0.0f);
  squares[i] = u;
}

// Light sampling from `org` as shade does it, over emissive triangles: out[i] = (wi, solid-angle
// pdf); one pair of the random sampler picks the light and places the point.
__kernel void sample_lights(__global float4* restrict out, __global const float* restrict light_cdf,
                            __global const uint* restrict light_tri, __global const float* restrict tri_light_pdf,
                            __global const uint4* restrict tri_vertices, __global const float4* restrict vertices,
                            __global const uint* restrict tri_material,
                            __global const MaterialData* restrict materials, uint light_count, float4 org,
                            SamplerParams params, uint count) {
  uint i = get_global_id(0);
  if (i >= count) return;
  float2 u = xi_sample_2d(XI_SAMPLER_RANDOM, params, 0u, i, 0u);
  EnvironmentData no_environment;
  no_environment.width = no_environment.height = 0u;
  // Shading word 0: emissive triangles only (punctual lights and the environment are not read).
  LightSample ls = xi_sample_light(light_cdf, light_tri, tri_light_pdf, tri_vertices, vertices, tri_material, materials,
                                   (__global const PunctualLightData*)0, no_environment, (__global const float4*)0,
                                   (__global const float*)0, 0u, light_count, org.xyz, u);
  out[i] = (float4)(ls.wi, ls.pdf);
}

// BSDF sampling as shade does it, for a unit normal n and outgoing direction wo on n's side.
// material: XI_MATERIAL_DIFFUSE → out[i] = (wi, pdf); XI_MATERIAL_DIELECTRIC (index `ior`, wo
// outside when `entering`) → out[i] = (wi, 1 if reflected else 0).
__kernel void sample_bsdf(__global float4* restrict out, uint material, float4 n, float4 wo, float ior,
                          int entering, SamplerParams params, uint count) {
  uint i = get_global_id(0);
  if (i >= count) return;
  float2 u = xi_sample_2d(XI_SAMPLER_RANDOM, params, 0u, i, 0u);
  if (material == XI_MATERIAL_DIELECTRIC) {
    bool reflected;
    float3 wi = xi_dielectric_sample(wo.xyz, n.xyz, ior, entering != 0, u.x, &reflected);
    out[i] = (float4)(wi, reflected ? 1.0f : 0.0f);
  } else {
    float pdf;
    float3 wi = xi_lambert_sample(n.xyz, u, &pdf);
    out[i] = (float4)(wi, pdf);
  }
}

// xi_lane_bits8, xi_lane_bits and xi_lane_bits16 (the BVH traversal branches on them) on the
// comparison whose true lanes are the set bits of i: out[i] = the 8-lane form, out[256 + i] = the
// 4-lane form on lanes 0–3, out[512 + i] = the 16-lane form with lanes 8–15 set as the bits of
// i ^ 0xa5.
__kernel void lane_bits(__global uint* restrict out) {
  uint i = get_global_id(0);
  if (i >= 256u) return;
  const uint8 shift = (uint8)(0u, 1u, 2u, 3u, 4u, 5u, 6u, 7u);
  uint8 bit = ((uint8)(i) >> shift) & (uint8)(1u);
  int8 m = convert_float8(bit) > (float8)(0.5f);
  out[i] = xi_lane_bits8(m);
  out[256u + i] = xi_lane_bits(m.lo);
  uint8 high = ((uint8)(i ^ 0xa5u) >> shift) & (uint8)(1u);
  int16 m16 = convert_float16((uint16)(bit, high)) > (float16)(0.5f);
  out[512u + i] = xi_lane_bits16(m16);
}
