// Stage 3, shade: at each queued hit, adds emitted radiance (MIS-weighted against light
// sampling), queues one shadow ray toward a light (next-event estimation), samples the BSDF for
// the next ray, applies Russian roulette and appends surviving paths to the next ray queue.
// What it does beyond diffuse surfaces is the shading word's (shading.h): mirrors, glass, the
// metallic-roughness material, textures, interpolated shading normals, emitters, punctual lights,
// the environment, light sampling (NEE) and MIS.
// Each work item shades XI_LANES paths at once (lanes.h): branches that differ between paths are
// lane masks, and every path of one launch is at the same depth, `bounce`.
#include "lanes.h"
#include "layout.h"
#include "lights.h"
#include "material.h"
#include "mesh.h"
#include "sampling.h"
#include "shading.h"
#include "spawn.h"
#include "textures.h"
#include "warps.h"

// Russian roulette from this bounce on, as in Mitsuba 3 (rr_depth 5): earlier bounces carry most
// of the image, and ending them early adds more variance than it saves time.
#define XI_ROULETTE_DEPTH 5u

// What shade reads of the scene beyond its buffers.
#define XI_SCENE_PARAMS XI_SCENE_BUFFERS(XI_CONST_PARAM) uint light_count, EnvironmentData env
#define XI_SCENE_ARGS XI_SCENE_BUFFERS(XI_ARG) light_count, env

// The metallic-roughness inputs at a hit: factors times textures (the base colour's texture is
// in the albedo already).
typedef struct {
  xfloat3 base_color;
  xfloat metallic, roughness, transmission, normal_scale;
} PbrInputs;

static inline XI_INLINE PbrInputs xi_pbr_inputs(XI_SCENE_PARAMS, uint shading, xuint mi, xfloat3 albedo, xfloat2 uv0,
                                                xfloat2 uv1) {
  PbrInputs in;
  in.base_color = albedo;
  xfloat3 f = XI_GATHER_XYZ_FIELD(materials, mi, pbr, &in.normal_scale);
  in.metallic = f.x;
  in.roughness = f.y;
  in.transmission = f.z;
  if (xi_uses(shading, XI_USE_TEXTURES)) {
    xfloat a;
    xfloat3 mr = xi_material_texture(materials, texture_refs, images, texels, mi, XI_TEXTURE_METALLIC_ROUGHNESS, uv0,
                                     uv1, &a);
    in.roughness = in.roughness * mr.y;
    in.metallic = in.metallic * mr.z;
  }
  return in;
}

// The tangent frame of texture coordinate set `set` at the hit, about n: the file's tangent (glTF's
// TANGENT, interpolated; the bitangent w · n × tangent) where it has one, else the direction of
// increasing u from the triangle's coordinates of the set, as glTF viewers do. False in lanes where
// neither gives a direction.
static inline XI_INLINE xmask xi_surface_tangent(XI_SCENE_PARAMS, xuint tri, xuint set, xfloat b1, xfloat b2, xfloat3 n,
                                                 xfloat3 p0, xfloat3 p1, xfloat3 p2, xfloat3* tangent,
                                                 xfloat3* bitangent) {
  xfloat w0, w1, w2;
  xfloat3 ta = xi_gather_xyz(tri_uv, 3u * tri, &w0), tb = xi_gather_xyz(tri_uv, 3u * tri + 1u, &w1),
          tc = xi_gather_xyz(tri_uv, 3u * tri + 2u, &w2);
  // The set's (u, v) at the three vertices.
  xfloat ua = set == 1u ? ta.z : ta.x, va = set == 1u ? w0 : ta.y;
  xfloat ub = set == 1u ? tb.z : tb.x, vb = set == 1u ? w1 : tb.y;
  xfloat uc = set == 1u ? tc.z : tc.x, vc = set == 1u ? w2 : tc.y;
  xfloat du1 = ub - ua, dv1 = vb - va, du2 = uc - ua, dv2 = vc - va;
  xfloat det = du1 * dv2 - du2 * dv1;
  xfloat3 dp1 = xi_sub3(p1, p0), dp2 = xi_sub3(p2, p0);
  xfloat3 dpdu = xi_scale3(xi_sub3(xi_scale3(dp1, dv2), xi_scale3(dp2, dv1)), 1.0f / (det != 0.0f ? det : (xfloat)1.0f));
  // The file's tangent (w: the bitangent's sign; 0 where it has none).
  xfloat sign;
  xfloat3 ft = xi_scale3(xi_gather_xyz(tri_tangents, 3u * tri, &sign), 1.0f - b1 - b2);
  ft = xi_add3(xi_add3(ft, xi_scale3(xi_gather_xyz(tri_tangents, 3u * tri + 1u, 0), b1)),
               xi_scale3(xi_gather_xyz(tri_tangents, 3u * tri + 2u, 0), b2));
  xmask from_file = sign != 0.0f;
  xfloat3 along = xi_select3(from_file, ft, dpdu);
  xfloat3 t = xi_sub3(along, xi_scale3(n, xi_dot3(n, along)));
  xfloat tl = xi_length3(t);
  *tangent = xi_scale3(t, 1.0f / (tl > 0.0f ? tl : (xfloat)1.0f));
  *bitangent = xi_scale3(xi_cross3(n, *tangent), from_file ? sign : (xfloat)1.0f);
  return (from_file || det != 0.0f) && tl > 0.0f;
}

// The shading normal n with the normal map of material mi's texture slot `slot` applied (tangent
// space: xi_surface_tangent's frame of the map's coordinates).
static inline XI_INLINE xfloat3 xi_mapped_normal(XI_SCENE_PARAMS, uint shading, xuint mi, xuint tri, int slot, xfloat b1,
                                                 xfloat b2, xfloat3 n, xfloat normal_scale, xfloat3 p0, xfloat3 p1,
                                                 xfloat3 p2, xfloat2 uv0, xfloat2 uv1) {
  if (xi_uses(shading, XI_USE_TEXTURES)) {
    xuint ref = XI_GATHER_UINT_FIELD(materials, mi, textures[slot]);
    xmask mapped = ref != XI_NO_TEXTURE;
    if (XI_ANY(mapped)) {
      xfloat a;
      xfloat3 t = xi_texture(texture_refs, images, texels, ref, uv0, uv1, &a);
      xuint r = mapped ? ref : (xuint)0u;
      xfloat3 tangent, bitangent;
      mapped = mapped && xi_surface_tangent(XI_SCENE_ARGS, tri, XI_GATHER_UINT_FIELD(texture_refs, r, texcoord), b1, b2,
                                            n, p0, p1, p2, &tangent, &bitangent);
      xfloat x = (2.0f * t.x - 1.0f) * normal_scale, y = (2.0f * t.y - 1.0f) * normal_scale, z = 2.0f * t.z - 1.0f;
      xfloat3 nm = xi_add3(xi_add3(xi_scale3(tangent, x), xi_scale3(bitangent, y)), xi_scale3(n, z));
      xfloat nl = xi_length3(nm);
      mapped = mapped && nl > 0.0f;
      n = xi_select3(mapped, xi_scale3(nm, 1.0f / (nl > 0.0f ? nl : (xfloat)1.0f)), n);
    }
  }
  return n;
}

// A metallic-roughness shading normal n turned where it would face away from wo or mirror wo below
// the surface: a shading normal seen from behind would make the lobes' local frame invalid (black
// fringes) or light leak through, and one that mirrors wo into the surface loses the specular light
// a bumped glossy surface reflects (a strong normal map went dark). As Cycles does, it is turned so
// that wo's mirror direction keeps the azimuth about the geometric normal it had but rises to just
// above the surface. (Sample directions are still checked against the geometric normal.)
static inline XI_INLINE xfloat3 xi_turned_normal(xfloat3 n, xfloat3 n_geo, xfloat3 wo) {
  // Never above the geometric normal's own cosine, so the geometric normal itself is left as it is.
  xfloat c = xi_dot3(n, wo), least = fmin((xfloat)0.01f, xi_dot3(n_geo, wo));
  n = xi_select3(c < least, xi_normalize3(xi_add3(n, xi_scale3(wo, least - c))), n);
  // The mirror direction r at least `lowest` above the surface: else r' (r's azimuth, that height)
  // and the normal halfway between wo and r'.
  xfloat3 r = xi_sub3(xi_scale3(n, 2.0f * xi_dot3(n, wo)), wo);
  xfloat height = xi_dot3(n_geo, r), lowest = fmin(0.9f * xi_dot3(n_geo, wo), (xfloat)0.01f);
  xfloat3 across = xi_sub3(r, xi_scale3(n_geo, height));
  xfloat al = xi_length3(across);
  xmask turn = height < lowest && al > 0.0f;
  xfloat3 raised = xi_add3(xi_scale3(across, xi_safe_sqrt(1.0f - lowest * lowest) / (al > 0.0f ? al : (xfloat)1.0f)),
                           xi_scale3(n_geo, lowest));
  return xi_select3(turn, xi_normalize3(xi_add3(wo, raised)), n);
}

// The BSDF at a hit (material.h): the shading normal (interpolated vertex normals, a normal map),
// the material's parameters after its textures, and the metallic-roughness lobes' frame. m holds
// the material after the base colour texture; front: wo is on the geometric normal ng's side.
static inline XI_INLINE Bsdf xi_surface_bsdf(XI_SCENE_PARAMS, uint shading, ShadingMaterial m, xuint mi, xuint tri,
                                             TriangleCorners c, xmask at_surface, xmask front, xfloat3 ng, xfloat3 wo,
                                             xfloat b1, xfloat b2, xfloat2 uv0, xfloat2 uv1) {
  const xfloat3 p0 = c.p0, p1 = c.p1, p2 = c.p2;
  Bsdf b;
  b.at_surface = at_surface;
  b.type = m.type;
  b.ior = m.ior;
  b.entering = front;
  b.n_geo = xi_select3(front, ng, xi_neg3(ng));
  b.n = b.n_geo;
  if (xi_uses(shading, XI_USE_NORMALS)) {
    xmask smooth = c.smooth;
    if (XI_ANY(smooth)) {  // (lanes of flat triangles read their vertices' zero normals, unused)
      xfloat3 ns = xi_normalize3(xi_add3(xi_add3(xi_scale3(xi_vertex_normal(vertices, c.v0), 1.0f - b1 - b2),
                                                 xi_scale3(xi_vertex_normal(vertices, c.v1), b1)),
                                         xi_scale3(xi_vertex_normal(vertices, c.v2), b2)));
      ns = xi_select3(xi_dot3(ns, b.n_geo) < 0.0f, xi_neg3(ns), ns);
      b.n = xi_select3(smooth, ns, b.n_geo);
    }
  }

  // The metallic-roughness material: its inputs, shading normal and local frame (n = +z, wo above).
  b.pbr = xi_plain_pbr_lobes(m.albedo);
  b.pbr.multiple_scattering = xi_uses(shading, XI_USE_MULTIPLE_SCATTERING) ? 1.0f : 0.0f;
  b.pbr.albedo_scaling = xi_uses(shading, XI_USE_ALBEDO_SCALING) ? 1.0f : 0.0f;
  b.frame_t = b.frame_b = b.n;
  if (xi_uses(shading, XI_USE_PBR)) {
    xmask pbr = at_surface && m.type == XI_MATERIAL_PBR;
    if (XI_ANY(pbr)) {
      PbrInputs in = xi_pbr_inputs(XI_SCENE_ARGS, shading, mi, m.albedo, uv0, uv1);
      xfloat3 n_interpolated = b.n;
      xfloat3 n_mapped = xi_mapped_normal(XI_SCENE_ARGS, shading, mi, tri, XI_TEXTURE_NORMAL, b1, b2, b.n, in.normal_scale,
                                          p0, p1, p2, uv0, uv1);
      xfloat3 np = xi_turned_normal(n_mapped, b.n_geo, wo);
      b.n = xi_select3(pbr, np, b.n);
      xi_basis(b.n, &b.frame_t, &b.frame_b);
      b.pbr.base_color = in.base_color;
      b.pbr.metallic = in.metallic;
      b.pbr.alpha = in.roughness * in.roughness;
      // Only light that can get in is ever inside: an opaque surface's back face is the same surface
      // seen from the other side (as glTF's double-sided surfaces and Cycles' Principled BSDF).
      b.pbr.eta = front || in.transmission <= 0.0f ? m.ior : 1.0f / m.ior;
      b.pbr.transmission = in.transmission;
      // The layers' factors, times their textures (glTF's channels: the coat's weight in R, its
      // roughness in G, the sheen's and the specular layer's strength in A).
      const bool textured = xi_uses(shading, XI_USE_TEXTURES);
      xfloat a;
      if (xi_uses(shading, XI_USE_ANISOTROPY)) {
        // KHR_materials_anisotropy: the frame's x turned to the anisotropy direction, the texture's
        // RG (a direction in the tangent frame of its coordinates, else that frame's u) rotated by
        // the material's angle, projected onto the shading plane; the lobes' alphas from its
        // strength (xi_set_anisotropy). Lanes without a tangent frame stay isotropic.
        xfloat3 anisotropy = XI_GATHER_XYZ_FIELD(materials, mi, anisotropy, 0);  // strength, cos and sin of the angle
        xfloat strength = pbr ? anisotropy.x : (xfloat)0.0f, dx = 1.0f, dy = 0.0f;
        xuint set = 0u;
        if (textured) {
          xuint ref = XI_GATHER_UINT_FIELD(materials, mi, textures[XI_TEXTURE_ANISOTROPY]);
          xmask mapped = ref != XI_NO_TEXTURE;
          if (XI_ANY(mapped)) {
            xfloat3 t = xi_texture(texture_refs, images, texels, ref, uv0, uv1, &a);
            dx = mapped ? 2.0f * t.x - 1.0f : dx;
            dy = mapped ? 2.0f * t.y - 1.0f : dy;
            strength = mapped ? strength * t.z : strength;
            set = XI_GATHER_UINT_FIELD(texture_refs, mapped ? ref : (xuint)0u, texcoord);
            set = mapped ? set : (xuint)0u;
          }
        }
        if (XI_ANY(strength > 0.0f)) {
          xfloat3 tangent, bitangent;
          xmask framed = xi_surface_tangent(XI_SCENE_ARGS, tri, set, b1, b2, b.n, p0, p1, p2, &tangent, &bitangent);
          xfloat3 d = xi_add3(xi_scale3(tangent, anisotropy.y * dx - anisotropy.z * dy),
                              xi_scale3(bitangent, anisotropy.z * dx + anisotropy.y * dy));
          d = xi_sub3(d, xi_scale3(b.n, xi_dot3(b.n, d)));
          xfloat dl = xi_length3(d);
          xmask turned = strength > 0.0f && framed && dl > 0.0f;
          d = xi_scale3(d, 1.0f / (dl > 0.0f ? dl : (xfloat)1.0f));
          b.frame_t = xi_select3(turned, d, b.frame_t);
          b.frame_b = xi_select3(turned, xi_cross3(b.n, d), b.frame_b);
          xi_set_anisotropy(&b.pbr, turned ? strength : (xfloat)0.0f);
        }
      }
      if (xi_uses(shading, XI_USE_SPECULAR)) {
        b.pbr.specular_color = XI_GATHER_XYZ_FIELD(materials, mi, specular, &b.pbr.specular);
        if (textured) {
          xi_material_texture(materials, texture_refs, images, texels, mi, XI_TEXTURE_SPECULAR, uv0, uv1, &a);
          b.pbr.specular *= a;
          b.pbr.specular_color = xi_mul3(b.pbr.specular_color, xi_material_texture(materials, texture_refs, images, texels, mi,
                                                                                    XI_TEXTURE_SPECULAR_COLOR, uv0, uv1, &a));
        }
      }
      if (xi_uses(shading, XI_USE_CLEARCOAT)) {
        xfloat3 coat = XI_GATHER_XYZ_FIELD(materials, mi, coat, 0);
        if (textured) {
          coat.x *= xi_material_texture(materials, texture_refs, images, texels, mi, XI_TEXTURE_CLEARCOAT, uv0, uv1, &a).x;
          coat.y *= xi_material_texture(materials, texture_refs, images, texels, mi, XI_TEXTURE_CLEARCOAT_ROUGHNESS, uv0,
                                        uv1, &a).y;
        }
        b.pbr.coat = pbr ? coat.x : (xfloat)0.0f;
        b.pbr.coat_alpha = coat.y * coat.y;
        // The coat's normal: the interpolated one with the coat's own normal map (not the base's).
        xfloat3 nc = xi_turned_normal(xi_mapped_normal(XI_SCENE_ARGS, shading, mi, tri, XI_TEXTURE_CLEARCOAT_NORMAL, b1, b2,
                                                       n_interpolated, coat.z, p0, p1, p2, uv0, uv1),
                                      b.n_geo, wo);
        b.pbr.coat_normal = xi_normalize3(xi_bsdf_to_local(b, nc));
      }
      if (xi_uses(shading, XI_USE_SHEEN)) {
        xfloat roughness;
        xfloat3 sheen = XI_GATHER_XYZ_FIELD(materials, mi, sheen, &roughness);
        if (textured) {
          sheen = xi_mul3(sheen, xi_material_texture(materials, texture_refs, images, texels, mi, XI_TEXTURE_SHEEN_COLOR, uv0,
                                                     uv1, &a));
          xi_material_texture(materials, texture_refs, images, texels, mi, XI_TEXTURE_SHEEN_ROUGHNESS, uv0, uv1, &a);
          roughness *= a;
        }
        b.pbr.sheen_color = xi_select3(pbr, sheen, b.pbr.sheen_color);
        b.pbr.sheen_alpha = roughness * roughness;
      }
      if (xi_uses(shading, XI_USE_IRIDESCENCE)) {
        // KHR_materials_iridescence: the film's weight times its texture's R; its thickness from the
        // minimum to the maximum by the thickness texture's G (an absent texture reads 1: the maximum).
        xfloat maximum;
        xfloat3 film = XI_GATHER_XYZ_FIELD(materials, mi, iridescence, &maximum);  // weight, ior, minimum
        xfloat g = 1.0f;
        if (textured) {
          film.x *= xi_material_texture(materials, texture_refs, images, texels, mi, XI_TEXTURE_IRIDESCENCE, uv0, uv1, &a).x;
          g = xi_material_texture(materials, texture_refs, images, texels, mi, XI_TEXTURE_IRIDESCENCE_THICKNESS, uv0, uv1, &a).y;
        }
        b.pbr.iridescence = pbr ? film.x : (xfloat)0.0f;
        b.pbr.iridescence_ior = film.y;
        b.pbr.iridescence_thickness = film.z + (maximum - film.z) * g;
      }
#if XI_DIFFUSE_NORMALS
      // Under a normal map, the Lambertian base's own normals (xi_diffuse_cosine).
      if (xi_uses(shading, XI_USE_NORMAL_MAP)) {
        xmask own = pbr && (n_mapped.x != n_interpolated.x || n_mapped.y != n_interpolated.y || n_mapped.z != n_interpolated.z);
        if (XI_ANY(own)) {
          b.pbr.diffuse_normal = xi_select3(own, xi_normalize3(xi_bsdf_to_local(b, n_mapped)), b.pbr.diffuse_normal);
          b.pbr.smooth_normal = xi_select3(own, xi_normalize3(xi_bsdf_to_local(b, n_interpolated)), b.pbr.smooth_normal);
        }
      }
#endif
      m.albedo = xi_select3(pbr, in.base_color, m.albedo);
      b.pbr_at = xi_bsdf_at_wo(b, wo);
    }
  }
  b.tint = m.albedo;
  return b;
}

// Beer–Lambert over the segment a ray travelled inside volume medium − 1: beta times exp(−σa t); a
// ray that escaped from inside (a mesh that is not closed) is absorbed wherever σa > 0.
static inline xfloat3 xi_volume_transmittance(__global const float4* volumes, xuint medium, xfloat t, xfloat3 beta) {
  xfloat3 sigma = xi_gather_xyz(volumes, medium != 0u ? medium - 1u : (xuint)0u, 0);
  xfloat d = t < 0.0f ? (xfloat)1e30f : t;
  return make_xfloat3(beta.x * exp(-sigma.x * d), beta.y * exp(-sigma.y * d), beta.z * exp(-sigma.z * d));
}

// Whether an escaped ray gathers light: from an environment map or a background that is not black.
static inline bool xi_lit_from_afar(uint shading, EnvironmentData env, float4 background) {
  return (xi_uses(shading, XI_USE_ENVIRONMENT) && env.width > 0u) || background.x != 0.0f || background.y != 0.0f ||
         background.z != 0.0f;
}

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

static inline XI_INLINE ShadeResult xi_shade_paths(XI_PATH_PARAMS xuint slot, xmask active, uint d, XI_SCENE_PARAMS,
                                                   SamplerParams sampler, uint shading, uint max_depth,
                                                   float4 background) {
  const int sampler_kind = xi_sampler_of(shading);
  ShadeResult r;
  r.next_ray = XI_FALSE;
  r.shadow = XI_FALSE;
  r.shadow_org = r.shadow_dir = r.shadow_contrib = xi_splat3(make_float3(0.0f, 0.0f, 0.0f));
  r.shadow_tmax = 0.0f;
  if (!XI_ANY(active)) return r;
  xfloat tri_bits;
  xfloat3 h = xi_gather_xyz(hit, slot, &tri_bits);  // t (< 0: missed), barycentrics u, v
  xmask escaped = h.x < 0.0f;
  // A camera ray (bounce 0) carries throughput 1 and no radiance yet, which generate does not write:
  // here they are known, not read, and every camera ray's radiance is written below.
  xfloat prev_pdf = 0.0f;  // 0 after a camera ray or a specular bounce
  xfloat3 beta = xi_splat3(make_float3(1.0f, 1.0f, 1.0f)), L = xi_splat3(make_float3(0.0f, 0.0f, 0.0f));
  if (d > 0u) {
    beta = xi_gather_xyz(throughput, slot, &prev_pdf);
    L = xi_gather_xyz(radiance, slot, 0);
  }
  if (!xi_lit_from_afar(shading, env, background)) {  // an escaped path gathers nothing more
    if (d == 0u) xi_scatter4(radiance, slot, L, (xfloat)0.0f, active && escaped);
    active = active && !escaped;
    if (!XI_ANY(active)) return r;
  }
  // The volumes the ray is in (layout.h's ray_dir.w, XI_VOLUME_BITS each): the innermost, medium,
  // in the lowest bits (0: none).
  xuint media = 0u, medium = 0u;
  if (xi_uses(shading, XI_USE_VOLUME)) {
    xfloat media_bits;
    xi_gather_xyz(ray_dir, slot, &media_bits);
    media = active ? xi_as_uint(media_bits) : (xuint)0u;
    medium = media & (xuint)((1u << XI_VOLUME_BITS) - 1u);
    if (XI_ANY(medium != 0u)) beta = xi_select3(medium != 0u, xi_volume_transmittance(volumes, medium, h.x, beta), beta);
  }

  if (xi_uses(shading, XI_USE_ENVIRONMENT) && env.width > 0u) {
    // The environment, MIS-weighted against light sampling where the ray was a BSDF sample.
    xmask seen = active && escaped;
    if (XI_ANY(seen)) {
      // The map's (u, v) once, for the lookup and the pdf; the pdf only where some lane needs it (not
      // after camera rays, most of an asset's escaped paths).
      xfloat3 in_map = xi_env_to_local(env, xi_gather_xyz(ray_dir, slot, 0));
      xfloat2 uv = xi_env_direction_to_uv(in_map);
      xfloat3 le = xi_env_lookup(environment_texels, env, uv.x, uv.y);
      xfloat w = 1.0f;
      xmask weighed = seen && prev_pdf > 0.0f;
      if (xi_uses(shading, XI_USE_MIS)) {
        if (XI_ANY(weighed))
          w = weighed ? xi_power_heuristic(prev_pdf, env.scale.w * xi_env_pdf_local(environment_cdf, env, in_map, uv)) : w;
      } else if (xi_uses(shading, XI_USE_NEE))
        w = prev_pdf > 0.0f && env.scale.w > 0.0f ? (xfloat)0.0f : w;
      L = xi_select3(seen, xi_add3(L, xi_scale3(xi_mul3(beta, le), w)), L);
    }
  } else {
    // Escaped: the background is not sampled as a light, so it has weight 1.
    L = xi_select3(escaped, xi_add3(L, xi_mul3(beta, xi_splat3(xyz(background)))), L);
  }
  const xmask surface_hit = active && !escaped;  // at_surface, until it loses the rays that pass through
  xmask at_surface = surface_hit;
  if (!XI_ANY(at_surface)) {
    xi_scatter4(radiance, slot, L, (xfloat)0.0f, active);
    return r;
  }
  const xuint pixel = xi_gather_uint(item_pixel, slot), sample_index = xi_gather_uint(item_sample, slot);

  xuint tri = at_surface ? xi_as_uint(tri_bits) : (xuint)0u;  // other lanes read triangle 0, unused
  const TriangleCorners corners = xi_triangle_corners(tri_vertices, vertices, tri);
  const xfloat3 p0 = corners.p0, p1 = corners.p1, p2 = corners.p2;
  xfloat3 wo = xi_neg3(xi_gather_xyz(ray_dir, slot, 0));
  xfloat3 ng = xi_normalize3(xi_cross3(xi_sub3(p1, p0), xi_sub3(p2, p0)));
  xmask front = xi_dot3(ng, wo) > 0.0f;
  xuint mi = xi_gather_uint(tri_material, tri);
  ShadingMaterial m = xi_gather_material(materials, mi);
  xfloat3 p_error;
  xfloat3 p = xi_interpolate(p0, p1, p2, h.y, h.z, &p_error);
  // Texture coordinates, sets 0 and 1, interpolated as p is.
  xfloat2 uv0 = make_xfloat2((xfloat)0.0f, (xfloat)0.0f), uv1 = uv0;
  xfloat base_alpha = 1.0f;
  if (xi_uses(shading, XI_USE_TEXTURES)) {
    xi_hit_uv(tri_uv, tri, h.y, h.z, &uv0, &uv1);
    xfloat a;
    m.emission = xi_mul3(m.emission, xi_material_texture(materials, texture_refs, images, texels, mi,
                                                         XI_TEXTURE_EMISSIVE, uv0, uv1, &a));
    // The base colour texture, looked up once: it tints a diffuse albedo and a metallic-roughness
    // base colour alike (1 where a material has none), and its alpha cuts out.
    m.albedo = xi_mul3(m.albedo, xi_material_texture(materials, texture_refs, images, texels, mi,
                                                     XI_TEXTURE_BASE_COLOR, uv0, uv1, &base_alpha));
  }
  // Cut-out and transparent surfaces: the path goes on through, unchanged (throughput, the last
  // BSDF pdf for MIS), from the far side; it counts as a bounce against max_depth.
  xmask passes = XI_FALSE;
  if (xi_uses(shading, XI_USE_ALPHA)) {
    xfloat u_alpha = xi_sample_2d(sampler_kind, sampler, pixel, sample_index, XI_PAIR_BOUNCE(d, XI_BOUNCE_LOBE)).y;
    passes = at_surface && xi_passes_through(materials, mi, base_alpha, u_alpha);
    at_surface = at_surface && !passes;
  }

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

  Bsdf bsdf = xi_surface_bsdf(XI_SCENE_ARGS, shading, m, mi, tri, corners, at_surface, front, ng, wo, h.y, h.z, uv0,
                               uv1);
  if (d == 0u) {  // (0 where a ray passes through, as generate wrote it: stored by surface_hit, as below)
    const xfloat3 none = xi_splat3(make_float3(0.0f, 0.0f, 0.0f));
    xi_scatter4(aov_albedo, slot, xi_select3(at_surface, bsdf.tint, none), (xfloat)0.0f, surface_hit);
    xi_scatter4(aov_normal, slot, xi_select3(at_surface, bsdf.n, none), (xfloat)0.0f, surface_hit);
  }

  // Direct light: one light sample, weighed against the BSDF's own density, as a shadow ray.
  xmask reachable = xi_bsdf_has_non_delta(bsdf, shading);
  if (xi_uses(shading, XI_USE_NEE) && light_count > 0u && XI_ANY(reachable)) {
    xfloat2 ul = xi_sample_2d(sampler_kind, sampler, pixel, sample_index, XI_PAIR_BOUNCE(d, XI_BOUNCE_LIGHT));
    xfloat3 org = xi_offset_ray_origin(p, p_error, bsdf.n_geo, bsdf.n_geo);  // lights behind n_geo are skipped
    LightSample ls = xi_sample_light(light_cdf, light_tri, tri_light_pdf, tri_vertices, vertices, tri_material,
                                     materials, punctual, env, environment_texels, environment_cdf, shading,
                                     light_count, org, ul);
    BsdfValue f = xi_bsdf_eval(bsdf, shading, wo, ls.wi);
    xfloat cos_s = xi_dot3(bsdf.n, ls.wi);
    xfloat w = 1.0f;
    if (xi_uses(shading, XI_USE_MIS)) w = ls.delta ? (xfloat)1.0f : xi_power_heuristic(ls.pdf, f.pdf);
    // Lights on either side: reflection above the surface, transmission below (the shadow ray then
    // starts below it).
    xfloat side = xi_dot3(bsdf.n_geo, ls.wi);
    r.shadow = reachable && ls.pdf > 0.0f && xi_bsdf_side_agrees(bsdf, side, cos_s) && xi_max3(f.colour) > 0.0f;
    r.shadow_contrib = xi_scale3(xi_mul3(xi_scale3(xi_mul3(beta, f.colour), f.scale), ls.radiance),
                                 fabs(cos_s) * w / (ls.pdf > 0.0f ? ls.pdf : (xfloat)1.0f));
    // Its end is off the light already; the margin covers the rounding of the hit distance.
    r.shadow_org = xi_select3(side < 0.0f, xi_offset_ray_origin(p, p_error, bsdf.n_geo, ls.wi), org);
    r.shadow_tmax = ls.dist * (1.0f - 1e-4f);
    r.shadow_dir = ls.wi;
  }

  // Scatter: the BSDF's sample is the next ray. (A material the shading word leaves out ends its path.)
  xfloat2 ub = xi_sample_2d(sampler_kind, sampler, pixel, sample_index, XI_PAIR_BOUNCE(d, XI_BOUNCE_BSDF_DIR));
  xfloat u_lobe = 0.0f;
  if (xi_uses(shading, XI_USE_DIELECTRIC | XI_USE_PBR))
    u_lobe = xi_sample_2d(sampler_kind, sampler, pixel, sample_index, XI_PAIR_BOUNCE(d, XI_BOUNCE_LOBE)).x;
  BsdfSample bs = xi_bsdf_sample(bsdf, shading, wo, u_lobe, ub);
  xfloat3 wi = bs.wi;
  xfloat pdf = bs.pdf;
  xmask goes_on = bs.valid;
  xfloat3 beta_in = beta;
  beta = xi_mul3(beta, bs.weight);

  if (d + 1u >= XI_ROULETTE_DEPTH) {
    // The decision takes an independent uniform, whatever the sampler: a deterministic sample set
    // (grid's cell centres) would make it a fixed cut, ending every path whose q is below them all.
    xfloat q = fmin(xi_max3(beta), 0.95f);
    xfloat u = xi_sample_2d(XI_SAMPLER_RANDOM, sampler, pixel, sample_index, XI_PAIR_BOUNCE(d, XI_BOUNCE_ROULETTE)).x;
    goes_on = goes_on && u < q;
    beta = xi_div3(beta, q);
  }
  goes_on = goes_on && xi_max3(beta) > 0.0f;
  if (xi_uses(shading, XI_USE_ALPHA)) {
    goes_on = goes_on || passes;
    wi = xi_select3(passes, xi_neg3(wo), wi);
    beta = xi_select3(passes, beta_in, beta);
    pdf = passes ? prev_pdf : pdf;
  }

  xfloat media_out = 0.0f;
  if (xi_uses(shading, XI_USE_VOLUME)) {
    // A refraction into a volume's mesh pushes its medium onto the ones the ray is in (XI_VOLUME_LEVELS
    // deep: a deeper one forgets the outermost); one out of it pops back to the one around it.
    // Reflections, thin surfaces and cut-outs keep the media the ray is in.
    xmask transmitted = at_surface && (bs.lobe & (xuint)XI_LOBE_TRANSMISSION) != 0u;
    xuint volume = XI_GATHER_UINT_FIELD(materials, mi, volume);
    xmask bounds = transmitted && volume != 0u;
    xuint pushed = (media << XI_VOLUME_BITS) | volume;
    media_out = xi_as_float(bounds ? (front ? pushed : media >> XI_VOLUME_BITS) : media);
  }
  // Stored wherever a surface was hit, not only where the path goes on: an ended path's ray is read
  // by no one, and whether a lane hit a surface is what neighbouring lanes share (escaped rays are
  // partitioned off), where the roulette's and the BSDF's outcomes are what no branch predictor learns.
  xi_scatter4(ray_org, slot, xi_offset_ray_origin(p, p_error, bsdf.n_geo, wi), (xfloat)0.0f, surface_hit);
  xi_scatter4(ray_dir, slot, wi, media_out, surface_hit);
  xi_scatter4(throughput, slot, beta, pdf, surface_hit);
  r.next_ray = goes_on;
  return r;
}

// Work item i shades queue entries XI_LANES·i to XI_LANES·i + XI_LANES − 1.
__kernel void shade(XI_PATH_PARAMS __global const uint* restrict queue_in, __global uint* restrict queue_out,
                    XI_SHADOW_PARAMS volatile __global uint* restrict counters, uint bounce, XI_SCENE_PARAMS,
                    SamplerParams sampler, uint shading_argument, uint max_depth, float4 background) {
  const uint shading = xi_shading(shading_argument);
  volatile __local uint partition_count[2], append_count[2], group_base[2];
  const uint count = counters[XI_COUNTER_RAYS(bounce)];
  xuint entry = (uint)get_global_id(0) * XI_LANES + XI_LANE_INDEX;
  xmask active = entry < count;  // launched over an upper bound
  xuint slot = xi_gather_uint(queue_in, active ? entry : (xuint)0u);
  slot = active ? slot : (xuint)0u;  // queue_in[0] may be unwritten when the queue is empty
  // After the first bounce many rays escape, and a surface costs far more to shade than an escaped
  // ray. The group's entries are partitioned, surface hits first and escaped rays last, so that most
  // work items shade lanes of one kind and one whose rays all escaped skips the surface code. Camera
  // rays escape in runs of neighbouring pixels, so at bounce 0 only an environment's lookups repay
  // it. Each path is shaded the same; only the work item changes.
  __local uint group_slots[XI_MAX_LOCAL_SIZE * XI_LANES];
  const bool skip_escaped = !xi_lit_from_afar(shading, env, background);
  const bool partitioned = bounce > 0u || !skip_escaped;
  const uint group_first = (uint)get_group_id(0) * (uint)get_local_size(0) * XI_LANES;
  const uint group_entries = group_first < count ? min((uint)get_local_size(0) * XI_LANES, count - group_first) : 0u;
  const uint local_first = (uint)get_local_id(0) * XI_LANES;
  if (get_local_id(0) == 0u) partition_count[0] = partition_count[1] = append_count[0] = append_count[1] = 0u;
  barrier(CLK_LOCAL_MEM_FENCE);
  if (partitioned) {
    xmask escaped = active && xi_gather_float((__global const float*)hit, 4u * slot) < 0.0f;
    xmask surface = active && !escaped;
    uint surfaces = xi_count(surface), escapes = xi_count(escaped);
    uint front = surfaces ? atomic_add(&partition_count[0], surfaces) : 0u;
    uint back = escapes ? atomic_add(&partition_count[1], escapes) : 0u;
    xuint at = surface ? xi_compact_index(front, surface) : (xuint)(group_entries - 1u) - xi_compact_index(back, escaped);
    xi_local_scatter_uint(group_slots, at, slot, active);
  }
  barrier(CLK_LOCAL_MEM_FENCE);
  if (partitioned) {
    xuint local_entry = local_first + XI_LANE_INDEX;
    active = local_entry < group_entries;
    slot = xi_local_gather_uint(group_slots, active ? local_entry : (xuint)0u);
    slot = active ? slot : (xuint)0u;
  }
#if XI_HAS_PREFETCH
  // The next work item's paths, fetched while this one shades (as extend does), so their loads no
  // longer wait on memory; escaped paths that need nothing more are not fetched.
  const uint ahead_first = (partitioned ? local_first : (uint)get_global_id(0) * XI_LANES) + XI_LANES;
  const uint ahead_end = min(ahead_first + XI_LANES,
                             partitioned ? (skip_escaped ? partition_count[0] : group_entries) : count);
  for (uint at = ahead_first; at < ahead_end; ++at) {
    uint ahead = partitioned ? group_slots[at] : queue_in[at];
    XI_PREFETCH(&hit[ahead], 0);
    if (bounce > 0u) {
      XI_PREFETCH(&throughput[ahead], 1);
      XI_PREFETCH(&radiance[ahead], 1);
    }
    XI_PREFETCH(&ray_dir[ahead], 1);
  }
#endif
  ShadeResult r = xi_shade_paths(XI_PATH_ARGS slot, active, bounce, XI_SCENE_ARGS, sampler, shading, max_depth,
                                 background);
  // Append to the ray and shadow queues: entries are counted in local memory and reserved with one
  // global atomic per work group, since a global atomic per item serialises the cores on one line.
  uint rays = xi_count(r.next_ray), shadows = xi_count(r.shadow);
  uint ray_index = rays ? atomic_add(&append_count[0], rays) : 0u;
  uint shadow_index = shadows ? atomic_add(&append_count[1], shadows) : 0u;
  barrier(CLK_LOCAL_MEM_FENCE);
  if (get_local_id(0) == 0u) {
    group_base[0] = atomic_add(&counters[XI_COUNTER_RAYS(bounce + 1u)], append_count[0]);
    group_base[1] = atomic_add(&counters[XI_COUNTER_SHADOW(bounce)], append_count[1]);
  }
  barrier(CLK_LOCAL_MEM_FENCE);
  xuint ray_at = xi_compact_index(group_base[0] + ray_index, r.next_ray);
  xuint shadow_at = xi_compact_index(group_base[1] + shadow_index, r.shadow);
  xi_append_uint(queue_out, ray_at, slot, r.next_ray);
  xi_append4(shadow_org, shadow_at, r.shadow_org, r.shadow_tmax, r.shadow);
  xi_append4(shadow_dir, shadow_at, r.shadow_dir, (xfloat)0.0f, r.shadow);
  xi_append4(shadow_contrib, shadow_at, r.shadow_contrib, xi_as_float(slot), r.shadow);
}
